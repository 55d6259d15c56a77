"""(slot, env) pairs that address a replay buffer's storage: the one check every lookup by pair starts with."""

from __future__ import annotations

import numpy as np


def stored_pairs(
    batch_inds: np.ndarray, env_indices: np.ndarray, n_stored: int, n_envs: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``batch_inds`` and ``env_indices`` as arrays, and whether each pair lies in the stored part of the buffer.

    :param batch_inds: Slots
    :param env_indices: Env indices, same shape as ``batch_inds``
    :param n_stored: slots in use (``buffer_size`` once full, else ``pos``)
    :param n_envs: the buffer's number of envs
    :return: the two arrays and a boolean array of their shape
    """
    batch_inds, env_indices = np.asarray(batch_inds), np.asarray(env_indices)
    if batch_inds.shape != env_indices.shape:
        raise ValueError(f"env_indices must have batch_inds' shape {batch_inds.shape}, got {env_indices.shape}")
    stored = (batch_inds >= 0) & (batch_inds < n_stored) & (env_indices >= 0) & (env_indices < n_envs)
    return batch_inds, env_indices, stored
