"""Small pieces EncoderSAC's loop and the agents share: a weighted mean, soft updates of parameter pairs, the seeds
of the loop's own generators, an image space's shape."""

from __future__ import annotations

import numpy as np
import torch as th
from gymnasium import spaces
from torch import nn


def weighted_mean(values: th.Tensor, weights: th.Tensor | None) -> th.Tensor:
    """mean(weights * values) over the batch, or the plain mean without weights."""
    return values.mean() if weights is None else (weights * values).mean()


def polyak_pairs(pairs: list[tuple[th.Tensor, th.Tensor]], tau: float) -> None:
    """target <- (1 - tau) target + tau online for each (online, target) pair, in place: SB3's polyak_update as two
    multi-tensor operations (the same arithmetic, element by element)."""
    if not pairs:
        return
    params, targets = [param for param, _ in pairs], [target for _, target in pairs]
    with th.no_grad():
        th._foreach_mul_(targets, 1 - tau)
        th._foreach_add_(targets, params, alpha=tau)


def target_pairs(critic: nn.Module, critic_target: nn.Module) -> tuple[list[tuple[th.Tensor, th.Tensor]], ...]:
    """(online, target) parameters of the critic's encoder, and of its heads, for the soft updates."""
    targets = dict(critic_target.named_parameters())
    encoder, heads = [], []  # type: list[tuple[th.Tensor, th.Tensor]], list[tuple[th.Tensor, th.Tensor]]
    for name, param in critic.named_parameters():
        (encoder if name.startswith("features_extractor.") else heads).append((param, targets[name]))
    return encoder, heads


def derived_seeds(seed: int | None) -> dict[str, int]:
    """Seeds of the generators the additions to SAC draw from, all from the model's seed: one stream, so that one
    addition does not move the others' draws (the sample weighting's, augmentation's, the objective's)."""
    draws = np.random.default_rng(seed).integers(2**31, size=3)
    return {"weighting": int(draws[0]), "augmentation": int(draws[1]), "representation": int(draws[2])}


def image_shape(space: spaces.Space) -> tuple[int, int, int]:
    """(C, H, W) of a channel-first image observation space."""
    if not isinstance(space, spaces.Box) or len(space.shape) != 3:
        raise ValueError(f"expected a (C, H, W) image observation space, got {space}")
    return tuple(int(size) for size in space.shape)  # type: ignore[return-value]
