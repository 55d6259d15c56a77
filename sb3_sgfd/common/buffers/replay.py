"""The replay buffer that remembers which environment (domain) each transition came from: its domain labels, the
buffer (SB3's ``ReplayBuffer`` holding a frame store and an episode index, :mod:`sb3_sgfd.common.buffers.storage`), its
batches, and SAC's n-step returns computed from its rewards and episode ends (:func:`n_step_targets`, as SB3's
``NStepReplayBuffer``)."""

from __future__ import annotations

import warnings
from typing import Any, NamedTuple

import numpy as np
import psutil
import torch as th
from gymnasium import spaces
from stable_baselines3.common.buffers import ReplayBuffer
from stable_baselines3.common.preprocessing import get_obs_shape
from stable_baselines3.common.vec_env import VecNormalize

from sb3_sgfd.common.buffers.old_layouts import held_layout
from sb3_sgfd.common.buffers.storage import EMPTY_SPACE, EpisodeIndex, FrameStore, check_frame_stack, stored_pairs
from sb3_sgfd.common.transfer import BatchTransfer
from sb3_sgfd.common.validation import check_interval, check_positive_int, check_transitions


def distinct_labels(domains: np.ndarray, n_stored: int) -> np.ndarray:
    """The distinct domain labels among the first ``n_stored`` slots of a buffer's labels (slot, env)."""
    return np.unique(domains[:n_stored])


def domain_labels(infos: list[dict[str, Any]]) -> np.ndarray:
    """``info["domain"]`` of each sub-env, or the sub-env's index where an env gives no label."""
    labels = np.array([info.get("domain", index) for index, info in enumerate(infos)])
    if labels.dtype.kind not in "iu" or (labels < 0).any():
        raise ValueError(f"info['domain'] must be a non-negative integer for every sub-env, got {labels.tolist()}")
    return labels.astype(np.int64)


class DomainReplayBufferSamples(NamedTuple):
    """SB3's ``ReplayBufferSamples`` plus the domain label of each sample, so SAC's code keeps working."""

    observations: th.Tensor
    actions: th.Tensor
    next_observations: th.Tensor
    dones: th.Tensor
    rewards: th.Tensor
    discounts: th.Tensor | None = None
    domains: th.Tensor | None = None
    # With same_episode_negatives: for each sample i, an observation o_j of the same episode with |j - i| >= 2
    same_episode_observations: th.Tensor | None = None


class DomainReplayBuffer(ReplayBuffer):
    """
    Replay buffer that stores the domain label of each transition.

    The label comes from ``info["domain"]`` (set by every ``sgfd_envs`` env); when an env does not
    provide one, the index of the sub-env in the VecEnv is used, so a VecEnv built with one sub-env
    per domain needs nothing more.

    With ``frame_stack=k`` the observations must be stacks of ``k`` frames along their first axis, as
    SB3's ``VecFrameStack`` (then ``VecTransposeImage`` for images) makes them: oldest frame first, newest
    last, zeros in place of the frames before an episode's start. Each frame is then stored once (the
    newest frame of every observation, plus the last frame of the next observation where it is not the
    following observation's frame: episode ends, or an env replaced mid-episode), and both stacks are
    rebuilt on sampling, identical to the arrays that were added. ``add`` checks that the observations
    have this structure and raises ``ValueError`` where they do not. Once the buffer wraps, the oldest
    ``k - 1`` transitions of each env may miss frames of their stacks; those are never sampled.

    In that mode ``observations`` and ``next_observations`` are empty placeholders (so that SB3's memory
    check does not count, nor the buffer hold, full stacks); the frames are in ``frames``.

    Episodes are tracked at every add: ``episodes[slot, env]`` is the id of the episode of the transition
    stored there. An env's episode ends with an add where its ``done`` is true (SB3 passes terminated or
    truncated); its next add starts a new one. With ``same_episode_negatives=True`` every sample also holds
    ``same_episode_observations``: for each sample i, the observation o_j stored at a slot j of the same
    episode with |j - i| >= 2 (neither o_{i-1}, o_i nor o_{i+1}, the next observation of i), drawn uniformly
    among the stored, sampleable ones, as TED's same-episode negatives (Dunion et al., ICLR 2023). Where the
    episode has no such slot (at most three of its transitions stored and sampleable, i among the middle ones),
    o_j is drawn uniformly from the sampleable transitions of all other episodes: still a pair that is not
    consecutive. Where there is none either (the buffer holds nothing else), sampling raises ``ValueError``.
    Each draw costs O(1), from the episode's first and last add index; the buffer is never scanned. A run
    resumed with a fresh env and no ``done`` in between counts as one episode: its pairs are still never
    consecutive ones.

    :param buffer_size: Max number of transitions (over all envs)
    :param observation_space: Observation space
    :param action_space: Action space
    :param device: PyTorch device
    :param n_envs: Number of parallel environments
    :param optimize_memory_usage: SB3's memory-efficient variant (next obs read from the next slot);
        not available with ``frame_stack``
    :param handle_timeout_termination: Treat time-limit truncation as non-terminal
    :param frame_stack: Number of frames stacked in each observation, to store each frame once;
        ``None`` stores the observations as they are
    :param same_episode_negatives: Also return, with each sample, a non-adjacent observation of its episode
        (``same_episode_observations``), drawn with the buffer's own numpy generator (seeded once from
        ``np.random`` at construction)
    :param n_domains: Number of domain labels, so that a label outside [0, n_domains) is refused at ``add``
        (EncoderSAC's agents pass their envs' count); None: any non-negative label
    :param n_steps: Rewards in each sample's return, as SB3's ``NStepReplayBuffer`` (SAC's ``n_steps``): up to
        ``n_steps`` discounted rewards of the episode, the next observation and done flag of the last, and
        ``discounts`` = gamma^(steps taken); 1: one-step transitions
    :param gamma: The discount of the n-step returns

    Every ``add`` refuses a non-finite observation, action or reward and a label out of range, naming the
    sub-env, its domain and the add (:func:`sb3_sgfd.common.validation.check_transitions`): nothing bad is stored, so
    nothing bad reaches a checkpoint.
    """

    def __init__(
        self,
        buffer_size: int,
        observation_space: spaces.Space,
        action_space: spaces.Space,
        device: th.device | str = "auto",
        n_envs: int = 1,
        optimize_memory_usage: bool = False,
        handle_timeout_termination: bool = True,
        frame_stack: int | None = None,
        same_episode_negatives: bool = False,
        n_domains: int | None = None,
        n_steps: int = 1,
        gamma: float = 0.99,
    ):
        if n_domains is not None:
            check_positive_int(n_domains=n_domains)
        check_positive_int(n_steps=n_steps)
        check_interval("gamma", gamma, 0.0, 1.0)
        if n_steps > 1 and optimize_memory_usage:
            raise ValueError("n_steps > 1 needs optimize_memory_usage=False (as SB3's NStepReplayBuffer)")
        self.n_domains = n_domains
        self.n_steps, self.gamma = int(n_steps), float(gamma)
        if not isinstance(same_episode_negatives, (bool, np.bool_)):
            raise ValueError(f"same_episode_negatives must be a bool, got {same_episode_negatives!r}")
        self.frame_stack = check_frame_stack(frame_stack, observation_space, optimize_memory_usage)
        # With frame_stack the parent gets a zero-size observation space, so that neither its
        # allocation nor its memory warning concerns full stacks; the real space is put back below.
        parent_space = observation_space if self.frame_stack is None else EMPTY_SPACE
        super().__init__(
            buffer_size,
            parent_space,
            action_space,
            device=device,
            n_envs=n_envs,
            optimize_memory_usage=optimize_memory_usage,
            handle_timeout_termination=handle_timeout_termination,
        )
        self.domains = np.zeros((self.buffer_size, self.n_envs), dtype=np.int64)
        self.same_episode_negatives = bool(same_episode_negatives)
        # Seeded from the global RNG only when used, so that a buffer without it leaves the global stream (and
        # thus every batch) exactly as before; later draws never touch the global RNG.
        rng = np.random.default_rng(np.random.randint(2**31 - 1)) if self.same_episode_negatives else None
        self.episode_index = EpisodeIndex(self.buffer_size, self.n_envs, rng)
        self.frame_store: FrameStore | None = None
        if self.frame_stack is not None:
            self.observation_space = observation_space
            self.obs_shape = get_obs_shape(observation_space)  # type: ignore[assignment]
            self._empty_obs = np.zeros((self.n_envs, 0), dtype=observation_space.dtype)
            self.frame_store = FrameStore(self.buffer_size, self.n_envs, observation_space, self.frame_stack)  # type: ignore[arg-type]
            warn_if_short_of_memory(self.storage_nbytes())

    def __getstate__(self) -> dict[str, Any]:
        # The held parts pickled as their attributes: a saved buffer names no class but this one's (and the batch
        # transfer's), so that the parts can move without old files failing to load.
        state = dict(self.__dict__)
        for name in ("episode_index", "frame_store"):
            if state[name] is not None:
                state[name] = dict(vars(state[name]))
        return state

    def __setstate__(self, state: dict[str, Any]) -> None:
        self.__dict__.update(held_layout(state))  # also a buffer pickled by an earlier version

    def stored_domains(self) -> np.ndarray:
        """The distinct domain labels among the transitions stored so far."""
        return distinct_labels(self.domains, self.size())

    def add(
        self,
        obs: np.ndarray,
        next_obs: np.ndarray,
        action: np.ndarray,
        reward: np.ndarray,
        done: np.ndarray,
        infos: list[dict[str, Any]],
    ) -> None:
        labels = domain_labels(infos)
        ended = np.asarray(done)
        if ended.size != self.n_envs:
            raise ValueError(f"done must hold one flag per env ({self.n_envs}), got shape {ended.shape}")
        check_transitions(
            observations=obs,
            next_observations=next_obs,
            actions=action,
            rewards=reward,
            domains=labels,
            n_domains=self.n_domains,
            add_index=self.episode_index.n_adds,
        )
        ended = ended.reshape(self.n_envs) != 0
        # Read before super().add() because that call advances self.pos.
        slot = self.pos
        self.domains[slot] = labels
        store = self.frame_store
        if store is None:
            super().add(obs, next_obs, action, reward, done, infos)
        else:
            obs, next_obs = store.as_stacks(obs, "obs"), store.as_stacks(next_obs, "next_obs")
            continuing = store.check_stacks(obs, next_obs)
            # Actions, rewards, dones, timeouts and the ring position are the parent's business.
            super().add(self._empty_obs, self._empty_obs, action, reward, done, infos)
            store.add(slot, obs, next_obs, continuing, ended)
        self.episode_index.track(slot, ended)

    def reset(self) -> None:
        super().reset()
        # The episode index is kept: an episode may go on after a reset. Add indices keep counting, so that the
        # stored part of every episode stays known.
        if self.frame_store is not None:
            self.frame_store.reset()

    def is_sampleable(self, batch_inds: np.ndarray, env_indices: np.ndarray) -> np.ndarray:
        """
        Whether each (slot, env) pair holds a transition that can be sampled: it is stored, with
        ``frame_stack`` all the frames of its observation stack are still stored, and with
        ``optimize_memory_usage`` its observation is (once full, slot ``pos`` holds the newest next_obs
        instead: SB3's ``sample`` never draws it).

        :param batch_inds: Slots
        :param env_indices: Env indices, same shape as ``batch_inds``
        :return: Boolean array of that shape
        """
        n_stored = self.buffer_size if self.full else self.pos
        batch_inds, env_indices, in_range = stored_pairs(batch_inds, env_indices, n_stored, self.n_envs)
        if self.optimize_memory_usage and self.full:
            in_range &= batch_inds != self.pos
        if self.frame_store is None or not in_range.any():
            return in_range
        slots, envs = np.where(in_range, batch_inds, 0), np.where(in_range, env_indices, 0)
        # Number of stored transitions older than each slot (0 for the oldest, at self.pos once full)
        older = (slots - self.pos) % self.buffer_size if self.full else slots
        return in_range & self.frame_store.whole(slots, envs, older)

    def _get_samples(  # type: ignore[override]  # a superset of ReplayBufferSamples (SB3: DictReplayBuffer)
        self,
        batch_inds: np.ndarray,
        env: VecNormalize | None = None,
        *,
        env_indices: np.ndarray | None = None,
    ) -> DomainReplayBufferSamples:
        """
        The transitions at (batch_inds, env_indices).

        :param batch_inds: Slots
        :param env: VecNormalize to normalize observations and rewards, if any
        :param env_indices: Env of each sample; drawn uniformly when None (then, with ``frame_stack``, pairs
            that cannot be sampled are drawn again), else every pair must be sampleable
        """
        batch_inds = np.asarray(batch_inds)
        if env_indices is None:
            # Same draws in the same order as ReplayBuffer._get_samples, so SGFD_SAC and SAC see the same
            # batches under the same seed.
            env_indices = np.random.randint(0, high=self.n_envs, size=(len(batch_inds),))
            if self.frame_stack is not None:
                batch_inds, env_indices = self._redraw_unsampleable(batch_inds, env_indices)
        else:
            env_indices = np.asarray(env_indices)
            sampleable = self.is_sampleable(batch_inds, env_indices)
            if not sampleable.all():
                bad = np.flatnonzero(~sampleable)[:5]
                pairs = list(zip(np.asarray(batch_inds)[bad].tolist(), env_indices[bad].tolist(), strict=True))
                raise ValueError(f"(batch_inds, env_indices) pairs {pairs} hold no sampleable transition")

        # The n-step return's last transition gives the next observation; one-step: the sampled one.
        targets = None
        if self.n_steps > 1:
            targets = n_step_targets(
                batch_inds,
                env_indices,
                dones=self.dones,
                timeouts=self.timeouts,
                newest_slot=(self.pos - 1) % self.buffer_size,
                buffer_size=self.buffer_size,
                n_steps=self.n_steps,
                gamma=self.gamma,
            )
        next_inds = batch_inds if targets is None else targets.last_slots
        if self.frame_store is not None:
            obs, next_obs = self.frame_store.rebuild(batch_inds, env_indices, next_inds)
        else:
            obs = self.observations[batch_inds, env_indices, :]
            if self.optimize_memory_usage:  # one-step only (n_steps > 1 refuses it)
                next_obs = self.observations[(batch_inds + 1) % self.buffer_size, env_indices, :]
            else:
                next_obs = self.next_observations[next_inds, env_indices, :]
        discounts = None
        if targets is None:
            dones = (self.dones[batch_inds, env_indices] * (1 - self.timeouts[batch_inds, env_indices])).reshape(-1, 1)
            rewards = self._normalize_reward(self.rewards[batch_inds, env_indices].reshape(-1, 1), env)
        else:
            steps = self._normalize_reward(self.rewards[targets.slots, env_indices[:, None]], env)
            rewards = (steps * targets.reward_weights).sum(axis=1, keepdims=True).astype(np.float32)
            dones, discounts = targets.dones, targets.discounts
        data = (
            self._normalize_obs(obs, env),
            self.actions[batch_inds, env_indices, :],
            self._normalize_obs(next_obs, env),
            dones,
            rewards,
        )
        arrays = [*data, self.domains[batch_inds, env_indices]]
        if self.same_episode_negatives:
            other_slots, other_envs = self._same_episode_indices(batch_inds, env_indices)
            arrays.append(self._normalize_obs(self._observations_at(other_slots, other_envs), env))
        if discounts is not None:
            arrays.append(discounts)
        # Every array here is the batch's own gather (or rebuilt stack): one transfer, no defensive copies.
        tensors = self._batch_transfer(arrays)
        return DomainReplayBufferSamples(  # type: ignore[misc]  # mypy cannot tell *tensors[:5] fills five fields
            *tensors[:5],
            domains=tensors[5],
            same_episode_observations=tensors[6] if self.same_episode_negatives else None,
            discounts=tensors[-1] if discounts is not None else None,
        )

    @property
    def _batch_transfer(self) -> BatchTransfer:
        # Made on first use, and again when the buffer moves (SB3's load_replay_buffer sets the model's device).
        transfer = getattr(self, "_transfer", None)
        if transfer is None or transfer.device != th.device(self.device):
            transfer = self._transfer = BatchTransfer(self.device)
        return transfer

    def observations_at(self, batch_inds: np.ndarray, env_indices: np.ndarray) -> np.ndarray:
        """
        The observations stored at sampleable (slot, env) pairs; with ``frame_stack``, their whole stacks.

        :param batch_inds: Slots, shape (n,)
        :param env_indices: Env indices, shape (n,)
        :return: New array of shape (n, *obs_shape), not normalized
        """
        batch_inds, env_indices = np.asarray(batch_inds), np.asarray(env_indices)
        if batch_inds.ndim != 1:
            raise ValueError(f"batch_inds must be one-dimensional, got shape {batch_inds.shape}")
        sampleable = self.is_sampleable(batch_inds, env_indices)
        if not sampleable.all():
            bad = np.flatnonzero(~sampleable)[:5]
            pairs = list(zip(batch_inds[bad].tolist(), env_indices[bad].tolist(), strict=True))
            raise ValueError(f"(batch_inds, env_indices) pairs {pairs} hold no sampleable transition")
        return self._observations_at(batch_inds, env_indices)

    def storage_nbytes(self) -> int:
        """Bytes held by the buffer's storage: its arrays, the episode index's, and the frame store's."""
        arrays = [self.actions, self.rewards, self.dones, self.timeouts, self.domains, self.observations]
        arrays += self.episode_index.arrays()
        if not self.optimize_memory_usage:
            arrays.append(self.next_observations)
        if self.frame_store is not None:
            arrays += self.frame_store.arrays()
        return sum(array.nbytes for array in arrays)

    def episode_ids(self, batch_inds: np.ndarray, env_indices: np.ndarray) -> np.ndarray:
        """
        Id of the episode of each stored transition; two transitions share an episode iff they share its id.

        :param batch_inds: Slots
        :param env_indices: Env indices, same shape as ``batch_inds``
        :return: int64 array of that shape
        """
        return self.episode_index.ids(batch_inds, env_indices, self.size())

    def _observations_at(self, batch_inds: np.ndarray, env_indices: np.ndarray) -> np.ndarray:
        """``observations_at`` without the checks, for pairs known to be sampleable."""
        if self.frame_store is None:
            return self.observations[batch_inds, env_indices]
        return self.frame_store.stacks_at(batch_inds, env_indices)

    def _same_episode_indices(self, batch_inds: np.ndarray, env_indices: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Slot and env of each sample's same-episode negative (:meth:`EpisodeIndex.negatives`)."""
        window = (self.frame_stack or 1) + 1  # only the oldest k - 1 may miss frames (one its obs, memory-optimised)
        first = self.episode_index.first_sampleable(self.pos, self.size(), window, self.is_sampleable)
        return self.episode_index.negatives(batch_inds, env_indices, self.pos, first)

    def _redraw_unsampleable(self, batch_inds: np.ndarray, env_indices: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """
        Draw again, uniformly, the pairs whose stacks miss frames (at most ``k - 1`` oldest slots per env).

        :param batch_inds: Drawn slots
        :param env_indices: Drawn env indices
        :return: Slots and env indices, all sampleable
        """
        bad = ~self.is_sampleable(batch_inds, env_indices)
        if not bad.any():
            return batch_inds, env_indices
        upper = self.size()
        # Slots with at least k - 1 older stored ones are always sampleable, so only tiny buffers need a look.
        slots = np.arange(upper)
        assert self.frame_stack is not None
        if (
            upper < self.frame_stack
            and not self.is_sampleable(np.repeat(slots, self.n_envs), np.tile(np.arange(self.n_envs), upper)).any()
        ):
            raise ValueError("No stored transition can be sampled: every stored one misses frames of its stack")
        batch_inds, env_indices = batch_inds.copy(), env_indices.copy()
        while bad.any():
            n_bad = int(bad.sum())
            batch_inds[bad] = np.random.randint(0, upper, size=n_bad)
            env_indices[bad] = np.random.randint(0, high=self.n_envs, size=n_bad)
            bad = ~self.is_sampleable(batch_inds, env_indices)
        return batch_inds, env_indices


def warn_if_short_of_memory(needed: int) -> None:
    """SB3's warning that the buffer's storage will not fit in the memory available, for the frame store's arrays
    (SB3 counts only its own)."""
    available = psutil.virtual_memory().available
    if needed > available:
        warnings.warn(
            "This system does not have apparently enough memory to store the complete "
            f"replay buffer {needed / 1e9:.2f}GB > {available / 1e9:.2f}GB",
            stacklevel=3,
        )


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
