"""The replay buffers by the path yaml files name (``replay_buffer_class: sb3_sgfd.buffers.DomainReplayBuffer``); they
live in :mod:`sb3_sgfd.common.buffers`."""

from sb3_sgfd.common.buffers import (
    DomainDictReplayBuffer,
    DomainDictReplayBufferSamples,
    DomainReplayBuffer,
    DomainReplayBufferSamples,
)

__all__ = ["DomainDictReplayBuffer", "DomainDictReplayBufferSamples", "DomainReplayBuffer", "DomainReplayBufferSamples"]
