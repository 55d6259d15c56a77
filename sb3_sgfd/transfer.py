"""The path replay buffers saved by version 0.1.0 name their batch transfer by (they load by it)."""

from sb3_sgfd.common.transfer import BatchTransfer

__all__ = ["BatchTransfer"]
