"""Small pieces EncoderSAC's loop and the agents share: a weighted mean, soft updates of parameter pairs, the mean
of logged figures in one host read, a finiteness guard, an image space's shape."""

from __future__ import annotations

import math
from collections.abc import Iterable

import torch as th
from gymnasium import spaces


def weighted_mean(values: th.Tensor, weights: th.Tensor | None) -> th.Tensor:
    """mean(weights * values) over the batch, or the plain mean without weights."""
    return values.mean() if weights is None else (weights * values).mean()


def polyak_pairs(pairs: list[tuple[th.Tensor, th.Tensor]], tau: float) -> None:
    """target <- (1 - tau) target + tau online for each (online, target) pair (SB3's polyak_update)."""
    with th.no_grad():
        for param, target_param in pairs:
            target_param.mul_(1 - tau)
            th.add(target_param, param, alpha=tau, out=target_param)


def means_of(figures: Iterable[list[float | th.Tensor]], device: th.device) -> list[float]:
    """The mean of each list of logged figures (0-d tensors on ``device``, or numbers), read in one host transfer."""
    means = [th.stack([th.as_tensor(v, dtype=th.float32, device=device) for v in values]).mean() for values in figures]
    return th.stack(means).tolist() if means else []


def finite(value: float, what: str, update_index: int) -> float:
    """``value``, or a stop naming ``what`` and the update where it became NaN or inf."""
    if not math.isfinite(value):
        raise RuntimeError(f"non-finite {what} ({value}) at update {update_index}; stopping before it spreads")
    return value


def image_shape(space: spaces.Space) -> tuple[int, int, int]:
    """(C, H, W) of a channel-first image observation space."""
    if not isinstance(space, spaces.Box) or len(space.shape) != 3:
        raise ValueError(f"expected a (C, H, W) image observation space, got {space}")
    return tuple(int(size) for size in space.shape)  # type: ignore[return-value]
