"""eskin: a data-versioned experiment pipeline for soft capacitive e-skins."""

__version__ = "0.1.0"
