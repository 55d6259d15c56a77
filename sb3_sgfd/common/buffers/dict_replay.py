"""The domain replay buffer for Dict observations (SB3's ``MultiInputPolicy``): SB3's ``DictReplayBuffer`` that also
stores each transition's domain label, refuses a bad transition where it enters, and returns the labels."""

from __future__ import annotations

from typing import Any, NamedTuple

import numpy as np
import torch as th
from gymnasium import spaces
from stable_baselines3.common.buffers import DictReplayBuffer
from stable_baselines3.common.vec_env import VecNormalize

from sb3_sgfd.common.buffers.replay import distinct_labels, domain_labels
from sb3_sgfd.common.validation import check_positive_int, check_transitions


class DomainDictReplayBufferSamples(NamedTuple):
    """SB3's ``DictReplayBufferSamples`` plus the domain label of each sample."""

    observations: dict[str, th.Tensor]
    actions: th.Tensor
    next_observations: dict[str, th.Tensor]
    dones: th.Tensor
    rewards: th.Tensor
    discounts: th.Tensor | None = None
    domains: th.Tensor | None = None
    same_episode_observations: th.Tensor | None = None


class DomainDictReplayBuffer(DictReplayBuffer):
    """
    :class:`~sb3_sgfd.common.buffers.DomainReplayBuffer` for Dict observation spaces: the label of each transition
    from ``info["domain"]`` (else the sub-env's index), a non-finite value or a label outside [0, n_domains)
    refused at ``add``. What the flat buffer adds beyond that (frames stored once, episodes for TED, n-step
    returns) is refused in one line, as SB3 refuses n-step returns for Dict observations.

    Takes the arguments of SB3's ``DictReplayBuffer``, plus:

    :param n_domains: Number of domain labels; None: any non-negative label
    """

    def __init__(
        self,
        buffer_size: int,
        observation_space: spaces.Dict,
        action_space: spaces.Space,
        device: th.device | str = "auto",
        n_envs: int = 1,
        optimize_memory_usage: bool = False,
        handle_timeout_termination: bool = True,
        n_domains: int | None = None,
        frame_stack: int | None = None,
        same_episode_negatives: bool = False,
        n_steps: int = 1,
        gamma: float = 0.99,
    ) -> None:
        for name, value, plain in (
            ("frame_stack", frame_stack, None),
            ("same_episode_negatives", same_episode_negatives, False),
            ("n_steps", n_steps, 1),
        ):
            if value != plain:
                raise ValueError(
                    f"{name}={value!r} is not available for Dict observations (the domain buffer of "
                    f"flat and image observations has it); got a Dict observation space"
                )
        if n_domains is not None:
            check_positive_int(n_domains=n_domains)
        self.n_domains = n_domains
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
        self._n_adds = 0

    def stored_domains(self) -> np.ndarray:
        """The distinct domain labels among the transitions stored so far."""
        return distinct_labels(self.domains, self.size())

    def add(  # type: ignore[override]
        self,
        obs: dict[str, np.ndarray],
        next_obs: dict[str, np.ndarray],
        action: np.ndarray,
        reward: np.ndarray,
        done: np.ndarray,
        infos: list[dict[str, Any]],
    ) -> None:
        labels = domain_labels(infos)
        check_transitions(
            observations=self._float_parts(obs),
            next_observations=self._float_parts(next_obs),
            actions=action,
            rewards=reward,
            domains=labels,
            n_domains=self.n_domains,
            add_index=self._n_adds,
        )
        self.domains[self.pos] = labels
        super().add(obs, next_obs, action, reward, done, infos)
        self._n_adds += 1

    def _float_parts(self, observation: dict[str, np.ndarray]) -> np.ndarray:
        """The floating-point entries of a Dict observation side by side, one row per sub-env, so that one check
        covers every key (integer entries, such as images, are finite)."""
        rows = [np.asarray(part).reshape(self.n_envs, -1) for part in observation.values()]
        floats = [part for part in rows if part.dtype.kind in "fc"]
        return np.concatenate(floats, axis=1) if floats else np.zeros((self.n_envs, 0), dtype=np.float32)

    def _get_samples(  # type: ignore[override]
        self, batch_inds: np.ndarray, env: VecNormalize | None = None
    ) -> DomainDictReplayBufferSamples:
        # The draws of SB3's DictReplayBuffer, in the same order: the same batches under the same seed.
        env_indices = np.random.randint(0, high=self.n_envs, size=(len(batch_inds),))
        obs = self._normalize_obs({key: o[batch_inds, env_indices, :] for key, o in self.observations.items()}, env)
        next_obs = self._normalize_obs(
            {key: o[batch_inds, env_indices, :] for key, o in self.next_observations.items()}, env
        )
        dones = self.dones[batch_inds, env_indices] * (1 - self.timeouts[batch_inds, env_indices])
        rewards = self._normalize_reward(self.rewards[batch_inds, env_indices].reshape(-1, 1), env)
        return DomainDictReplayBufferSamples(
            observations={key: self.to_torch(o) for key, o in obs.items()},  # type: ignore[union-attr]
            actions=self.to_torch(self.actions[batch_inds, env_indices]),
            next_observations={key: self.to_torch(o) for key, o in next_obs.items()},  # type: ignore[union-attr]
            dones=self.to_torch(dones.reshape(-1, 1)),
            rewards=self.to_torch(rewards),
            domains=self.to_torch(self.domains[batch_inds, env_indices]),
        )
