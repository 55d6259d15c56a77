"""Replay buffer that remembers which environment (domain) each transition came from."""

from __future__ import annotations

from typing import Any, NamedTuple

import numpy as np
import torch as th
from gymnasium import spaces
from stable_baselines3.common.buffers import ReplayBuffer
from stable_baselines3.common.vec_env import VecNormalize


class DomainReplayBufferSamples(NamedTuple):
    """SB3's ``ReplayBufferSamples`` plus the domain label of each sample, so SAC's code keeps working."""

    observations: th.Tensor
    actions: th.Tensor
    next_observations: th.Tensor
    dones: th.Tensor
    rewards: th.Tensor
    discounts: th.Tensor | None = None
    domains: th.Tensor | None = None


class DomainReplayBuffer(ReplayBuffer):
    """
    Replay buffer that stores the domain label of each transition.

    The label comes from ``info["domain"]`` (set by every ``sgfd_envs`` env); when an env does not
    provide one, the index of the sub-env in the VecEnv is used, so a VecEnv built with one sub-env
    per domain needs nothing more.

    :param buffer_size: Max number of transitions (over all envs)
    :param observation_space: Observation space
    :param action_space: Action space
    :param device: PyTorch device
    :param n_envs: Number of parallel environments
    :param optimize_memory_usage: SB3's memory-efficient variant (next obs read from the next slot)
    :param handle_timeout_termination: Treat time-limit truncation as non-terminal
    """

    domains: np.ndarray

    def __init__(
        self,
        buffer_size: int,
        observation_space: spaces.Space,
        action_space: spaces.Space,
        device: th.device | str = "auto",
        n_envs: int = 1,
        optimize_memory_usage: bool = False,
        handle_timeout_termination: bool = True,
    ):
        super().__init__(
            buffer_size,
            observation_space,
            action_space,
            device=device,
            n_envs=n_envs,
            optimize_memory_usage=optimize_memory_usage,
            handle_timeout_termination=handle_timeout_termination,
        )
        self.domains = np.zeros((self.buffer_size, self.n_envs), dtype=np.int64)

    def add(
        self,
        obs: np.ndarray,
        next_obs: np.ndarray,
        action: np.ndarray,
        reward: np.ndarray,
        done: np.ndarray,
        infos: list[dict[str, Any]],
    ) -> None:
        # Written before super().add() because that call advances self.pos.
        self.domains[self.pos] = domain_labels(infos)
        super().add(obs, next_obs, action, reward, done, infos)

    def _get_samples(self, batch_inds: np.ndarray, env: VecNormalize | None = None) -> DomainReplayBufferSamples:
        # Same draws in the same order as ReplayBuffer._get_samples, so SGFD_SAC and SAC see the same
        # batches under the same seed.
        env_indices = np.random.randint(0, high=self.n_envs, size=(len(batch_inds),))
        if self.optimize_memory_usage:
            next_obs = self.observations[(batch_inds + 1) % self.buffer_size, env_indices, :]
        else:
            next_obs = self.next_observations[batch_inds, env_indices, :]
        data = (
            self._normalize_obs(self.observations[batch_inds, env_indices, :], env),
            self.actions[batch_inds, env_indices, :],
            self._normalize_obs(next_obs, env),
            (self.dones[batch_inds, env_indices] * (1 - self.timeouts[batch_inds, env_indices])).reshape(-1, 1),
            self._normalize_reward(self.rewards[batch_inds, env_indices].reshape(-1, 1), env),
        )
        return DomainReplayBufferSamples(
            *map(self.to_torch, data), domains=self.to_torch(self.domains[batch_inds, env_indices])
        )

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
