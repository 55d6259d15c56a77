"""A pickled DomainReplayBuffer's state as the buffer holds it: a :class:`~sb3_sgfd.common.buffers.storage.FrameStore`
and an :class:`~sb3_sgfd.common.buffers.storage.EpisodeIndex` (``DomainReplayBuffer.__setstate__`` calls
:func:`held_layout`). Today's pickles hold the two parts' attributes as dicts; those of earlier versions (0.1.0, 0.2.0)
held them as attributes of the buffer itself. The pickle's arrays are taken as they are: the same transitions, the
same draws."""

from __future__ import annotations

from typing import Any

from sb3_sgfd.common.buffers.storage import EpisodeIndex, FrameStore

#: The buffer's attribute in those versions -> the frame store's
FRAME_STORE_ATTRIBUTES = {
    "frames": "frames",
    "history": "history",
    "side_frames": "side_frames",
    "has_side_frame": "has_side_frame",
    "_last_next_obs": "last_next_obs",
    "_last_done": "last_done",
    "_last_history": "last_history",
    "_last_slot": "last_slot",
    "_channels": "channels",
}
#: The buffer's attribute in those versions -> the episode index's
EPISODE_INDEX_ATTRIBUTES = {
    "episodes": "episodes",
    "_episode_first": "first",
    "_episode_last": "last",
    "_n_episodes": "n_episodes",
    "_n_adds": "n_adds",
    "_current_episode": "current",
    "_episode_open": "open",
    "_negatives_rng": "rng",
}


def held_layout(state: dict[str, Any]) -> dict[str, Any]:
    """A pickled DomainReplayBuffer's state with its parts as objects.

    :param state: the buffer's state as pickled
    """
    state = dict(state)
    if "episode_index" in state:
        state["episode_index"] = _part(EpisodeIndex, state["episode_index"])
        state["frame_store"] = None if state["frame_store"] is None else _part(FrameStore, state["frame_store"])
        return state
    index = EpisodeIndex.__new__(EpisodeIndex)
    index.buffer_size, index.n_envs = state["buffer_size"], state["n_envs"]
    for old, new in EPISODE_INDEX_ATTRIBUTES.items():
        setattr(index, new, state.pop(old))
    state["episode_index"], state["frame_store"] = index, None
    state.setdefault("n_steps", 1)  # version 0.1.0 had one-step returns only
    state.setdefault("gamma", 0.99)
    if state.get("frame_stack") is not None:
        store = FrameStore.__new__(FrameStore)
        store.buffer_size, store.n_envs, store.frame_stack = state["buffer_size"], state["n_envs"], state["frame_stack"]
        store.obs_shape, store.dtype = tuple(state["obs_shape"]), state["observation_space"].dtype
        for old, new in FRAME_STORE_ATTRIBUTES.items():
            setattr(store, new, state.pop(old))
        state["frame_store"] = store
    return state


def _part(cls: type[EpisodeIndex] | type[FrameStore], attributes: dict[str, Any]) -> Any:
    """An object of ``cls`` with ``attributes`` (as ``__getstate__`` pickled them), made without its constructor."""
    part = object.__new__(cls)
    part.__dict__.update(attributes)
    return part
