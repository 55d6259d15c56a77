"""``--record FILE`` for the bench scripts: what a bench prints, kept in a file with its command, date and machine.

The tables docs/performance.md shows are copied from such files (docs/measured/bench-*.txt), and
tests/project/test_docs.py checks each copy against its file.
"""

from __future__ import annotations

import contextlib
import datetime
import io
import os
import platform
import shlex
import sys
from collections.abc import Callable, Iterator
from pathlib import Path


class _Both(io.TextIOBase):
    """Writes to two streams: the terminal and the record."""

    def __init__(self, first: io.TextIOBase, second: io.StringIO):
        self.first, self.second = first, second

    def write(self, text: str) -> int:
        self.first.write(text)
        self.second.write(text)
        return len(text)

    def flush(self) -> None:
        self.first.flush()


def machine_line() -> str:
    """The platform, the CPU model and count, and the 1-minute load average now."""
    cpu = platform.processor()
    cpuinfo = Path("/proc/cpuinfo")
    if cpuinfo.is_file():
        names = [line.split(":", 1)[1].strip() for line in cpuinfo.read_text().splitlines() if "model name" in line]
        cpu = names[0] if names else cpu
    load = f", 1-minute load {os.getloadavg()[0]:.1f}" if hasattr(os, "getloadavg") else ""
    return f"{platform.platform()}, {os.cpu_count()} CPUs ({cpu}){load}"


@contextlib.contextmanager
def recorded(path: str | Path | None, script: str) -> Iterator[None]:
    """Print as usual and, when ``path`` is given, also keep what is printed in ``path``, after a header: the
    command (``python bench/<script> <arguments>``), the date, and the machine at the start and at the end.

    :param path: the record to write (None: print only)
    :param script: the bench's file name
    """
    if path is None:
        yield
        return
    kept = io.StringIO()
    started = machine_line()
    with contextlib.redirect_stdout(_Both(sys.stdout, kept)):  # type: ignore[arg-type]
        yield
    header = [
        f"command: {shlex.join(['python', f'bench/{script}', *sys.argv[1:]])}",
        f"date: {datetime.date.today().isoformat()}",
        f"machine at the start: {started}",
        f"machine at the end: {machine_line()}",
    ]
    Path(path).write_text("\n".join(header) + "\n\n" + kept.getvalue())


def run_recorded(main: Callable[[], object], script_path: str) -> None:
    """Run a bench's ``main`` with ``--record FILE`` taken off the command line first (see :func:`recorded`); its
    ``-h`` lists ``--record`` after the bench's own options.

    :param main: the bench's entry, reading ``sys.argv``
    :param script_path: the bench's ``__file__``
    """
    arguments = sys.argv[1:]
    path = None
    if "--record" in arguments:
        at = arguments.index("--record")
        if at + 1 >= len(arguments):
            sys.exit(f"{Path(script_path).name}: error: --record needs a file name")
        path = arguments[at + 1]
        del arguments[at : at + 2]
    sys.argv[1:] = arguments
    try:
        with recorded(path, Path(script_path).name):
            main()
    except SystemExit:
        if {"-h", "--help"} & set(arguments):
            print("  --record FILE         also write what it prints to FILE, after its command, date and machine")
        raise
