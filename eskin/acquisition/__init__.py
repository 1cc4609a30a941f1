"""Acquisition: scene plans, the raw log, the runner and sessions."""
