"""MLflow runs, compare and audit, the model registry, a lab's server; the planner that
reads make bench's learning curves (`eskin plan`)."""

import os

# Before any module here imports MLflow, which sets its loggers' level at import: its INFO
# lines (the tables it creates in a new SQLite store, alembic's migrations) are not a
# command's or the tracking stage's output. Warnings and errors still show;
# MLFLOW_LOGGING_LEVEL=INFO brings the rest back.
os.environ.setdefault("MLFLOW_LOGGING_LEVEL", "WARNING")
