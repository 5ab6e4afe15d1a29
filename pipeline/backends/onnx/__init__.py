"""ONNX Runtime backends: the 2D person detectors and pose estimators."""
