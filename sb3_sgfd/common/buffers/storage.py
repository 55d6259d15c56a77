"""What :class:`~sb3_sgfd.common.buffers.DomainReplayBuffer` stores beyond SB3's arrays: each frame of the frame
stacks once (``FrameStorageMixin``), and the episode index with TED's same-episode negatives drawn from it
(``EpisodeIndexMixin``); both address stored transitions by (slot, env) pairs, checked by :func:`stored_pairs`.

The two mixins are parts of that one class (their docstrings say what each needs from it), in a module of their own
so that neither module passes 500 lines."""

from __future__ import annotations

import warnings
from collections.abc import Callable

import numpy as np
from gymnasium import spaces

try:
    import psutil
except ImportError:  # pragma: no cover - psutil comes with SB3's usual installs
    psutil = None


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


# --- Frames stored once ---


class FrameStorageMixin:
    """
    Stores, with ``frame_stack=k``, each rendered frame once and rebuilds the observation stacks on sampling
    (the format is in :class:`~sb3_sgfd.common.buffers.DomainReplayBuffer`'s docstring).

    Owns ``frames``, ``history``, ``side_frames``, ``has_side_frame`` and the state of the newest transition
    (``_last_next_obs``, ``_last_done``, ``_last_history``, ``_last_slot``), which the host's ``add`` and ``reset``
    update. Needs from the host: SB3's ``buffer_size``, ``n_envs``, ``pos``, ``full``, ``obs_shape``,
    ``observation_space`` and ``observations``, the checked ``frame_stack`` (``check_frame_stack``),
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

        :param observation_space: The stacked observation space (checked by ``check_frame_stack``)
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
EMPTY_SPACE = spaces.Box(low=0, high=0, shape=(0,), dtype=np.uint8)


def check_frame_stack(
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


# --- The episode index ---


class EpisodeIndexMixin:
    """
    Tracks, at every add, the episode of each stored transition, and draws from that index TED's same-episode
    negatives in O(batch) (the rules are in :class:`~sb3_sgfd.common.buffers.DomainReplayBuffer`'s docstring).

    Owns ``episodes``, the first and last add index of each episode (``_episode_first``, ``_episode_last``), the
    add count ``_n_adds`` and each env's open episode. Needs from the host: SB3's ``buffer_size``, ``n_envs``,
    ``pos``, ``full`` and ``dones``, ``frame_stack``, ``is_sampleable``, and, for the negatives,
    ``same_episode_negatives`` and its generator ``_negatives_rng``; the host calls ``_track_episodes`` at each add.
    """

    episodes: np.ndarray
    # From the host: SB3's ReplayBuffer ...
    buffer_size: int
    n_envs: int
    pos: int
    full: bool
    dones: np.ndarray
    # ... and DomainReplayBuffer
    frame_stack: int | None
    same_episode_negatives: bool
    _negatives_rng: np.random.Generator | None
    is_sampleable: Callable[[np.ndarray, np.ndarray], np.ndarray]

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

    def episode_ids(self, batch_inds: np.ndarray, env_indices: np.ndarray) -> np.ndarray:
        """
        Id of the episode of each stored transition; two transitions share an episode iff they share its id.

        :param batch_inds: Slots
        :param env_indices: Env indices, same shape as ``batch_inds``
        :return: int64 array of that shape
        """
        n_stored = self.buffer_size if self.full else self.pos
        batch_inds, env_indices, stored = stored_pairs(batch_inds, env_indices, n_stored, self.n_envs)
        if not stored.all():
            bad = np.flatnonzero(~stored.ravel())[:5]
            pairs = list(zip(batch_inds.ravel()[bad].tolist(), env_indices.ravel()[bad].tolist(), strict=True))
            raise ValueError(f"(batch_inds, env_indices) pairs {pairs} hold no stored transition")
        return self.episodes[batch_inds, env_indices].copy()

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


def _grown(array: np.ndarray, capacity: int) -> np.ndarray:
    """``array`` followed by zeros up to ``capacity`` entries."""
    grown = np.zeros(capacity, dtype=array.dtype)
    grown[: len(array)] = array
    return grown
