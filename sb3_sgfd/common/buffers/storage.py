"""What :class:`~sb3_sgfd.common.buffers.DomainReplayBuffer` holds beyond SB3's arrays: a :class:`FrameStore`, which
stores each frame of the frame stacks once and rebuilds the stacks, and an :class:`EpisodeIndex`, which knows the
episode of every stored transition and draws TED's same-episode negatives from it. Both address stored transitions
by (slot, env) pairs, checked by :func:`stored_pairs`; the buffer hands them its ring position where they need it."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from gymnasium import spaces


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


class FrameStore:
    """
    Each rendered frame of ``frame_stack``-frame observations stored once, and the stacks rebuilt on sampling (the
    format is in :class:`~sb3_sgfd.common.buffers.DomainReplayBuffer`'s docstring).

    :param buffer_size: slots of the buffer's ring
    :param n_envs: its envs
    :param observation_space: the stacked observation space (checked by :func:`check_frame_stack`)
    :param frame_stack: frames per observation
    """

    def __init__(self, buffer_size: int, n_envs: int, observation_space: spaces.Box, frame_stack: int) -> None:
        self.buffer_size, self.n_envs, self.frame_stack = buffer_size, n_envs, frame_stack
        self.obs_shape, self.dtype = tuple(observation_space.shape), observation_space.dtype
        self.channels = self.obs_shape[0] // frame_stack
        frame_shape = (self.channels, *self.obs_shape[1:])
        #: frames[slot, env]: newest frame of the observation stored at (slot, env)
        self.frames = np.zeros((buffer_size, n_envs, *frame_shape), dtype=self.dtype)
        #: history[slot, env]: how many frames of that observation come before its newest one (the others are the
        #: zero padding of an episode start); they sit at slot - 1, ..., slot - history
        self.history = np.zeros((buffer_size, n_envs), dtype=np.min_scalar_type(frame_stack - 1))
        #: The last frame of next_obs where it is not frames[slot + 1, env]; has_side_frame allows vectorised lookups,
        #: and both are cleared when their slot is overwritten.
        self.side_frames: dict[tuple[int, int], np.ndarray] = {}
        self.has_side_frame = np.zeros((buffer_size, n_envs), dtype=bool)
        # The newest transition: its next_obs (whose last frame is that transition's next frame until the following
        # add), to tell whether the next obs continues it.
        self.last_next_obs = np.zeros((n_envs, *self.obs_shape), dtype=self.dtype)
        self.last_done = np.ones(n_envs, dtype=bool)
        self.last_history = np.zeros(n_envs, dtype=self.history.dtype)
        self.last_slot: int | None = None

    def as_stacks(self, stacks: np.ndarray, name: str) -> np.ndarray:
        """``stacks`` as an array of shape (n_envs, *obs_shape) in the observation dtype.

        :param stacks: One stacked observation per env
        :param name: Argument name for the error message
        """
        array = np.asarray(stacks)
        expected = (self.n_envs, *self.obs_shape)
        if array.shape != expected:
            raise ValueError(f"{name} must have shape (n_envs, *observation_space.shape) {expected}, got {array.shape}")
        return array.astype(self.dtype, copy=False)

    def check_stacks(self, obs: np.ndarray, next_obs: np.ndarray) -> np.ndarray:
        """Check that obs and next_obs are frame stacks as VecFrameStack makes them.

        :param obs: Stacked observations, one per env
        :param next_obs: Stacked next observations (terminal observation for done envs)
        :return: For each env, whether obs continues the env's previous transition
        """
        channels, n_envs = self.channels, self.n_envs
        shifted = (next_obs[:, :-channels] == obs[:, channels:]).reshape(n_envs, -1).all(axis=1)
        if not shifted.all():
            raise ValueError(
                f"next_obs of env(s) {np.flatnonzero(~shifted).tolist()} is not obs shifted by one frame: with "
                f"frame_stack={self.frame_stack}, next_obs[:, :-{channels}] must equal obs[:, {channels}:] (SB3's "
                "VecFrameStack, with info['terminal_observation'] as next_obs of a done env)"
            )
        continuing = ~self.last_done & (obs == self.last_next_obs).reshape(n_envs, -1).all(axis=1)
        padded = (obs[:, :-channels] == 0).reshape(n_envs, -1).all(axis=1)
        broken = ~continuing & ~padded
        if broken.any():
            raise ValueError(
                f"obs of env(s) {np.flatnonzero(broken).tolist()} neither continues that env's previous transition "
                "(equal to its next_obs, not done) nor starts an episode (all frames but the newest zero): "
                f"frame_stack={self.frame_stack} expects observations stacked by SB3's VecFrameStack"
            )
        return continuing

    def add(self, slot: int, obs: np.ndarray, next_obs: np.ndarray, continuing: np.ndarray, ended: np.ndarray) -> None:
        """Store the newest frame of each env's observation at ``slot``, and, where the previous transition's next
        frame will not be the next slot's frame (an episode ended, an env replaced), that frame aside.

        :param slot: the slot written by this add
        :param obs: the checked stacks (:meth:`check_stacks`)
        :param next_obs: their next observations
        :param continuing: whether each env's obs continues its previous transition
        :param ended: whether each env's episode ended at this transition
        """
        for env_idx in np.flatnonzero(self.has_side_frame[slot]):
            del self.side_frames[(slot, int(env_idx))]
        self.has_side_frame[slot] = False
        last = self.last_slot
        # With a single slot, the previous transition is the one overwritten now.
        if last is not None and last != slot:
            for env_idx in np.flatnonzero(~continuing):
                self.side_frames[(last, int(env_idx))] = self.last_next_obs[env_idx, -self.channels :].copy()
                self.has_side_frame[last, env_idx] = True
        history = np.where(continuing, np.minimum(self.last_history.astype(np.intp) + 1, self.frame_stack - 1), 0)
        self.frames[slot] = obs[:, -self.channels :]
        self.history[slot] = history
        self.last_history[:] = history
        self.last_next_obs[:] = next_obs
        self.last_done[:] = ended
        self.last_slot = slot

    def reset(self) -> None:
        """The ring is emptied: the side frames go; the continuity state is kept (an episode may go on after a reset,
        its older frames are just no longer stored)."""
        self.side_frames.clear()
        self.has_side_frame[:] = False
        self.last_slot = None

    def whole(self, slots: np.ndarray, envs: np.ndarray, older: np.ndarray) -> np.ndarray:
        """Whether every frame of the stacks at (slots, envs) is still stored, given how many stored transitions are
        older than each slot."""
        return older >= self.history[slots, envs]

    def rebuild(
        self, batch_inds: np.ndarray, env_indices: np.ndarray, next_inds: np.ndarray | None = None
    ) -> tuple[np.ndarray, np.ndarray]:
        """Observation and next observation stacks of sampleable pairs, from the stored frames.

        :param batch_inds: Slots
        :param env_indices: Env indices
        :param next_inds: Slots whose next observations to rebuild (an n-step return's last transition, in the
            same episode); None: ``batch_inds``
        :return: obs and next_obs, each a new C-contiguous array of shape (batch, *obs_shape)
        """
        # Frames `offsets` slots back, oldest first: obs takes the first k, next_obs the last k (whose newest,
        # read from slot + 1, is replaced below where the next frame is stored elsewhere).
        offsets = np.arange(self.frame_stack - 1, -2, -1)
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
        newest = np.flatnonzero(next_inds == self.last_slot)
        if len(newest) > 0:
            next_obs[newest, -1] = self.last_next_obs[env_indices[newest], -self.channels :]
        for row in np.flatnonzero(self.has_side_frame[next_inds, env_indices]):
            next_obs[row, -1] = self.side_frames[(int(next_inds[row]), int(env_indices[row]))]
        stacked_shape = (len(batch_inds), *self.obs_shape)
        return obs.reshape(stacked_shape), next_obs.reshape(stacked_shape)

    def stacks_at(self, batch_inds: np.ndarray, env_indices: np.ndarray) -> np.ndarray:
        """The observation stacks of sampleable pairs (as :meth:`rebuild` gives obs): the frames k - 1, ..., 0 slots
        back, zeros before the episode's start."""
        offsets = np.arange(self.frame_stack - 1, -1, -1)
        slots = (batch_inds[:, None] - offsets) % self.buffer_size
        stacks = self.frames[slots, env_indices[:, None]]
        padding = offsets > self.history[batch_inds, env_indices][:, None].astype(np.intp)
        if padding.any():
            stacks[padding] = 0
        return stacks.reshape((len(batch_inds), *self.obs_shape))

    def arrays(self) -> list[np.ndarray]:
        """Every array it holds (for the buffer's storage size)."""
        return [self.frames, self.history, self.has_side_frame, self.last_next_obs, *self.side_frames.values()]


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


class EpisodeIndex:
    """
    The episode of every stored transition, tracked at each add, and TED's same-episode negatives drawn from it in
    O(batch) (the rules are in :class:`~sb3_sgfd.common.buffers.DomainReplayBuffer`'s docstring).

    Transitions are counted by their add index over the buffer's life (through resets): the one added at index t
    sits in slot (t - n_adds + pos) % buffer_size.

    :param buffer_size: slots of the buffer's ring
    :param n_envs: its envs
    :param rng: the generator of the negatives' draws (None: the buffer draws none)
    """

    def __init__(self, buffer_size: int, n_envs: int, rng: np.random.Generator | None = None) -> None:
        self.buffer_size, self.n_envs, self.rng = buffer_size, n_envs, rng
        #: episodes[slot, env]: id of the episode of the transition stored at (slot, env)
        self.episodes = np.zeros((buffer_size, n_envs), dtype=np.int64)
        # Add index of the first and last transition of each episode, by id; the arrays double when full, so that an
        # add costs O(n_envs).
        self.first = np.zeros(16, dtype=np.int64)
        self.last = np.zeros(16, dtype=np.int64)
        self.n_episodes = 0
        #: Add index of the next add.
        self.n_adds = 0
        self.current = np.zeros(n_envs, dtype=np.int64)
        #: False where the env's last add ended its episode (or none came yet): its next add starts one.
        self.open = np.zeros(n_envs, dtype=bool)

    def track(self, slot: int, done: np.ndarray) -> None:
        """Record the transitions just written to ``slot``.

        :param slot: The slot written by this add
        :param done: Done flag of each env, shape (n_envs,), bool
        """
        starting = np.flatnonzero(~self.open)
        if len(starting) > 0:
            n_episodes = self.n_episodes + len(starting)
            if n_episodes > len(self.first):
                capacity = max(n_episodes, 2 * len(self.first))
                self.first, self.last = _grown(self.first, capacity), _grown(self.last, capacity)
            ids = np.arange(self.n_episodes, n_episodes)
            self.first[ids] = self.n_adds
            self.current[starting] = ids
            self.n_episodes = n_episodes
        self.last[self.current] = self.n_adds
        self.episodes[slot] = self.current
        self.open = ~done
        self.n_adds += 1

    def ids(self, batch_inds: np.ndarray, env_indices: np.ndarray, n_stored: int) -> np.ndarray:
        """Id of the episode of each stored transition (see ``DomainReplayBuffer.episode_ids``)."""
        batch_inds, env_indices, stored = stored_pairs(batch_inds, env_indices, n_stored, self.n_envs)
        if not stored.all():
            bad = np.flatnonzero(~stored.ravel())[:5]
            pairs = list(zip(batch_inds.ravel()[bad].tolist(), env_indices.ravel()[bad].tolist(), strict=True))
            raise ValueError(f"(batch_inds, env_indices) pairs {pairs} hold no stored transition")
        return self.episodes[batch_inds, env_indices].copy()

    def add_indices(self, slots: np.ndarray, pos: int) -> np.ndarray:
        """Add index of the transitions stored in ``slots`` (the newest sits at pos - 1, and so on back)."""
        return self.n_adds - 1 - (pos - 1 - slots) % self.buffer_size

    def slots(self, add_indices: np.ndarray, pos: int) -> np.ndarray:
        """Slot of the stored transitions added at ``add_indices``."""
        return (add_indices - self.n_adds + pos) % self.buffer_size

    def first_sampleable(
        self, pos: int, n_stored: int, window: int, sampleable: Callable[[np.ndarray, np.ndarray], np.ndarray]
    ) -> np.ndarray:
        """For each env, the add index of its oldest sampleable transition (``n_adds`` if it has none).

        A column's sampleable transitions are all its stored ones from that index on: a stack's history grows by at
        most one per add, so (stored transitions older than it) - (its history) never decreases along the column.
        Only the oldest few may miss frames, so the first ``window`` stored slots decide.

        :param pos: the buffer's ring position
        :param n_stored: its stored slots
        :param window: the oldest slots to look at (the frame stack plus one)
        :param sampleable: the buffer's ``is_sampleable``
        """
        end = self.n_adds
        window = min(n_stored, window)
        if window == 0:
            return np.full(self.n_envs, end, dtype=np.int64)
        candidates = end - n_stored + np.arange(window)
        shape = (window, self.n_envs)
        found = sampleable(
            np.broadcast_to(self.slots(candidates, pos)[:, None], shape), np.broadcast_to(np.arange(self.n_envs), shape)
        )
        return np.where(found.any(axis=0), candidates[found.argmax(axis=0)], end)

    def negatives(
        self, batch_inds: np.ndarray, env_indices: np.ndarray, pos: int, first_sampleable: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """Slot and env of the same-episode observation o_j of each sample i (see the buffer's docstring), O(batch).

        :param batch_inds: Slots of the samples
        :param env_indices: Envs of the samples
        :param pos: the buffer's ring position
        :param first_sampleable: :meth:`first_sampleable`
        :return: Slots and envs of the observations, each of shape (batch,)
        """
        assert self.rng is not None
        i = self.add_indices(batch_inds, pos)
        episode = self.episodes[batch_inds, env_indices]
        # The episode's sampleable transitions: add indices low..high (its column's are a suffix, its own a run).
        low = np.maximum(self.first[episode], first_sampleable[env_indices])
        high = self.last[episode]
        n_episode = np.maximum(high - low + 1, 0)
        # i - 1, i, i + 1, clipped to [low, high], are excluded: draw among the others, then step over them.
        excluded_low = np.maximum(low, i - 1)
        n_excluded = np.maximum(np.minimum(high, i + 1) - excluded_low + 1, 0)
        n_allowed = n_episode - n_excluded
        j = low + self.rng.integers(0, np.maximum(n_allowed, 1))
        j = np.where(j >= excluded_low, j + n_excluded, j)
        envs = env_indices.copy()
        fallback = np.flatnonzero(n_allowed <= 0)
        if len(fallback) > 0:
            j[fallback], envs[fallback] = self._other_episodes(
                first_sampleable, env_indices[fallback], low[fallback], n_episode[fallback]
            )
        return self.slots(j, pos), envs

    def _other_episodes(
        self, first_sampleable: np.ndarray, env_indices: np.ndarray, low: np.ndarray, n_episode: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """Add index and env of a transition drawn uniformly among all sampleable ones outside a given episode.

        The sampleable transitions are numbered column after column (each column's a run of add indices); the
        episode's are one run of that numbering, which the draw steps over.

        :param first_sampleable: :meth:`first_sampleable`
        :param env_indices: Env of each episode
        :param low: Add index of each episode's oldest sampleable transition
        :param n_episode: Number of each episode's sampleable transitions
        :return: Add indices and envs, each of shape (len(env_indices),)
        """
        assert self.rng is not None
        counts = self.n_adds - first_sampleable
        ends = np.cumsum(counts)
        starts = ends - counts
        n_others = ends[-1] - n_episode
        if (n_others <= 0).any():
            raise ValueError(
                "same_episode_negatives: a sample's episode has no transition two steps or more away from it, "
                "and the buffer holds no sampleable transition of another episode to use instead"
            )
        flat = self.rng.integers(0, n_others)
        episode_start = starts[env_indices] + low - first_sampleable[env_indices]
        flat = np.where(flat >= episode_start, flat + n_episode, flat)
        envs = np.searchsorted(ends, flat, side="right")
        return first_sampleable[envs] + flat - starts[envs], envs

    def arrays(self) -> list[np.ndarray]:
        """Every array it holds (for the buffer's storage size)."""
        return [self.episodes, self.first, self.last]


def _grown(array: np.ndarray, capacity: int) -> np.ndarray:
    """``array`` followed by zeros up to ``capacity`` entries."""
    grown = np.zeros(capacity, dtype=array.dtype)
    grown[: len(array)] = array
    return grown
