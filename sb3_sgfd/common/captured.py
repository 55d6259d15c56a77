"""The update as captured work: each piece of a gradient step replayed as one CUDA graph, its logged figures summed
on the device.

On a GPU these agents' networks are small: an eager gradient step is hundreds of kernel launches (about 25 us each
on a recent host) and a few host reads (about 110 us each), while the arithmetic takes microseconds. With
``compile_update=True`` :class:`sb3_sgfd.common.encoder_sac.EncoderSAC` runs each piece of a step (the augmented
views, the step itself, and where a reading needs one a classifier round) through :class:`CapturedUpdate`:

- on CUDA, a piece is run eagerly (on a side stream) for its first ``warmup`` calls of each *plan* (the host's
  decisions for the step, e.g. whether the actor learns), then captured once as a CUDA graph and replayed from then
  on: one launch per piece and plan. The replay batch is copied into static input tensors first; every state the
  graphs touch (parameters, optimiser moments, target networks, the figures' sums) is updated in place;
- everywhere, the figures a step logs are summed on the device (:class:`DeviceFigures`) and read in one host
  transfer when they are logged, and a loss that stops being finite is remembered with the update it happened at;
- the optimisers step fused, with their learning rate and step counters as tensors on the device (what a graph can
  replay; :func:`prepare_optimizers`).

What fuses (SGFD's weight solver) is compiled with ``torch.compile`` by its owner; this module captures.
"""

from __future__ import annotations

from collections import defaultdict
from collections.abc import Callable, Hashable, Iterable, Sequence
from contextlib import contextmanager
from typing import Any, NamedTuple, ParamSpec, TypeVar

import torch as th
from torch import Tensor

T = TypeVar("T")
P = ParamSpec("P")

#: Calls of each piece and plan run eagerly before the capture (lazy state, cuBLAS workspaces, compilation).
WARMUP_CALLS = 2
#: With the update captured, the non-finite flag is read at least every this many updates (one host read each).
FINITE_CHECK_UPDATES = 1000


class StepPlan(NamedTuple):
    """The host's decisions for one gradient step: a captured step is one CUDA graph per distinct plan.

    :param update_actor: the actor and the entropy coefficient learn
    :param update_target: the target networks move
    :param objective: the representation objective's own decisions (``Representation.plan``)
    :param weighting: a sample weighting's (``_weighting_plan``)
    """

    update_actor: bool
    update_target: bool
    objective: tuple = ()
    weighting: tuple = ()


class DeviceFigures:
    """The figures of the gradient steps, summed on the device and read in one host transfer, and the first update
    at which a checked value (a loss) was not finite.

    :param device: where the sums live (the model's device)
    """

    def __init__(self, device: th.device | str) -> None:
        self.device = th.device(device)
        self._sums: dict[str, Tensor] = {}
        self._counts: dict[str, Tensor] = {}
        self._checked: list[str] = []
        #: The index of the update being run, counted on the device (what a non-finite value is reported at).
        self.update = th.zeros((), dtype=th.int64, device=self.device)
        self._first_bad = th.full((), -1, dtype=th.int64, device=self.device)
        self._bad_what = th.zeros((), dtype=th.int64, device=self.device)

    def start(self, update_index: int) -> None:
        """Count updates from ``update_index`` (the model's ``_n_updates``)."""
        self.update.fill_(update_index)

    def add(self, key: str, value: Tensor | float, when: Tensor | None = None) -> None:
        """Add one step's ``value`` (a 0-d tensor or a number) to the figure ``key``; with ``when`` (a 0-d bool
        tensor), only where it is true."""
        if key not in self._sums:
            self._sums[key] = th.zeros((), dtype=th.float64, device=self.device)
            self._counts[key] = th.zeros((), dtype=th.float64, device=self.device)
        # a number becomes a tensor by a fill on the device (a copy from the host would not replay)
        value = value.detach() if isinstance(value, Tensor) else th.full((), float(value), device=self.device)
        value = value.to(th.float64).reshape(())
        if when is None:
            self._sums[key].add_(value)
            self._counts[key].add_(1)
        else:
            self._sums[key].add_(th.where(when, value, 0.0))
            self._counts[key].add_(when.to(th.float64))

    def check(self, what: str, value: Tensor) -> None:
        """Remember the update at which ``value`` (0-d) is first not finite, as ``what``, without a host read."""
        if what not in self._checked:
            self._checked.append(what)
        fresh = ~th.isfinite(value.detach()) & (self._first_bad < 0)
        self._first_bad.copy_(th.where(fresh, self.update, self._first_bad))
        self._bad_what.copy_(th.where(fresh, self._checked.index(what), self._bad_what))

    def end_update(self) -> None:
        """The step is done: the next one has the next index."""
        self.update.add_(1)

    def read(self) -> dict[str, float]:
        """The mean of each figure since the last read (then cleared), in one host transfer; a stop naming the value
        and the update where it became NaN or inf."""
        keys = list(self._sums)
        flags = [self._first_bad.to(th.float64), self._bad_what.to(th.float64)]
        values = th.stack([*self._sums.values(), *self._counts.values(), *flags]).tolist()
        self._raise_if_bad(int(values[-2]), int(values[-1]))
        for tensor in (*self._sums.values(), *self._counts.values()):
            tensor.zero_()
        n = len(keys)
        return {key: values[i] / values[n + i] for i, key in enumerate(keys) if values[n + i] > 0}

    def raise_if_not_finite(self) -> None:
        """The non-finite check alone (one host read)."""
        first_bad, what = th.stack([self._first_bad, self._bad_what]).tolist()
        self._raise_if_bad(int(first_bad), int(what))

    def _raise_if_bad(self, first_bad: int, what: int) -> None:
        if first_bad >= 0:
            raise RuntimeError(
                f"non-finite {self._checked[what]} at update {first_bad}; stopping before it spreads (the model "
                "is left as it was after that update: do not save it; resume from the last checkpoint)"
            )


class CapturedUpdate:
    """Runs the pieces of gradient steps: as they are (``capture=False``, or off CUDA), or each piece and plan as one
    CUDA graph after ``warmup`` eager calls.

    :param device: the model's device
    :param capture: capture and replay on CUDA (``compile_update``)
    :param generators: the generators the pieces draw from beside CUDA's default one (each graph registers them, so
        that every replay draws afresh and their states stay what a checkpoint saves)
    :param warmup: eager calls of each piece and plan before it is captured
    """

    def __init__(
        self,
        device: th.device | str,
        capture: bool,
        generators: Callable[[], Iterable[th.Generator]] = tuple,
        warmup: int = WARMUP_CALLS,
    ) -> None:
        self.device = th.device(device)
        #: The batch goes through static inputs (on any device: on the CPU the same path runs, without graphs).
        self.static = capture
        self.capture = capture and self.device.type == "cuda"
        self.generators = generators
        self.warmup = warmup
        self.reset()

    def reset(self) -> None:
        """Forget every graph and static input: the next calls warm up and capture again (after a load, a device
        change, new optimiser states)."""
        self.graphs: dict[Hashable, tuple[Any, Any]] = {}
        self.calls: dict[Hashable, int] = defaultdict(int)
        self.static_inputs: dict[str, Tensor] = {}
        self._stream: Any = None

    def input(self, name: str, value: Tensor) -> Tensor:
        """``value`` as the graphs read it: copied into the static tensor ``name`` (when captured), else as it is."""
        if not self.static:
            return value
        static = self.static_inputs.get(name)
        if static is None or static.shape != value.shape or static.dtype != value.dtype:
            if static is not None:  # another shape: graphs that read the old tensor cannot be replayed
                self.reset()
            static = self.static_inputs[name] = th.empty_like(value)
        static.copy_(value, non_blocking=True)
        return static

    def inputs(self, prefix: str, values: Any) -> Any:
        """A named tuple of tensors (a replay batch) with each tensor field through :meth:`input`."""
        if not self.static:
            return values
        fields = {
            name: self.input(f"{prefix}.{name}", value)
            for name, value in values._asdict().items()
            if isinstance(value, Tensor)
        }
        return values._replace(**fields)

    def run(self, key: Hashable, piece: Callable[P, T], *args: P.args, **kwargs: P.kwargs) -> T:
        """``piece(*args, **kwargs)``, or the replay of its graph for ``key`` (what its Python decisions depend on).

        The piece may read only static inputs, tensors kept alive between calls, and what earlier captured pieces
        returned; it returns tensors (or containers of them) that later pieces may read until its next call."""
        if not self.capture:
            return piece(*args, **kwargs)
        captured = self.graphs.get(key)
        if captured is not None:
            graph, outputs = captured
            graph.replay()
            return outputs  # type: ignore[no-any-return]
        if self.calls[key] < self.warmup:
            self.calls[key] += 1
            with self._side_stream():
                return piece(*args, **kwargs)
        graph = th.cuda.CUDAGraph()
        for generator in self.generators():
            if generator.device.type == "cuda":
                graph.register_generator_state(generator)
        with _no_distribution_checks(), th.cuda.graph(graph):
            outputs = piece(*args, **kwargs)
        self.graphs[key] = (graph, outputs)
        graph.replay()
        return outputs

    @contextmanager
    def _side_stream(self) -> Any:
        # Warm-up off the default stream, as CUDA graphs' docs ask, ordered with it on both sides.
        if self._stream is None:
            self._stream = th.cuda.Stream(self.device)
        current = th.cuda.current_stream(self.device)
        self._stream.wait_stream(current)
        with th.cuda.stream(self._stream):
            yield
        current.wait_stream(self._stream)


@contextmanager
def _no_distribution_checks() -> Any:
    # torch.distributions checks its arguments' values with host reads, which a capture refuses; SB3's own SAC
    # policies build distributions with the checks on (this package's policies switch them off).
    previous = th.distributions.Distribution._validate_args
    th.distributions.Distribution.set_default_validate_args(False)
    try:
        yield
    finally:
        th.distributions.Distribution.set_default_validate_args(previous)


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


def masked_step(optimizer: th.optim.Optimizer, take: Tensor) -> None:
    """``optimizer.step()`` where the 0-d bool ``take`` is true; where it is false, parameters and optimiser state stay
    as they were (a state the step made for the first time stays at zeros, which is how Adam's and SGD's momentum
    start): the decision stays on the device, no host read.

    :param optimizer: an optimiser whose state starts at zero (Adam; SGD with momentum and no dampening)
    :param take: whether the step happens
    """
    params = [param for group in optimizer.param_groups for param in group["params"] if param.grad is not None]
    before = {
        param: (
            param.detach().clone(),
            {
                name: value.clone()
                for name, value in optimizer.state.get(param, {}).items()
                if isinstance(value, Tensor)
            },
        )
        for param in params
    }
    optimizer.step()
    with th.no_grad():
        for param, (value, state) in before.items():
            param.copy_(th.where(take, param, value))
            for name, now in optimizer.state[param].items():
                if isinstance(now, Tensor):
                    old = state.get(name)
                    now.copy_(th.where(take, now, th.zeros_like(now) if old is None else old))


class CapturedUpdateMixin:
    """What :class:`sb3_sgfd.common.encoder_sac.EncoderSAC` adds to SB3's algorithm for its update's runner (mixed in
    before SB3's ``SAC``): the figures on the device, the optimisers set up for the way the update runs, the learning
    rate set in place, and the graphs forgotten whenever parameters or states are replaced."""

    compile_update: bool
    device: th.device
    logger: Any
    lr_schedule: Callable[[float], float]
    _current_progress_remaining: float
    _n_updates: int
    _update: CapturedUpdate
    _figures: DeviceFigures
    _finite_checked: int
    _optimizers_prepared: bool

    def record(
        self, key: str, value: float | th.Tensor, check_finite: str | None = None, when: th.Tensor | None = None
    ) -> None:
        """Log a figure of this gradient step (summed on the device; the log shows the mean over the steps since the
        last log); with ``check_finite``, a non-finite value stops training, naming it and its update.

        :param key: the logger's key
        :param value: a 0-d tensor or a number
        :param check_finite: what the value is, for the stop's message; None: not checked
        :param when: a 0-d bool tensor: the value counts only where it is true
        """
        self._figures.add(key, value, when)
        if check_finite is not None:
            assert isinstance(value, th.Tensor)
            self._figures.check(check_finite, value)

    def _captures_update(self) -> bool:
        """Whether the update runs as captured (and compiled) work (``compile_update``; a model saved before it
        existed has none)."""
        return bool(getattr(self, "compile_update", False))

    def _prepare_update(self) -> None:
        """The update's runner, optimisers and figures, made or fixed up before the steps (after a load, a
        ``set_parameters`` or a device change they are set up afresh)."""
        captured = self._captures_update()
        runner = getattr(self, "_update", None)
        if (
            runner is None
            or runner.device != self.device
            or runner.capture != (captured and self.device.type == "cuda")
        ):
            self._update = CapturedUpdate(self.device, captured, generators=lambda: self.generators().values())
            self._figures = DeviceFigures(self.device)
            self._finite_checked = self._n_updates
            self._optimizers_prepared = False
        if not self._optimizers_prepared:
            prepare_optimizers(self._update_optimizers(), self._update.capture)
            self._optimizers_prepared = True
        self._figures.start(self._n_updates)

    def _update_optimizers(self) -> list[th.optim.Optimizer]:
        """Every optimiser a gradient step steps."""
        raise NotImplementedError

    def generators(self) -> dict[str, th.Generator]:
        """The generators the steps draw from beside the global ones."""
        raise NotImplementedError

    def _update_learning_rate(self, optimizers: list[th.optim.Optimizer] | th.optim.Optimizer) -> None:
        # SB3's, with the rate set in place where it is a tensor (a captured graph reads it there)
        self.logger.record("train/learning_rate", self.lr_schedule(self._current_progress_remaining))
        for optimizer in optimizers if isinstance(optimizers, list) else [optimizers]:
            set_learning_rate(optimizer, self.lr_schedule(self._current_progress_remaining))

    def _after_train(self) -> None:
        """After a ``train`` call: the figures into the logger (eager: now, one host read; captured: once per log
        interval), and with the update captured the non-finite check at least every ``FINITE_CHECK_UPDATES``."""
        if not self._update.capture:
            self._log_figures()
        elif self._n_updates - self._finite_checked >= FINITE_CHECK_UPDATES:
            self._finite_checked = self._n_updates
            self._figures.raise_if_not_finite()

    def _log_figures(self) -> None:
        """The figures since the last read, into the logger (one host read)."""
        for key, mean in self._figures.read().items():
            self.logger.record(key, mean)

    def dump_logs(self) -> None:
        if getattr(self, "_update", None) is not None and self._update.capture:
            self._log_figures()  # + once per log interval when captured
        super().dump_logs()  # type: ignore[misc]  # SB3's, after this mixin

    def set_parameters(
        self, load_path_or_dict: str | dict[str, Any], exact_match: bool = True, device: th.device | str = "auto"
    ) -> None:
        super().set_parameters(load_path_or_dict, exact_match=exact_match, device=device)  # type: ignore[misc]
        self._forget_update()

    def _forget_update(self) -> None:
        """New parameters, optimiser states or generators: the captured graphs are replayed no more, and the
        optimisers are set up again at the next ``train``."""
        if getattr(self, "_update", None) is not None:
            self._update.reset()
        self._optimizers_prepared = False

    def _excluded_save_params(self) -> list[str]:
        excluded = super()._excluded_save_params()  # type: ignore[misc]
        return [*excluded, "_update", "_figures", "_finite_checked", "_optimizers_prepared"]

    def save(self, *args: Any, **kwargs: Any) -> None:
        if getattr(self, "_figures", None) is not None:
            self._figures.raise_if_not_finite()  # nothing non-finite is saved
        super().save(*args, **kwargs)  # type: ignore[misc]
