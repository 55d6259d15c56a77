"""n-step returns of sampled transitions, as SB3's ``NStepReplayBuffer`` computes them (SAC's ``n_steps``), from
a ring buffer's rewards and episode ends: pure numpy."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np


class NStepTargets(NamedTuple):
    """What the n-step target of each sampled transition t needs.

    :param slots: the slots t, t + 1, ..., t + n_steps - 1 of each sample, shape (n, n_steps)
    :param reward_weights: gamma^k for the rewards r_{t+k} in the return (k <= m), else 0, shape (n, n_steps): the
        return is the sum of the rewards at ``slots`` times these
    :param last_slots: slot of the last transition t + m in the return (its next observation bootstraps)
    :param dones: whether the episode terminated at t + m (not a time-limit truncation), shape (n, 1)
    :param discounts: gamma^(m + 1), the discount of the bootstrapped value, shape (n, 1)
    """

    slots: np.ndarray
    reward_weights: np.ndarray
    last_slots: np.ndarray
    dones: np.ndarray
    discounts: np.ndarray


def n_step_targets(
    batch_inds: np.ndarray,
    env_indices: np.ndarray,
    *,
    dones: np.ndarray,
    timeouts: np.ndarray,
    newest_slot: int,
    buffer_size: int,
    n_steps: int,
    gamma: float,
) -> NStepTargets:
    """Where the n-step return of each sampled (slot, env) comes from: up to ``n_steps`` rewards of the same env,
    stopping after the first transition that ends its episode (terminated or truncated) and at the newest stored
    transition, whose next observation then bootstraps, as for a truncation.

    :param batch_inds: slots of the sampled transitions, shape (n,)
    :param env_indices: their envs, shape (n,)
    :param dones: its done flags (terminated or truncated), (buffer_size, n_envs)
    :param timeouts: its time-limit flags, (buffer_size, n_envs)
    :param newest_slot: the slot of the newest stored transition
    :param buffer_size: slots in the ring
    :param n_steps: the most rewards summed
    :param gamma: the discount
    """
    steps = np.arange(n_steps)
    slots = (batch_inds[:, None] + steps) % buffer_size
    envs = env_indices[:, None]
    # transitions stored after t, up to the newest: beyond it the ring holds older data
    after = (newest_slot - batch_inds) % buffer_size
    beyond_newest = steps[None, :] > after[:, None]
    ends = dones[slots, envs].astype(bool) | beyond_newest
    ends[:, -1] = True
    # m: the first step that ends the sum (its own reward still counts, unless it lies beyond the newest)
    last = np.argmax(ends, axis=1)
    last = np.where(beyond_newest[np.arange(len(last)), last], last - 1, last)
    included = steps[None, :] <= last[:, None]
    last_slots = slots[np.arange(len(last)), last]
    terminated = dones[last_slots, env_indices] * (1 - timeouts[last_slots, env_indices])
    # The powers of gamma in float32, as SB3 takes them: the same returns and discounts to the bit.
    gamma32 = np.float32(gamma)
    return NStepTargets(
        slots=slots,
        reward_weights=gamma32 ** steps[None, :].astype(np.float32) * included,
        last_slots=last_slots,
        dones=terminated.reshape(-1, 1).astype(np.float32),
        discounts=(gamma32 ** (last + 1).astype(np.float32)).reshape(-1, 1),
    )
