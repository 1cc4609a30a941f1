"""The pipeline's steps, one module each: read params, call the library, write outputs. A
DVC stage (``stages/<step>.py``) and its ``eskin`` command call the same ``run``."""
