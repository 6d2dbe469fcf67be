"""Detector training: synthetic data, datasets, the network, training, evaluation and ONNX export.
"""
