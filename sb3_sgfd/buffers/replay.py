"""Replay buffer that remembers which environment (domain) each transition came from."""

from __future__ import annotations

import warnings
from typing import Any, NamedTuple

import numpy as np
import torch as th
from gymnasium import spaces
from stable_baselines3.common.buffers import ReplayBuffer
from stable_baselines3.common.preprocessing import get_obs_shape
from stable_baselines3.common.vec_env import VecNormalize

from sb3_sgfd.transfer import BatchTransfer
from sb3_sgfd.validation import check_positive_int, check_transitions

try:
    import psutil
except ImportError:  # pragma: no cover - psutil comes with SB3's usual installs
    psutil = None


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

    Every ``add`` refuses a non-finite observation, action or reward and a label out of range, naming the
    sub-env, its domain and the add (:func:`sb3_sgfd.validation.check_transitions`): nothing bad is stored, so
    nothing bad reaches a checkpoint.
    """

    domains: np.ndarray
    episodes: np.ndarray
    same_episode_negatives: bool
    frame_stack: int | None
    frames: np.ndarray
    history: np.ndarray
    has_side_frame: np.ndarray
    side_frames: dict[tuple[int, int], np.ndarray]

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
    ):
        if n_domains is not None:
            check_positive_int(n_domains=n_domains)
        self.n_domains = n_domains
        if not isinstance(same_episode_negatives, (bool, np.bool_)):
            raise ValueError(f"same_episode_negatives must be a bool, got {same_episode_negatives!r}")
        self.frame_stack = _check_frame_stack(frame_stack, observation_space, optimize_memory_usage)
        # With frame_stack the parent gets a zero-size observation space, so that neither its
        # allocation nor its memory warning concerns full stacks; the real space is put back below.
        parent_space = observation_space if self.frame_stack is None else _EMPTY_SPACE
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
        # Before the frame storage: its memory check counts these arrays too.
        self._init_episode_tracking()
        if self.frame_stack is not None:
            self.observation_space = observation_space
            self.obs_shape = get_obs_shape(observation_space)  # type: ignore[assignment]
            self._init_frame_storage(observation_space)  # type: ignore[arg-type]
        self.same_episode_negatives = bool(same_episode_negatives)
        # Seeded from the global RNG only when used, so that a buffer without it leaves the global stream (and
        # thus every batch) exactly as before; later draws never touch the global RNG.
        self._negatives_rng = (
            np.random.default_rng(np.random.randint(2**31 - 1)) if self.same_episode_negatives else None
        )

    def __setstate__(self, state: dict[str, Any]) -> None:
        # Buffers pickled before frame_stack existed stored observations as they are.
        state.setdefault("frame_stack", None)
        # Buffers pickled before episode tracking existed: no negatives, episodes rebuilt from the done flags.
        state.setdefault("same_episode_negatives", False)
        state.setdefault("_negatives_rng", None)
        state.setdefault("n_domains", None)
        self.__dict__.update(state)
        if "episodes" not in state:
            self._rebuild_episodes()

    def _init_episode_tracking(self) -> None:
        """Allocate the episode bookkeeping, for an empty buffer."""
        # episodes[slot, env]: id of the episode of the transition stored at (slot, env)
        self.episodes = np.zeros((self.buffer_size, self.n_envs), dtype=np.int64)
        # Add index (counted over the buffer's life, through resets) of the first and last transition of each
        # episode, by id; the arrays double when full, so that an add costs O(n_envs).
        self._episode_first = np.zeros(16, dtype=np.int64)
        self._episode_last = np.zeros(16, dtype=np.int64)
        self._n_episodes = 0
        # Add index of the next add: the transition added at index t sits in slot (t - _n_adds + pos) % buffer_size.
        self._n_adds = 0
        self._current_episode = np.zeros(self.n_envs, dtype=np.int64)
        # False where the env's last add ended its episode (or none came yet): its next add starts one.
        self._episode_open = np.zeros(self.n_envs, dtype=bool)

    def _track_episodes(self, slot: int, done: np.ndarray) -> None:
        """
        Record the transitions just written to ``slot`` in the episode bookkeeping.

        :param slot: The slot written by this add
        :param done: Done flag of each env, shape (n_envs,), bool
        """
        starting = np.flatnonzero(~self._episode_open)
        if len(starting) > 0:
            n_episodes = self._n_episodes + len(starting)
            if n_episodes > len(self._episode_first):
                capacity = max(n_episodes, 2 * len(self._episode_first))
                self._episode_first = _grown(self._episode_first, capacity)
                self._episode_last = _grown(self._episode_last, capacity)
            ids = np.arange(self._n_episodes, n_episodes)
            self._episode_first[ids] = self._n_adds
            self._current_episode[starting] = ids
            self._n_episodes = n_episodes
        self._episode_last[self._current_episode] = self._n_adds
        self.episodes[slot] = self._current_episode
        self._episode_open = ~done
        self._n_adds += 1

    def _rebuild_episodes(self) -> None:
        """Episode bookkeeping of a buffer pickled without it, from the stored done flags (one vectorised pass)."""
        self._init_episode_tracking()
        n_stored = self.buffer_size if self.full else self.pos
        if n_stored == 0:
            return
        chronological = (self.pos - n_stored + np.arange(n_stored)) % self.buffer_size
        ended = self.dones[chronological] != 0
        # The oldest stored transition of each column starts an episode (as far as the buffer knows).
        starts = np.ones_like(ended)
        starts[1:] = ended[:-1]
        # Ids numbered column after column; cumsum flattens starts.T row by row, i.e. one env after the other.
        ids = (np.cumsum(starts.T) - 1).reshape(self.n_envs, n_stored).T
        n_episodes = int(ids[-1, -1]) + 1
        rows = np.broadcast_to(np.arange(n_stored)[:, None], ids.shape)
        capacity = max(n_episodes, len(self._episode_first))
        self._episode_first = np.zeros(capacity, dtype=np.int64)
        self._episode_last = np.zeros(capacity, dtype=np.int64)
        self._episode_first[ids[starts]] = rows[starts]
        np.maximum.at(self._episode_last, ids.ravel(), rows.ravel())
        self._n_episodes = n_episodes
        # Add indices count from the oldest stored transition: row r of `chronological` was added at index r.
        self._n_adds = n_stored
        self.episodes[chronological] = ids
        self._current_episode = ids[-1].copy()
        self._episode_open = ~ended[-1]

    def _init_frame_storage(self, observation_space: spaces.Box) -> None:
        """
        Allocate the per-frame storage used with ``frame_stack``.

        :param observation_space: The stacked observation space (checked by ``_check_frame_stack``)
        """
        assert self.frame_stack is not None
        n_frames, dtype = self.frame_stack, observation_space.dtype
        self._channels = self.obs_shape[0] // n_frames
        frame_shape = (self._channels, *self.obs_shape[1:])
        self._empty_obs = np.zeros((self.n_envs, 0), dtype=dtype)
        # frames[slot, env]: newest frame of the observation stored at (slot, env)
        self.frames = np.zeros((self.buffer_size, self.n_envs, *frame_shape), dtype=dtype)
        # history[slot, env]: how many frames of that observation come before its newest one (the
        # others are the zero padding of an episode start); they sit at slot - 1, ..., slot - history
        self.history = np.zeros((self.buffer_size, self.n_envs), dtype=np.min_scalar_type(n_frames - 1))
        # Last frame of next_obs where it is not frames[slot + 1, env]; has_side_frame allows
        # vectorised lookups, and both are cleared when their slot is overwritten.
        self.side_frames = {}
        self.has_side_frame = np.zeros((self.buffer_size, self.n_envs), dtype=bool)
        # State of the newest transition: its next_obs (whose last frame is that transition's next
        # frame until the following add), to tell whether the next obs continues it.
        self._last_next_obs = np.zeros((self.n_envs, *self.obs_shape), dtype=dtype)
        self._last_done = np.ones(self.n_envs, dtype=bool)
        self._last_history = np.zeros(self.n_envs, dtype=self.history.dtype)
        self._last_slot: int | None = None

        if psutil is not None:
            needed = self.storage_nbytes()
            available = psutil.virtual_memory().available
            if needed > available:
                warnings.warn(
                    "This system does not have apparently enough memory to store the complete "
                    f"replay buffer {needed / 1e9:.2f}GB > {available / 1e9:.2f}GB",
                    stacklevel=3,
                )

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
            add_index=self._n_adds,
        )
        ended = ended.reshape(self.n_envs) != 0
        if self.frame_stack is None:
            # Read before super().add() because that call advances self.pos.
            slot = self.pos
            self.domains[slot] = labels
            super().add(obs, next_obs, action, reward, done, infos)
            self._track_episodes(slot, ended)
            return

        obs, next_obs = self._as_stacks(obs, "obs"), self._as_stacks(next_obs, "next_obs")
        continuing = self._check_stacks(obs, next_obs)

        slot = self.pos
        self.domains[slot] = labels
        # Actions, rewards, dones, timeouts and the ring position are the parent's business.
        super().add(self._empty_obs, self._empty_obs, action, reward, done, infos)

        for env_idx in np.flatnonzero(self.has_side_frame[slot]):
            del self.side_frames[(slot, int(env_idx))]
        self.has_side_frame[slot] = False
        last = self._last_slot
        # With a single slot, the previous transition is the one overwritten now.
        if last is not None and last != slot:
            for env_idx in np.flatnonzero(~continuing):
                self.side_frames[(last, int(env_idx))] = self._last_next_obs[env_idx, -self._channels :].copy()
                self.has_side_frame[last, env_idx] = True

        history = np.where(continuing, np.minimum(self._last_history.astype(np.intp) + 1, self.frame_stack - 1), 0)
        self.frames[slot] = obs[:, -self._channels :]
        self.history[slot] = history
        self._last_history[:] = history
        self._last_next_obs[:] = next_obs
        self._last_done[:] = ended
        self._last_slot = slot
        self._track_episodes(slot, ended)

    def _as_stacks(self, stacks: np.ndarray, name: str) -> np.ndarray:
        """
        ``stacks`` as an array of shape (n_envs, *obs_shape) in the observation dtype.

        :param stacks: One stacked observation per env
        :param name: Argument name for the error message
        """
        array = np.asarray(stacks)
        expected = (self.n_envs, *self.obs_shape)
        if array.shape != expected:
            raise ValueError(f"{name} must have shape (n_envs, *observation_space.shape) {expected}, got {array.shape}")
        return array.astype(self.observation_space.dtype, copy=False)

    def _check_stacks(self, obs: np.ndarray, next_obs: np.ndarray) -> np.ndarray:
        """
        Check that obs and next_obs are frame stacks as VecFrameStack makes them.

        :param obs: Stacked observations, one per env
        :param next_obs: Stacked next observations (terminal observation for done envs)
        :return: For each env, whether obs continues the env's previous transition
        """
        assert self.frame_stack is not None
        channels, n_envs = self._channels, self.n_envs
        shifted = (next_obs[:, :-channels] == obs[:, channels:]).reshape(n_envs, -1).all(axis=1)
        if not shifted.all():
            raise ValueError(
                f"next_obs of env(s) {np.flatnonzero(~shifted).tolist()} is not obs shifted by one frame: with "
                f"frame_stack={self.frame_stack}, next_obs[:, :-{channels}] must equal obs[:, {channels}:] (SB3's "
                "VecFrameStack, with info['terminal_observation'] as next_obs of a done env)"
            )
        continuing = ~self._last_done & (obs == self._last_next_obs).reshape(n_envs, -1).all(axis=1)
        padded = (obs[:, :-channels] == 0).reshape(n_envs, -1).all(axis=1)
        broken = ~continuing & ~padded
        if broken.any():
            raise ValueError(
                f"obs of env(s) {np.flatnonzero(broken).tolist()} neither continues that env's previous transition "
                "(equal to its next_obs, not done) nor starts an episode (all frames but the newest zero): "
                f"frame_stack={self.frame_stack} expects observations stacked by SB3's VecFrameStack"
            )
        return continuing

    def reset(self) -> None:
        super().reset()
        # The episode bookkeeping is kept: an episode may go on after a reset. Add indices keep counting, so
        # that the stored part of every episode stays known.
        if self.frame_stack is not None:
            self.side_frames.clear()
            self.has_side_frame[:] = False
            # The continuity state is kept: an episode may go on after a reset, its older frames
            # are just no longer stored (see is_sampleable).
            self._last_slot = None

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
        batch_inds, env_indices = np.asarray(batch_inds), np.asarray(env_indices)
        if batch_inds.shape != env_indices.shape:
            raise ValueError(f"env_indices must have batch_inds' shape {batch_inds.shape}, got {env_indices.shape}")
        upper = self.buffer_size if self.full else self.pos
        in_range = (batch_inds >= 0) & (batch_inds < upper) & (env_indices >= 0) & (env_indices < self.n_envs)
        if self.optimize_memory_usage and self.full:
            in_range &= batch_inds != self.pos
        if self.frame_stack is None or not in_range.any():
            return in_range
        slots, envs = np.where(in_range, batch_inds, 0), np.where(in_range, env_indices, 0)
        # Number of stored transitions older than each slot (0 for the oldest, at self.pos once full)
        older = (slots - self.pos) % self.buffer_size if self.full else slots
        return in_range & (older >= self.history[slots, envs])

    def _get_samples(
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

        if self.frame_stack is not None:
            obs, next_obs = self._rebuild_stacks(batch_inds, env_indices)
        else:
            obs = self.observations[batch_inds, env_indices, :]
            if self.optimize_memory_usage:
                next_obs = self.observations[(batch_inds + 1) % self.buffer_size, env_indices, :]
            else:
                next_obs = self.next_observations[batch_inds, env_indices, :]
        data = (
            self._normalize_obs(obs, env),
            self.actions[batch_inds, env_indices, :],
            self._normalize_obs(next_obs, env),
            (self.dones[batch_inds, env_indices] * (1 - self.timeouts[batch_inds, env_indices])).reshape(-1, 1),
            self._normalize_reward(self.rewards[batch_inds, env_indices].reshape(-1, 1), env),
        )
        arrays = [*data, self.domains[batch_inds, env_indices]]
        if self.same_episode_negatives:
            other_slots, other_envs = self._same_episode_indices(batch_inds, env_indices)
            arrays.append(self._normalize_obs(self._observations_at(other_slots, other_envs), env))
        # Every array here is the batch's own gather (or rebuilt stack): one transfer, no defensive copies.
        tensors = self._batch_transfer(arrays)
        return DomainReplayBufferSamples(
            *tensors[:5],
            domains=tensors[5],
            same_episode_observations=tensors[6] if self.same_episode_negatives else None,
        )

    @property
    def _batch_transfer(self) -> BatchTransfer:
        # Made on first use, and again when the buffer moves (SB3's load_replay_buffer sets the model's device).
        transfer = getattr(self, "_transfer", None)
        if transfer is None or transfer.device != th.device(self.device):
            transfer = self._transfer = BatchTransfer(self.device)
        return transfer

    def episode_ids(self, batch_inds: np.ndarray, env_indices: np.ndarray) -> np.ndarray:
        """
        Id of the episode of each stored transition; two transitions share an episode iff they share its id.

        :param batch_inds: Slots
        :param env_indices: Env indices, same shape as ``batch_inds``
        :return: int64 array of that shape
        """
        batch_inds, env_indices = np.asarray(batch_inds), np.asarray(env_indices)
        if batch_inds.shape != env_indices.shape:
            raise ValueError(f"env_indices must have batch_inds' shape {batch_inds.shape}, got {env_indices.shape}")
        upper = self.buffer_size if self.full else self.pos
        stored = (batch_inds >= 0) & (batch_inds < upper) & (env_indices >= 0) & (env_indices < self.n_envs)
        if not stored.all():
            bad = np.flatnonzero(~stored.ravel())[:5]
            pairs = list(zip(batch_inds.ravel()[bad].tolist(), env_indices.ravel()[bad].tolist(), strict=True))
            raise ValueError(f"(batch_inds, env_indices) pairs {pairs} hold no stored transition")
        return self.episodes[batch_inds, env_indices].copy()

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

    def _observations_at(self, batch_inds: np.ndarray, env_indices: np.ndarray) -> np.ndarray:
        """``observations_at`` without the checks, for pairs known to be sampleable."""
        if self.frame_stack is None:
            return self.observations[batch_inds, env_indices]
        # As _rebuild_stacks does for obs: the frames k - 1, ..., 0 slots back, zeros before the episode start.
        offsets = np.arange(self.frame_stack - 1, -1, -1)
        slots = (batch_inds[:, None] - offsets) % self.buffer_size
        stacks = self.frames[slots, env_indices[:, None]]
        padding = offsets > self.history[batch_inds, env_indices][:, None].astype(np.intp)
        if padding.any():
            stacks[padding] = 0
        return stacks.reshape((len(batch_inds), *self.obs_shape))

    def _add_indices(self, slots: np.ndarray) -> np.ndarray:
        """Add index of the transitions stored in ``slots`` (the newest sits at pos - 1, and so on back)."""
        return self._n_adds - 1 - (self.pos - 1 - slots) % self.buffer_size

    def _slots(self, add_indices: np.ndarray) -> np.ndarray:
        """Slot of the stored transitions added at ``add_indices``."""
        return (add_indices - self._n_adds + self.pos) % self.buffer_size

    def _first_sampleable(self) -> np.ndarray:
        """
        For each env, the add index of its oldest sampleable transition (``_n_adds`` if it has none).

        A column's sampleable transitions are all its stored ones from that index on: a stack's history grows by
        at most one per add, so (stored transitions older than it) - (its history) never decreases along the
        column. Only the oldest k - 1 may miss frames (and with optimize_memory_usage the oldest one lost its
        observation), so the first k + 1 stored slots decide.
        """
        end = self._n_adds
        n_stored = self.buffer_size if self.full else self.pos
        window = min(n_stored, (self.frame_stack or 1) + 1)
        if window == 0:
            return np.full(self.n_envs, end, dtype=np.int64)
        candidates = end - n_stored + np.arange(window)
        shape = (window, self.n_envs)
        sampleable = self.is_sampleable(
            np.broadcast_to(self._slots(candidates)[:, None], shape), np.broadcast_to(np.arange(self.n_envs), shape)
        )
        return np.where(sampleable.any(axis=0), candidates[sampleable.argmax(axis=0)], end)

    def _same_episode_indices(self, batch_inds: np.ndarray, env_indices: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """
        Slot and env of the same-episode observation o_j of each sample i (see the class docstring), O(batch).

        :param batch_inds: Slots of the samples
        :param env_indices: Envs of the samples
        :return: Slots and envs of the observations, each of shape (batch,)
        """
        assert self._negatives_rng is not None
        rng = self._negatives_rng
        first_sampleable = self._first_sampleable()
        i = self._add_indices(batch_inds)
        episode = self.episodes[batch_inds, env_indices]
        # The episode's sampleable transitions: add indices low..high (its column's are a suffix, its own a run).
        low = np.maximum(self._episode_first[episode], first_sampleable[env_indices])
        high = self._episode_last[episode]
        n_episode = np.maximum(high - low + 1, 0)
        # i - 1, i, i + 1, clipped to [low, high], are excluded: draw among the others, then step over them.
        excluded_low = np.maximum(low, i - 1)
        n_excluded = np.maximum(np.minimum(high, i + 1) - excluded_low + 1, 0)
        n_allowed = n_episode - n_excluded
        j = low + rng.integers(0, np.maximum(n_allowed, 1))
        j = np.where(j >= excluded_low, j + n_excluded, j)
        envs = env_indices.copy()
        fallback = np.flatnonzero(n_allowed <= 0)
        if len(fallback) > 0:
            j[fallback], envs[fallback] = self._other_episode_indices(
                first_sampleable, env_indices[fallback], low[fallback], n_episode[fallback]
            )
        return self._slots(j), envs

    def _other_episode_indices(
        self, first_sampleable: np.ndarray, env_indices: np.ndarray, low: np.ndarray, n_episode: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """
        Add index and env of a transition drawn uniformly among all sampleable ones outside a given episode.

        The sampleable transitions are numbered column after column (each column's a run of add indices); the
        episode's are one run of that numbering, which the draw steps over.

        :param first_sampleable: ``_first_sampleable()``
        :param env_indices: Env of each episode
        :param low: Add index of each episode's oldest sampleable transition
        :param n_episode: Number of each episode's sampleable transitions
        :return: Add indices and envs, each of shape (len(env_indices),)
        """
        assert self._negatives_rng is not None
        counts = self._n_adds - first_sampleable
        ends = np.cumsum(counts)
        starts = ends - counts
        n_others = ends[-1] - n_episode
        if (n_others <= 0).any():
            raise ValueError(
                "same_episode_negatives: a sample's episode has no transition two steps or more away from it, "
                "and the buffer holds no sampleable transition of another episode to use instead"
            )
        flat = self._negatives_rng.integers(0, n_others)
        episode_start = starts[env_indices] + low - first_sampleable[env_indices]
        flat = np.where(flat >= episode_start, flat + n_episode, flat)
        envs = np.searchsorted(ends, flat, side="right")
        return first_sampleable[envs] + flat - starts[envs], envs

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
        upper = self.buffer_size if self.full else self.pos
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

    def _rebuild_stacks(self, batch_inds: np.ndarray, env_indices: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """
        Observation and next observation stacks of sampleable pairs, from the stored frames.

        :param batch_inds: Slots
        :param env_indices: Env indices
        :return: obs and next_obs, each a new C-contiguous array of shape (batch, *obs_shape)
        """
        assert self.frame_stack is not None
        n_frames, channels = self.frame_stack, self._channels
        # Frames `offsets` slots back, oldest first: obs takes the first k, next_obs the last k (whose newest,
        # read from slot + 1, is replaced below where the next frame is stored elsewhere).
        offsets = np.arange(n_frames - 1, -2, -1)
        slots = (batch_inds[:, None] - offsets) % self.buffer_size
        env_column = env_indices[:, None]
        # Two gathers rather than one sequence sliced twice: contiguous results convert to tensors without a copy.
        obs = self.frames[slots[:, :-1], env_column]
        next_obs = self.frames[slots[:, 1:], env_column]

        padding = offsets > self.history[batch_inds, env_indices][:, None].astype(np.intp)
        if padding.any():
            obs[padding[:, :-1]] = 0
            next_obs[padding[:, 1:]] = 0

        newest = np.flatnonzero(batch_inds == self._last_slot)
        if len(newest) > 0:
            next_obs[newest, -1] = self._last_next_obs[env_indices[newest], -channels:]
        for row in np.flatnonzero(self.has_side_frame[batch_inds, env_indices]):
            next_obs[row, -1] = self.side_frames[(int(batch_inds[row]), int(env_indices[row]))]

        stacked_shape = (len(batch_inds), *self.obs_shape)
        return obs.reshape(stacked_shape), next_obs.reshape(stacked_shape)

    def storage_nbytes(self) -> int:
        """Bytes held by the buffer's storage: its arrays, plus, with ``frame_stack``, the side frames."""
        arrays = [self.actions, self.rewards, self.dones, self.timeouts, self.domains, self.observations]
        arrays += [self.episodes, self._episode_first, self._episode_last]
        if not self.optimize_memory_usage:
            arrays.append(self.next_observations)
        if self.frame_stack is not None:
            arrays += [self.frames, self.history, self.has_side_frame, self._last_next_obs]
            arrays += list(self.side_frames.values())
        return sum(array.nbytes for array in arrays)

    def stored_domains(self) -> np.ndarray:
        """The distinct domain labels among the transitions stored so far."""
        upper = self.buffer_size if self.full else self.pos
        return np.unique(self.domains[:upper])


# Observation space handed to ReplayBuffer.__init__ with frame_stack: its arrays then take no memory.
_EMPTY_SPACE = spaces.Box(low=0, high=0, shape=(0,), dtype=np.uint8)


def _grown(array: np.ndarray, capacity: int) -> np.ndarray:
    """``array`` followed by zeros up to ``capacity`` entries."""
    grown = np.zeros(capacity, dtype=array.dtype)
    grown[: len(array)] = array
    return grown


def _check_frame_stack(
    frame_stack: int | None, observation_space: spaces.Space, optimize_memory_usage: bool
) -> int | None:
    """
    ``frame_stack`` after checking it against the other arguments.

    :param frame_stack: Number of stacked frames, or None
    :param observation_space: Observation space of the buffer
    :param optimize_memory_usage: The buffer's optimize_memory_usage
    """
    if frame_stack is None:
        return None
    if isinstance(frame_stack, bool) or not isinstance(frame_stack, (int, np.integer)) or frame_stack < 1:
        raise ValueError(f"frame_stack must be None or a positive integer, got {frame_stack!r}")
    if optimize_memory_usage:
        raise ValueError("optimize_memory_usage=True cannot be combined with frame_stack (it stores each frame once)")
    if not isinstance(observation_space, spaces.Box) or len(observation_space.shape) == 0:
        raise ValueError(
            f"frame_stack needs a Box observation space stacked along its first axis, got {observation_space}"
        )
    if observation_space.shape[0] % frame_stack != 0:
        raise ValueError(
            f"frame_stack={frame_stack} must divide the first (channel) axis of the observation space, "
            f"got shape {observation_space.shape}"
        )
    return int(frame_stack)


def domain_labels(infos: list[dict[str, Any]]) -> np.ndarray:
    """``info["domain"]`` of each sub-env, or the sub-env's index where an env gives no label."""
    labels = np.array([info.get("domain", index) for index, info in enumerate(infos)])
    if labels.dtype.kind not in "iu" or (labels < 0).any():
        raise ValueError(f"info['domain'] must be a non-negative integer for every sub-env, got {labels.tolist()}")
    return labels.astype(np.int64)
