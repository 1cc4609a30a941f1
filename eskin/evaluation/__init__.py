"""Cross-validation folds, metrics, and the task runner."""
