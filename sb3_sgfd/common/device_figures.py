"""The figures a training loop logs of its gradient steps, summed where the steps run (the model's device) and read in
one host transfer per log: :class:`DeviceFigures`, the logging path of every EncoderSAC agent, eager or captured. A
loss that stops being finite is remembered with the update it happened at, without a host read."""

from __future__ import annotations

import torch as th
from torch import Tensor


class DeviceFigures:
    """The figures of the gradient steps, summed on the device and read in one host transfer, and the first update
    at which a checked value (a loss) was not finite.

    :param device: where the sums live (the model's device)
    :param replayed: the steps that add figures are replayed as captured graphs, so that the counts of values must
        live on the device too (else they are counted on the host, one operator less per value)
    """

    def __init__(self, device: th.device | str, replayed: bool = False) -> None:
        self.device = th.device(device)
        self.replayed = replayed
        self._sums: dict[str, Tensor] = {}
        self._counts: dict[str, Tensor] = {}
        self._host_counts: dict[str, int] = {}
        self._checked: list[str] = []
        #: The index of the update being run, counted on the device (what a non-finite value is reported at).
        self.update = th.zeros((), dtype=th.int64, device=self.device)
        self._first_bad = th.full((), -1, dtype=th.int64, device=self.device)
        #: The newest values of each histogram (a tensor kept on the device) and whether any came since the last read
        self._kept: dict[str, tuple[Tensor, Tensor]] = {}
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
            self._host_counts[key] = 0
        if when is None and not self.replayed and isinstance(value, Tensor):
            with th.no_grad():  # the sum takes the value's float32 as it is, and counts on the host
                self._sums[key].add_(value.reshape(()))
            self._host_counts[key] += 1
            return
        # a number becomes a tensor by a fill on the device (a copy from the host would not replay)
        value = value.detach() if isinstance(value, Tensor) else th.full((), float(value), device=self.device)
        value = value.to(th.float64).reshape(())
        if when is None:
            self._sums[key].add_(value)
            self._counts[key].add_(1)
        else:
            self._sums[key].add_(th.where(when, value, 0.0))
            self._counts[key].add_(when.to(th.float64))

    def keep(self, key: str, values: Tensor, when: Tensor | None = None) -> None:
        """Keep the newest ``values`` of the histogram ``key`` (e.g. the sample weights), in place on the device;
        with ``when`` (a 0-d bool tensor), only where it is true."""
        values = values.detach()
        if key not in self._kept or self._kept[key][0].shape != values.shape:
            self._kept[key] = (th.zeros_like(values), th.zeros((), dtype=th.bool, device=self.device))
        kept, seen = self._kept[key]
        if when is None:
            kept.copy_(values)
            seen.fill_(True)
        else:
            kept.copy_(th.where(when, values, kept))
            seen.copy_(seen | when)

    def histograms(self) -> dict[str, Tensor]:
        """The histograms kept since the last call, on the host (one transfer each: read once per log)."""
        read = {key: kept.cpu() for key, (kept, seen) in self._kept.items() if bool(seen)}
        for _, seen in self._kept.values():
            seen.fill_(False)
        return read

    def check(self, what: str, value: Tensor) -> None:
        """Remember the update at which ``value`` (0-d) is first not finite, as ``what``, without a host read."""
        if what not in self._checked:
            self._checked.append(what)
        with th.no_grad():
            fresh = th.isfinite(value).logical_not_().logical_and_(self._first_bad < 0)
            self._first_bad.masked_fill_(fresh, self.update)
            self._bad_what.masked_fill_(fresh, self._checked.index(what))

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
        counts = [values[n + i] + self._host_counts[key] for i, key in enumerate(keys)]
        self._host_counts = dict.fromkeys(keys, 0)
        return {key: values[i] / counts[i] for i, key in enumerate(keys) if counts[i] > 0}

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
