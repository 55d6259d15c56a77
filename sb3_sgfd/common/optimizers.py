"""The optimisers of a gradient step set up for the way it runs (eager as they were made; compiled: fused, and where
captured with their learning rate and step counters on the device), and a learning rate set in place."""

from __future__ import annotations

from collections.abc import Sequence

import torch as th
from torch import Tensor


def prepare_optimizers(optimizers: Sequence[th.optim.Optimizer], captured: bool, fused: bool = False) -> None:
    """Set the optimisers up for the update they run in (their steps unchanged, their state kept).

    Captured: Adam and SGD step fused (one kernel each), Adam's learning rate and step counters as tensors on the
    device (what a graph can replay: a schedule fills the rate tensor in place). Fused (``compile_update`` on the CPU,
    where nothing is captured): the same fused kernels, the rate and the counters as SB3 keeps them; the same Adam and
    SGD, rounded otherwise. Eager: as the optimiser was made (SB3's settings, or the fused or foreach choice of the
    policy's ``optimizer_kwargs``), so that a model saved from any way trains as it would when loaded without
    ``compile_update``.

    :param optimizers: every optimiser the update steps
    :param captured: whether the update is captured
    :param fused: step with the fused kernels without capturing (implied by ``captured``)
    """
    fused = fused or captured
    for optimizer in optimizers:
        adam = isinstance(optimizer, th.optim.Adam)
        made = optimizer.defaults
        for group in optimizer.param_groups:
            device = group["params"][0].device
            lr = float(group["lr"])
            group["fused"], group["foreach"] = (True, False) if fused else (made.get("fused"), made.get("foreach"))
            if adam:
                # fused steps are graph-safe on CUDA when capturable
                group["capturable"] = captured and device.type == "cuda" if fused else bool(made.get("capturable"))
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
