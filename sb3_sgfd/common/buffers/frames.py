"""Frame storage of :class:`~sb3_sgfd.common.buffers.DomainReplayBuffer`: each frame of the frame stacks stored once."""

from __future__ import annotations

import warnings
from collections.abc import Callable

import numpy as np
from gymnasium import spaces

try:
    import psutil
except ImportError:  # pragma: no cover - psutil comes with SB3's usual installs
    psutil = None


class FrameStorageMixin:
    """
    Stores, with ``frame_stack=k``, each rendered frame once and rebuilds the observation stacks on sampling
    (the format is in :class:`~sb3_sgfd.common.buffers.DomainReplayBuffer`'s docstring).

    Owns ``frames``, ``history``, ``side_frames``, ``has_side_frame`` and the state of the newest transition
    (``_last_next_obs``, ``_last_done``, ``_last_history``, ``_last_slot``), which the host's ``add`` and ``reset``
    update. Needs from the host: SB3's ``buffer_size``, ``n_envs``, ``pos``, ``full``, ``obs_shape``,
    ``observation_space`` and ``observations``, the checked ``frame_stack`` (``_check_frame_stack``),
    ``is_sampleable`` and ``storage_nbytes``.
    """

    frames: np.ndarray
    history: np.ndarray
    has_side_frame: np.ndarray
    side_frames: dict[tuple[int, int], np.ndarray]
    # From the host: SB3's ReplayBuffer ...
    buffer_size: int
    n_envs: int
    pos: int
    full: bool
    obs_shape: tuple[int, ...]
    observation_space: spaces.Space
    observations: np.ndarray
    # ... and DomainReplayBuffer
    frame_stack: int | None
    is_sampleable: Callable[[np.ndarray, np.ndarray], np.ndarray]
    storage_nbytes: Callable[[], int]

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

    def _rebuild_stacks(
        self, batch_inds: np.ndarray, env_indices: np.ndarray, next_inds: np.ndarray | None = None
    ) -> tuple[np.ndarray, np.ndarray]:
        """
        Observation and next observation stacks of sampleable pairs, from the stored frames.

        :param batch_inds: Slots
        :param env_indices: Env indices
        :param next_inds: Slots whose next observations to rebuild (an n-step return's last transition, in the
            same episode); None: ``batch_inds``
        :return: obs and next_obs, each a new C-contiguous array of shape (batch, *obs_shape)
        """
        assert self.frame_stack is not None
        n_frames, channels = self.frame_stack, self._channels
        # Frames `offsets` slots back, oldest first: obs takes the first k, next_obs the last k (whose newest,
        # read from slot + 1, is replaced below where the next frame is stored elsewhere).
        offsets = np.arange(n_frames - 1, -2, -1)
        slots = (batch_inds[:, None] - offsets) % self.buffer_size
        env_column = env_indices[:, None]
        padding = offsets > self.history[batch_inds, env_indices][:, None].astype(np.intp)
        # Two gathers rather than one sequence sliced twice: contiguous results convert to tensors without a copy.
        obs = self.frames[slots[:, :-1], env_column]
        if next_inds is None or next_inds is batch_inds:
            next_inds, next_slots, next_padding = batch_inds, slots, padding
        else:
            next_slots = (next_inds[:, None] - offsets) % self.buffer_size
            next_padding = offsets > self.history[next_inds, env_indices][:, None].astype(np.intp)
        next_obs = self.frames[next_slots[:, 1:], env_column]

        if padding.any():
            obs[padding[:, :-1]] = 0
        if next_padding.any():
            next_obs[next_padding[:, 1:]] = 0

        newest = np.flatnonzero(next_inds == self._last_slot)
        if len(newest) > 0:
            next_obs[newest, -1] = self._last_next_obs[env_indices[newest], -channels:]
        for row in np.flatnonzero(self.has_side_frame[next_inds, env_indices]):
            next_obs[row, -1] = self.side_frames[(int(next_inds[row]), int(env_indices[row]))]

        stacked_shape = (len(batch_inds), *self.obs_shape)
        return obs.reshape(stacked_shape), next_obs.reshape(stacked_shape)

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
