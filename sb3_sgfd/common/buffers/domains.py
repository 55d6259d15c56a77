"""Domain labels of :class:`~sb3_sgfd.common.buffers.DomainReplayBuffer`: where they come from, and what is stored."""

from __future__ import annotations

from typing import Any

import numpy as np


class DomainLabelsMixin:
    """
    The domain labels of the stored transitions, ``domains[slot, env]``, which the host allocates and fills at
    each add (from :func:`domain_labels`). Needs from the host: SB3's ``buffer_size``, ``pos`` and ``full``.
    """

    domains: np.ndarray
    # From the host (SB3's BaseBuffer)
    buffer_size: int
    pos: int
    full: bool

    def stored_domains(self) -> np.ndarray:
        """The distinct domain labels among the transitions stored so far."""
        upper = self.buffer_size if self.full else self.pos
        return np.unique(self.domains[:upper])


def domain_labels(infos: list[dict[str, Any]]) -> np.ndarray:
    """``info["domain"]`` of each sub-env, or the sub-env's index where an env gives no label."""
    labels = np.array([info.get("domain", index) for index, info in enumerate(infos)])
    if labels.dtype.kind not in "iu" or (labels < 0).any():
        raise ValueError(f"info['domain'] must be a non-negative integer for every sub-env, got {labels.tolist()}")
    return labels.astype(np.int64)
