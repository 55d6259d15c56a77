"""How a training loop runs its gradient steps: :class:`UpdateRunner`, which
:class:`~sb3_sgfd.common.encoder_sac.EncoderSAC` holds, and the host's decisions for one step (:class:`StepPlan`).

The runner puts three parts together, each in its own module:

- the pieces of a step run as they are, or, with ``compile_update`` on CUDA, each piece and plan replayed as one CUDA
  graph (:class:`~sb3_sgfd.common.capture.CapturedUpdate`);
- the figures a step logs, summed on the device and read once per ``train`` call (eager) or per log interval
  (captured), with the non-finite check (:class:`~sb3_sgfd.common.device_figures.DeviceFigures`);
- the optimisers set up for the way the steps run (:func:`~sb3_sgfd.common.optimizers.prepare_optimizers`).

Where a piece is captured (``compile_update`` on CUDA) every decision inside it must be a tensor (a graph replays what
its capture ran); elsewhere (the CPU, and CUDA without ``compile_update``) a decision is a Python branch, which skips
the work a mask would compute and discard (:attr:`UpdateRunner.masked`). What fuses (SGFD's weight solver) is compiled
with ``torch.compile`` by its owner when ``compile_update`` is on CUDA; on the CPU ``compile_update`` steps the
optimisers fused and compiles nothing.
"""

from __future__ import annotations

from collections.abc import Callable, Hashable, Iterable, Sequence
from typing import Any, NamedTuple, ParamSpec, TypeVar

import torch as th
from stable_baselines3.common.logger import Logger
from torch import Tensor

from sb3_sgfd.common.capture import CapturedUpdate
from sb3_sgfd.common.device_figures import DeviceFigures
from sb3_sgfd.common.optimizers import prepare_optimizers

T = TypeVar("T")
P = ParamSpec("P")

#: With the update captured, the non-finite flag is read at least every this many updates (one host read each).
FINITE_CHECK_UPDATES = 1000


class StepPlan(NamedTuple):
    """The host's decisions for one gradient step: a captured step is one CUDA graph per distinct plan.

    :param update_actor: the actor and the entropy coefficient learn
    :param update_target: the target networks move
    :param objective: the representation objective's own decisions (``Representation.plan``)
    :param weighting: the sample weighting's (``SampleWeighting.plan``)
    """

    update_actor: bool
    update_target: bool
    objective: tuple = ()
    weighting: tuple = ()


class UpdateRunner:
    """Runs a training loop's gradient steps: their pieces, figures and optimisers.

    :param device: the model's device
    :param compiled: the steps run as captured work (``compile_update``): CUDA graphs on CUDA
    :param generators: the generators the pieces draw from beside the global ones (a captured graph registers them)
    :param n_updates: the model's updates so far (the figures count from there)
    """

    def __init__(
        self,
        device: th.device | str,
        compiled: bool,
        generators: Callable[[], Iterable[th.Generator]] = tuple,
        n_updates: int = 0,
    ) -> None:
        self.device = th.device(device)
        self.compiled = bool(compiled)
        self.pieces = CapturedUpdate(self.device, self.compiled, generators=generators)
        #: Decide inside a step with tensors (masks), not Python branches: where the pieces are captured. A test on the
        #: CPU sets it to run the captured logic eagerly (the CPU twin of a GPU's step).
        self.masked = self.pieces.capture
        self.figures = DeviceFigures(self.device, replayed=self.pieces.capture)
        self.optimizers_prepared = False
        self.finite_checked = n_updates

    @property
    def capture(self) -> bool:
        """Whether the pieces are replayed as CUDA graphs."""
        return self.pieces.capture

    def fits(self, device: th.device, compiled: bool) -> bool:
        """Whether this runner runs steps on ``device`` in the way ``compiled`` asks."""
        return self.device == device and self.compiled == bool(compiled)

    def run(self, key: Hashable, piece: Callable[P, T], *args: P.args, **kwargs: P.kwargs) -> T:
        """``piece(*args, **kwargs)``, or the replay of its graph for ``key`` (:meth:`CapturedUpdate.run`)."""
        return self.pieces.run(key, piece, *args, **kwargs)

    def inputs(self, prefix: str, values: Any) -> Any:
        """A replay batch through the static inputs of captured pieces (as it is otherwise)."""
        return self.pieces.inputs(prefix, values)

    def start(self, optimizers: Callable[[], Sequence[th.optim.Optimizer]], n_updates: int) -> None:
        """Before a ``train`` call's steps: the optimisers (``optimizers()``, listed only then) set up once, and again
        after :meth:`forget`; the figures counting from update ``n_updates``."""
        if not self.optimizers_prepared:
            prepare_optimizers(optimizers(), self.capture, fused=self.compiled)
            self.optimizers_prepared = True
        self.figures.start(n_updates)

    def record(
        self, key: str, value: float | Tensor, check_finite: str | None = None, when: Tensor | None = None
    ) -> None:
        """Log a figure of this gradient step (summed on the device; the log shows the mean since the last log); with
        ``check_finite``, a non-finite value stops training, naming it and its update.

        :param key: the logger's key
        :param value: a 0-d tensor or a number
        :param check_finite: what the value is, for the stop's message; None: not checked
        :param when: a 0-d bool tensor: the value counts only where it is true
        """
        self.figures.add(key, value, when)
        if check_finite is not None:
            assert isinstance(value, Tensor)
            self.figures.check(check_finite, value)

    def end_step(self) -> None:
        """A step is done (inside its piece: the figures' update counter moves on the device)."""
        self.figures.end_update()

    def finish(self, logger: Logger, n_updates: int) -> None:
        """After a ``train`` call: the figures into the logger (eager: now, one host read; captured: at the log, see
        :meth:`flush`), and with the update captured the non-finite check at least every ``FINITE_CHECK_UPDATES``."""
        if not self.capture:
            self.log_figures(logger)
        elif n_updates - self.finite_checked >= FINITE_CHECK_UPDATES:
            self.finite_checked = n_updates
            self.figures.raise_if_not_finite()

    def flush(self, logger: Logger) -> None:
        """Before the logger writes: a captured update's figures read (once per log interval), and the histograms
        kept on the device (for TensorBoard only: the other outputs take numbers)."""
        if self.capture:
            self.log_figures(logger)
        for key, values in self.figures.histograms().items():
            logger.record(key, values, exclude=("stdout", "log", "json", "csv"))

    def log_figures(self, logger: Logger) -> None:
        """The figures since the last read, into the logger (one host read)."""
        for key, mean in self.figures.read().items():
            logger.record(key, mean)

    def forget(self) -> None:
        """New parameters, optimiser states or generators: no captured graph is replayed again, and the optimisers
        are set up again at the next ``train``."""
        self.pieces.reset()
        self.optimizers_prepared = False
