"""MLflow runs, compare and audit, the model registry, a lab's server."""
