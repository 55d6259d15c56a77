"""Small pieces EncoderSAC's loop and the agents share: a weighted mean, soft updates of parameter pairs, an image
space's shape."""

from __future__ import annotations

import torch as th
from gymnasium import spaces


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


def image_shape(space: spaces.Space) -> tuple[int, int, int]:
    """(C, H, W) of a channel-first image observation space."""
    if not isinstance(space, spaces.Box) or len(space.shape) != 3:
        raise ValueError(f"expected a (C, H, W) image observation space, got {space}")
    return tuple(int(size) for size in space.shape)  # type: ignore[return-value]
