"""Export of trained models to ONNX model bundles with codebooks."""
