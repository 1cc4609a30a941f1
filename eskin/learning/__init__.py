"""Features, estimators and training: the featurize and train steps."""
