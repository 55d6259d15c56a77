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
    """

    domains: np.ndarray
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
    ):
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
        if self.frame_stack is not None:
            self.observation_space = observation_space
            self.obs_shape = get_obs_shape(observation_space)  # type: ignore[assignment]
            self._init_frame_storage(observation_space)  # type: ignore[arg-type]

    def __setstate__(self, state: dict[str, Any]) -> None:
        # Buffers pickled before frame_stack existed stored observations as they are.
        state.setdefault("frame_stack", None)
        self.__dict__.update(state)

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
        if self.frame_stack is None:
            # Written before super().add() because that call advances self.pos.
            self.domains[self.pos] = labels
            super().add(obs, next_obs, action, reward, done, infos)
            return

        obs, next_obs = self._as_stacks(obs, "obs"), self._as_stacks(next_obs, "next_obs")
        done = np.asarray(done)
        if done.size != self.n_envs:
            raise ValueError(f"done must hold one flag per env ({self.n_envs}), got shape {done.shape}")
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
        self._last_done[:] = done.reshape(self.n_envs) != 0
        self._last_slot = slot

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
        if self.frame_stack is not None:
            self.side_frames.clear()
            self.has_side_frame[:] = False
            # The continuity state is kept: an episode may go on after a reset, its older frames
            # are just no longer stored (see is_sampleable).
            self._last_slot = None

    def is_sampleable(self, batch_inds: np.ndarray, env_indices: np.ndarray) -> np.ndarray:
        """
        Whether each (slot, env) pair holds a transition that can be sampled: it is stored and, with
        ``frame_stack``, all the frames of its observation stack are still stored.

        :param batch_inds: Slots
        :param env_indices: Env indices, same shape as ``batch_inds``
        :return: Boolean array of that shape
        """
        batch_inds, env_indices = np.asarray(batch_inds), np.asarray(env_indices)
        if batch_inds.shape != env_indices.shape:
            raise ValueError(f"env_indices must have batch_inds' shape {batch_inds.shape}, got {env_indices.shape}")
        upper = self.buffer_size if self.full else self.pos
        in_range = (batch_inds >= 0) & (batch_inds < upper) & (env_indices >= 0) & (env_indices < self.n_envs)
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

        # Stacks rebuilt from frames are new arrays that nothing else references: no copy needed.
        copy_obs = self.frame_stack is None
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
        copies = (copy_obs, True, copy_obs, True, True)
        return DomainReplayBufferSamples(
            *(self.to_torch(array, copy=copy) for array, copy in zip(data, copies, strict=True)),
            domains=self.to_torch(self.domains[batch_inds, env_indices]),
        )

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
