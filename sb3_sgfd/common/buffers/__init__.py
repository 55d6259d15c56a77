"""
Replay buffers: :class:`DomainReplayBuffer` (``sb3_sgfd.common.buffers.DomainReplayBuffer`` in yaml) and its batches.

By concept: ``replay.py`` the buffer (SB3's ``ReplayBuffer`` plus the mixins below), ``domains.py`` the domain
labels, ``frames.py`` the frame storage for frame stacks, ``episodes.py`` the episode index and TED's negatives,
``slots.py`` the check of (slot, env) pairs they share.
"""

from sb3_sgfd.common.buffers.domains import domain_labels
from sb3_sgfd.common.buffers.replay import DomainReplayBuffer, DomainReplayBufferSamples

__all__ = ["DomainReplayBuffer", "DomainReplayBufferSamples", "domain_labels"]
