"""The pieces of a gradient step replayed as CUDA graphs (``compile_update=True`` on CUDA): :class:`CapturedUpdate`.

On a GPU these agents' networks are small: an eager gradient step is hundreds of kernel launches (about 25 us each on
a recent host) and a few host reads (about 110 us each), while the arithmetic takes microseconds. A piece (the
augmented views, the step itself, a weighting's classifier round) is run eagerly (on a side stream) for its first
``warmup`` calls of each *plan* (the host's decisions for the step, e.g. whether the actor learns), then captured once
as a CUDA graph and replayed from then on: one launch per piece and plan. The replay batch is copied into static input
tensors first; every state the graphs touch (parameters, optimiser moments, target networks, the figures' sums) is
updated in place.
"""

from __future__ import annotations

from collections import defaultdict
from collections.abc import Callable, Hashable, Iterable
from contextlib import contextmanager
from typing import Any, ParamSpec, TypeVar

import torch as th
from torch import Tensor

T = TypeVar("T")
P = ParamSpec("P")

#: Calls of each piece and plan run eagerly before the capture (lazy state, cuBLAS workspaces, compilation).
WARMUP_CALLS = 2


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
