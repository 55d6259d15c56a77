"""Replay buffers: :class:`DomainReplayBuffer` and its batches (``sb3_sgfd.buffers.DomainReplayBuffer`` in yaml)."""

from sb3_sgfd.buffers.replay import DomainReplayBuffer, DomainReplayBufferSamples, domain_labels

__all__ = ["DomainReplayBuffer", "DomainReplayBufferSamples", "domain_labels"]
