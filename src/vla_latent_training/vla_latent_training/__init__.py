"""Latent-action model training: training pairs from demonstrations, the CAE, training and calibration.
"""
