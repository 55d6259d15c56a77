"""Synthetic encoder-like features with one domain-dependent feature (shared by tests and bench)."""

from __future__ import annotations

from typing import NamedTuple

import torch
from torch import Tensor, nn


class DomainBatch(NamedTuple):
    z: Tensor  # (n, d) features in (-1, 1), like LayerNorm -> tanh encoder outputs
    domains: Tensor  # (n,) int64 domain labels
    top: int  # column of the domain-dependent feature
    tied: list[int]  # columns that depend on it


# The batch's sizes, then its noise and column order.
def make_domain_batch(
    n: int = 128, d: int = 50, n_domains: int = 4, n_tied: int = 4,
    domain_noise: float = 0.15, tie_noise: float = 0.8, seed: int = 0, shuffle: bool = True,
) -> DomainBatch:  # fmt: skip
    """A batch from ``n_domains`` equally-sized domains.

    One feature s is a domain offset plus noise (the domains are almost separable on it); ``n_tied``
    features depend on s (linearly, through tanh, through a quadratic and through a sine, plus noise); the
    other features are independent noise. With the default noise levels the domain feature's mean |Pearson
    r| with its tied features is about 0.63. With ``n_tied=0`` only s tells the domains apart. Everything is
    tanh-squashed, as encoder features are; columns are shuffled.
    """
    if not 0 <= n_tied <= 4 or d < n_tied + 1:
        raise ValueError(f"need 0 <= n_tied <= 4 and d >= n_tied + 1, got n_tied={n_tied}, d={d}")
    g = torch.Generator().manual_seed(seed)

    def noise(*shape: int) -> Tensor:
        return torch.randn(*shape, generator=g)

    domains = torch.arange(n) % n_domains
    offsets = torch.linspace(-1.2, 1.2, n_domains)
    s = offsets[domains] + domain_noise * noise(n)
    ties = [
        0.8 * s + tie_noise * noise(n),
        torch.tanh(2.0 * s) + tie_noise * noise(n),
        0.6 * s**2 + 0.5 * s + tie_noise * noise(n),
        torch.sin(1.5 * s) + tie_noise * noise(n),
    ][:n_tied]
    raw = torch.cat([s.unsqueeze(1), *(t.unsqueeze(1) for t in ties), noise(n, d - 1 - n_tied)], dim=1)
    z = torch.tanh(0.8 * raw)
    order = torch.randperm(d, generator=g) if shuffle else torch.arange(d)
    column_of = torch.argsort(order)  # original feature k now lives in column column_of[k]
    return DomainBatch(
        z=z[:, order],
        domains=domains,
        top=int(column_of[0]),
        tied=[int(column_of[k]) for k in range(1, n_tied + 1)],
    )


class ScaledLogits(nn.Module):
    """A classifier whose logits are multiplied by ``scale``: same decisions, less (or more) confident."""

    def __init__(self, classifier: nn.Module, scale: float) -> None:
        super().__init__()
        self.classifier, self.scale = classifier, scale

    def forward(self, z: Tensor) -> Tensor:
        return self.scale * self.classifier(z)
