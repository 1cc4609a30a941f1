"""The trained stack on the robot side: load, export to ONNX, run live."""
