"""
Replay buffers: :class:`DomainReplayBuffer` (``sb3_sgfd.DomainReplayBuffer`` in yaml) and its batches, and
:class:`DomainDictReplayBuffer` for Dict observations.

``replay.py`` holds the buffer, its domain labels and its n-step returns, ``storage.py`` what it stores beyond SB3's
arrays (each frame once, the episode index and TED's negatives), ``dict_replay.py`` the buffer for Dict observations.
"""

from sb3_sgfd.common.buffers.dict_replay import DomainDictReplayBuffer, DomainDictReplayBufferSamples
from sb3_sgfd.common.buffers.replay import DomainReplayBuffer, DomainReplayBufferSamples, domain_labels

__all__ = [
    "DomainDictReplayBuffer",
    "DomainDictReplayBufferSamples",
    "DomainReplayBuffer",
    "DomainReplayBufferSamples",
    "domain_labels",
]
