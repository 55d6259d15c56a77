"""Episode index of :class:`~sb3_sgfd.common.buffers.DomainReplayBuffer`, and TED's same-episode negatives drawn
from it."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from sb3_sgfd.common.buffers.slots import stored_pairs


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
