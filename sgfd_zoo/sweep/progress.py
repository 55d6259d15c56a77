"""Live progress of a sweep: the runs report to a board (a Ray actor), the driver shows one line per run.

On a terminal the lines redraw in place (rich); in a log or CI the block is printed every ``interval`` seconds.
"""

from __future__ import annotations

import sys
import time
from collections.abc import Sequence
from typing import Any, TextIO


class ProgressBoard:
    """The latest report of each run, by key (used as a Ray actor: ``ray.remote(ProgressBoard)``)."""

    def __init__(self) -> None:
        self.reports: dict[str, dict[str, Any]] = {}

    def report(self, key: str, report: dict[str, Any]) -> None:
        self.reports[key] = {**report, "received": time.time()}

    def snapshot(self) -> dict[str, dict[str, Any]]:
        return dict(self.reports)


def duration(seconds: float) -> str:
    """``1h02m``, ``4m05s`` or ``12s``."""
    seconds = max(int(seconds), 0)
    hours, rest = divmod(seconds, 3600)
    minutes, secs = divmod(rest, 60)
    if hours:
        return f"{hours}h{minutes:02d}m"
    return f"{minutes}m{secs:02d}s" if minutes else f"{secs}s"


def returns_text(report: dict[str, Any]) -> str:
    """The latest evaluation return of each split, e.g. ``train 312.4, extrapolation 88.1``."""
    returns = report.get("returns") or {}
    return ", ".join(f"{split} {value:.1f}" for split, value in returns.items())


def activity_text(report: dict[str, Any], now: float | None = None) -> str:
    """What the run does now, with its pace: ``90 steps/s  ETA  2m37s`` while it learns (the rate and the ETA from
    its learning steps: the warm-up's random actions are many times faster), ``warm-up to step 1000`` before,
    ``evaluating extrapolation for 1m05s`` while an evaluation runs (it reports nothing else meanwhile).

    :param report: the run's latest report (steps, total, steps_per_second, learning_starts, evaluating, ...)
    :param now: the wall-clock time (default: now), for how long the evaluation has run
    """
    steps, total, rate = report["steps"], report["total"], report.get("steps_per_second", 0.0)
    if report.get("evaluating"):
        since = report.get("evaluating_since")
        for_how_long = "" if since is None else f" for {duration((now or time.time()) - since)}"
        return f"evaluating {report['evaluating']}{for_how_long}"
    learning_starts = report.get("learning_starts", 0)
    if steps < learning_starts:
        return f"warm-up to step {learning_starts} (random actions)"
    if rate <= 0 and steps < total:
        return "learning, pace measured at the next report"  # e.g. right after an evaluation at learning_starts
    eta = duration((total - steps) / rate) if rate > 0 and steps < total else "-"
    return f"{rate:>5.0f} steps/s  ETA {eta:>6}"


def progress_line(name: str, report: dict[str, Any], now: float | None = None) -> str:
    """One run's line: steps done of total, what it does now and its pace (:func:`activity_text`), the latest
    evaluation returns.

    :param name: the run, e.g. ``sgfd_sac MT-walker-walk seed 0``
    :param report: its latest report (steps, total, steps_per_second, learning_starts, evaluating, returns)
    :param now: the wall-clock time (default: now)
    """
    steps, total = report["steps"], report["total"]
    line = f"{name:<44} {steps:>8}/{total:<8} {100 * steps / max(total, 1):>3.0f}%  {activity_text(report, now)}"
    evaluated = returns_text(report)
    return f"{line}  last eval: {evaluated}" if evaluated else line


def progress_block(names: Sequence[str], reports: dict[str, dict[str, Any]], status: dict[str, str]) -> list[str]:
    """The lines of the runs under way (reported, not ended) and one line counting the others.

    :param names: every run of the sweep, in order
    :param reports: the latest report of each run that sent one
    :param status: the runs that ended, with their status (``finished`` or ``FAILED``)
    """
    running = [name for name in names if name in reports and name not in status]
    lines = [progress_line(name, reports[name]) for name in running]
    finished = sum(1 for name in names if status.get(name) == "finished")
    failed = sum(1 for name in names if status.get(name) == "FAILED")
    waiting = len(names) - len(running) - finished - failed
    lines.append(f"{len(running)} running, {waiting} waiting, {finished} finished, {failed} failed")
    return lines


class LiveView:
    """Shows a block of lines: redrawn in place on a terminal, printed every ``interval`` seconds otherwise.

    :param interval: seconds between printed blocks when the output is not a terminal
    :param stream: where to write (default: stdout)
    """

    def __init__(self, interval: float = 60.0, stream: TextIO | None = None) -> None:
        self.stream = stream or sys.stdout
        self.interval = interval
        self.terminal = self.stream.isatty()
        self._live: Any = None
        self._last_print: float | None = None  # the first block is printed at once
        self._lines: Sequence[str] = ()

    def __enter__(self) -> LiveView:
        if self.terminal:
            from rich.console import Console
            from rich.live import Live

            self._live = Live(console=Console(file=self.stream), auto_refresh=False, transient=True)
            self._live.__enter__()
        return self

    def __exit__(self, *exc: object) -> None:
        if self._live is not None:
            self._live.__exit__(*exc)
            self._live = None
            # The live block was transient: its final state stays on the screen.
            print(*self._lines, sep="\n", file=self.stream, flush=True)

    def show(self, lines: Sequence[str], force: bool = False) -> None:
        """Display ``lines`` (on a terminal at once; otherwise when the interval has passed, or ``force``)."""
        self._lines = list(lines)
        if self._live is not None:
            from rich.text import Text

            self._live.update(Text("\n".join(lines)), refresh=True)
            return
        now = time.monotonic()
        if force or self._last_print is None or now - self._last_print >= self.interval:
            self._last_print = now
            stamp = time.strftime("%H:%M:%S")
            print(f"--- sweep progress {stamp}", *lines, sep="\n", file=self.stream, flush=True)

    def message(self, text: str) -> None:
        """A line that stays (a run finished or failed), printed above the live block."""
        if self._live is not None:
            self._live.console.print(text, highlight=False, markup=False)
        else:
            print(text, file=self.stream, flush=True)
