"""SGFD's own checks of its tensors: the sample weights of the decorrelation, the feature probabilities p(Z_i) from
the classifier's saliency, and the domain labels the classifier learns. The generic checks (shapes, numbers,
SAC's arguments) are in :mod:`sb3_sgfd.common.validation`; like those, a check that reads a tensor's values back
to the host says so."""

from __future__ import annotations

import torch
from torch import Tensor


def check_weights(weights: Tensor, n: int) -> None:
    """Refuse sample weights that are not a finite, non-negative (n,) tensor with a positive sum (a host read)."""
    if not isinstance(weights, Tensor) or weights.shape != (n,):
        shape = tuple(weights.shape) if isinstance(weights, Tensor) else type(weights).__name__
        raise ValueError(f"weights must be a tensor of shape ({n},), got {shape}")
    w = weights.detach()
    if not torch.isfinite(w).all():
        raise ValueError("weights contains NaN or inf values")
    if (w < 0).any() or w.sum() <= 0:
        raise ValueError("weights must be non-negative with a positive sum")


def check_probs(feature_probs: Tensor | None, d: int) -> None:
    """Refuse feature probabilities p(Z_i) that are not None or a (d,) distribution (a host read)."""
    if feature_probs is None:
        return
    if not isinstance(feature_probs, Tensor) or feature_probs.shape != (d,):
        shape = tuple(feature_probs.shape) if isinstance(feature_probs, Tensor) else type(feature_probs)
        raise ValueError(f"feature_probs must be a tensor of shape ({d},), got {shape}")
    p = feature_probs.detach().double()
    if not torch.isfinite(p).all() or (p < 0).any() or abs(p.sum().item() - 1.0) > 1e-4:
        raise ValueError("feature_probs must be finite, non-negative and sum to 1")


def check_domains(domains: Tensor, n: int) -> None:
    """Refuse domain labels that are not an integer (n,) tensor (their values are checked where they are used)."""
    if not isinstance(domains, Tensor) or domains.shape != (n,):
        shape = tuple(domains.shape) if isinstance(domains, Tensor) else type(domains).__name__
        raise ValueError(f"domains must be a tensor of shape ({n},), got {shape}")
    if domains.is_floating_point() or domains.is_complex() or domains.dtype == torch.bool:
        raise TypeError(f"domains must be an integer tensor of domain labels, got {domains.dtype}")
