"""Tiny ``sgfd-zoo train`` runs for the tests of faults and writers: the quick configuration of SAC on states, cut
to a few hundred steps with a tiny network, run in this process (:func:`zoo`) or in a subprocess
(:class:`Training`)."""

from __future__ import annotations

import contextlib
import io
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path

from sgfd_cli import main as zoo_main
from sgfd_zoo.runs.checkpoints import read_index

ENV_ID = "SGFD/MT-walker-walk-v0"
NAME = "SGFD-MT-walker-walk-v0"
SETTINGS = ["--quick", "--num-threads", "1", "--no-progress", "--verbose", "0", "--eval-freq", "-1"]
# One update per env step (of the 4 sub-envs), from step 100.
TINY_PARAMS = ["learning_starts:100", "gradient_steps:1", "batch_size:64", "policy_kwargs:dict(net_arch=[32])"]
SETTINGS += ["-params", *TINY_PARAMS, "buffer_size:2000"]


def train_args(folder: Path, *extra: str, seed: int = 0, steps: int = 400, save_freq: int = 200) -> list[str]:
    """``sgfd-zoo train`` of a tiny SAC run into ``folder``, with checkpoints every ``save_freq`` steps."""
    args = ["train", "--algo", "sac", "--env", ENV_ID, "--seed", str(seed), "-f", str(folder), *SETTINGS]
    return [*args, "-n", str(steps), "--save-freq", str(save_freq), *extra]


def zoo(args: list[str]) -> tuple[int, str, list[str]]:
    """``sgfd-zoo`` in this process: exit code, stdout, and the lines of stderr."""
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = zoo_main(args)
    return code, out.getvalue(), [line for line in err.getvalue().splitlines() if line.strip()]


class Training:
    """``sgfd-zoo train`` in a subprocess, its output in files.

    :param args: its arguments
    :param folder: where its output goes
    """

    def __init__(self, args: list[str], folder: Path):
        folder.mkdir(parents=True, exist_ok=True)
        self.out, self.err = folder / "stdout.txt", folder / "stderr.txt"
        with self.out.open("w") as out, self.err.open("w") as err:
            self.process = subprocess.Popen([sys.executable, "-m", "sgfd_cli", *args], stdout=out, stderr=err)

    def wait_until(self, condition: Callable[[], bool], timeout: float = 300, poll: float = 0.005) -> None:
        deadline = time.monotonic() + timeout
        while not condition():
            assert self.process.poll() is None, f"ended early:\n{self.err.read_text()[-3000:]}"
            assert time.monotonic() < deadline, "timed out"
            time.sleep(poll)

    def send(self, signum: int, times: int = 1) -> int:
        """Send ``signum`` ``times`` times; its exit code."""
        for _ in range(times):
            self.process.send_signal(signum)
            time.sleep(0.02)
        return self.process.wait(timeout=300)

    def error_lines(self) -> list[str]:
        return [line for line in self.err.read_text().splitlines() if line.strip()]

    def last_error(self) -> str:
        """The last line of stderr, which must hold no traceback."""
        lines = self.error_lines()
        assert not any("Traceback" in line for line in lines), self.err.read_text()[-3000:]
        return lines[-1]


def has_checkpoint(run: Path, after: int = 0) -> Callable[[], bool]:
    """Whether ``run`` has a checkpoint of more than ``after`` steps."""

    def check() -> bool:
        try:
            return bool(read_index(run)) and read_index(run)[0].num_timesteps > after
        except Exception:  # not there yet, or being replaced
            return False

    return check
