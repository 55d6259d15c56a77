"""
Replay buffers: :class:`DomainReplayBuffer` (``sb3_sgfd.DomainReplayBuffer`` in yaml) and its batches, and
:class:`DomainDictReplayBuffer` for Dict observations.

By concept: ``replay.py`` the buffer (SB3's ``ReplayBuffer`` plus the mixins below), ``domains.py`` the domain
labels, ``frames.py`` the frame storage for frame stacks, ``episodes.py`` the episode index and TED's negatives,
``nstep.py`` SAC's n-step returns, ``slots.py`` the check of (slot, env) pairs they share; ``dict_replay.py`` the
buffer for Dict observations.
"""

from sb3_sgfd.common.buffers.dict_replay import DomainDictReplayBuffer, DomainDictReplayBufferSamples
from sb3_sgfd.common.buffers.domains import domain_labels
from sb3_sgfd.common.buffers.replay import DomainReplayBuffer, DomainReplayBufferSamples

__all__ = [
    "DomainDictReplayBuffer",
    "DomainDictReplayBufferSamples",
    "DomainReplayBuffer",
    "DomainReplayBufferSamples",
    "domain_labels",
]
