"""MLflow runs, compare and audit, the model registry, a lab's server; the planner that
reads make bench's learning curves (`eskin plan`)."""
