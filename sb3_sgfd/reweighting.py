"""SGFD's weights as functions of tensors (random Fourier features, the decorrelation loss, the weight solver), by
the path earlier code imports them from; they live in :mod:`sb3_sgfd.sgfd.functional`."""

from sb3_sgfd.sgfd.functional import (
    decorrelation_loss,
    effective_sample_size,
    learn_sample_weights,
    loss_gradient,
    random_fourier_features,
    weighted_pearson,
)

__all__ = [
    "decorrelation_loss",
    "effective_sample_size",
    "learn_sample_weights",
    "loss_gradient",
    "random_fourier_features",
    "weighted_pearson",
]
