"""Counting host reads (device-to-host synchronisations on a GPU) of torch code, on any device."""

from __future__ import annotations

import sys
from typing import Any

import torch
from torch.overrides import TorchFunctionMode

# Tensor methods that hand a tensor's values to Python, or make a shape depend on them: on a GPU each waits for
# every queued kernel.
READS = {"item", "__bool__", "__float__", "__int__", "__index__", "tolist", "numpy", "__array__", "cpu", "nonzero"}
READS |= {"masked_select", "unique", "argwhere"}


class HostReads(TorchFunctionMode):
    """A torch function mode counting host reads while active (``count``, and ``names`` in the order seen).

    Reads made inside ``torch.optim`` are left out: they read the optimisers' step counters, which live on the CPU
    whatever the device (no synchronisation)."""

    def __init__(self) -> None:
        super().__init__()
        self.names: list[str] = []

    @property
    def count(self) -> int:
        return len(self.names)

    def __torch_function__(self, func: Any, types: Any, args: tuple = (), kwargs: dict | None = None) -> Any:
        name = getattr(func, "__name__", "")
        if name in READS or (name == "__getitem__" and _boolean_index(args)):
            caller = sys._getframe(1).f_globals.get("__name__", "")
            if not caller.startswith("torch.optim"):
                self.names.append(name)
        return func(*args, **(kwargs or {}))


def _boolean_index(args: tuple) -> bool:
    index = args[1] if len(args) > 1 else None
    indices = index if isinstance(index, tuple) else (index,)
    return any(isinstance(i, torch.Tensor) and i.dtype == torch.bool for i in indices)
