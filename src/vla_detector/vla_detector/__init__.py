"""Object detector for the latent-action context: datasets, training, ONNX Runtime inference node."""
