"""The exit code of an ``sgfd-zoo`` command stopped by a signal, as a shell gives it: 128 + the signal's number."""

from __future__ import annotations

import signal


def signal_exit_code(signum: int) -> int:
    """128 + ``signum``: what a shell reports for a process the signal ended, so scripts and batch systems read
    a stop at a checkpoint as that signal's."""
    return 128 + int(signum)


#: Ctrl-C (SIGINT): 130.
INTERRUPTED = signal_exit_code(signal.SIGINT)
#: SIGTERM (a batch system's time limit, a preemption): 143.
TERMINATED = signal_exit_code(signal.SIGTERM)
