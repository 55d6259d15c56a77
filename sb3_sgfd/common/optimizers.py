"""The optimisers of a gradient step set up for the way it runs (eager as SB3 runs them, or captured: fused, with
their learning rate and step counters on the device), and a learning rate set in place."""

from __future__ import annotations

from collections.abc import Sequence

import torch as th
from torch import Tensor


def prepare_optimizers(optimizers: Sequence[th.optim.Optimizer], captured: bool) -> None:
    """Set the optimisers up for the update they run in (their steps unchanged, their state kept).

    Captured: Adam and SGD step fused (one kernel each), Adam's learning rate and step counters as tensors on the
    device (what a graph can replay: a schedule fills the rate tensor in place). Eager: SB3's own settings (a
    learning rate as a number, Adam's counters on the host), so that a model saved from either way trains as SB3
    would when loaded without ``compile_update``.

    :param optimizers: every optimiser the update steps
    :param captured: whether the update is captured
    """
    for optimizer in optimizers:
        adam = isinstance(optimizer, th.optim.Adam)
        for group in optimizer.param_groups:
            device = group["params"][0].device
            lr = float(group["lr"])
            group["fused"], group["foreach"] = (True, False) if captured else (None, None)
            if adam:
                group["capturable"] = captured and device.type == "cuda"  # fused steps graph-safe on CUDA only then
                group["lr"] = th.tensor(lr, device=device) if captured else lr
            for param in group["params"]:
                state = optimizer.state.get(param, {})
                if adam and "step" in state:
                    step = float(state["step"])
                    state["step"] = th.tensor(step, dtype=th.float32, device=device) if captured else th.tensor(step)


def set_learning_rate(optimizer: th.optim.Optimizer, learning_rate: float) -> None:
    """``learning_rate`` into each of the optimiser's groups: in place where the rate is a tensor (a captured graph
    reads it there), else as SB3 sets it."""
    for group in optimizer.param_groups:
        if isinstance(group["lr"], Tensor):
            group["lr"].fill_(learning_rate)
        else:
            group["lr"] = learning_rate
