"""The path models and replay buffers saved by version 0.1.0 name their buffer by (they load by it)."""

from sb3_sgfd.common.buffers.replay import DomainReplayBuffer, DomainReplayBufferSamples

__all__ = ["DomainReplayBuffer", "DomainReplayBufferSamples"]
