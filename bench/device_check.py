"""The device check: what a GPU machine's minutes are for, in one script and one markdown table.

Runs, each in a subprocess stopped at its own time limit (:data:`BUDGETS`; they add up to less than
:data:`TOTAL_SECONDS`, 8 minutes, the whole check's worst case on a GPU host with 16 CPU cores):

1. the tests marked ``cuda`` (pinned replay transfers, GPU-saved models loading on the CPU and back, the paper's
   agent with every tensor on the GPU);
2. ``bench/update_overhead.py`` for the MLP, the CNN and the agents, with GPU-sized warm-up and rounds;
3. ``bench/env_throughput.py`` (rendering with MUJOCO_GL=egl, which uses the GPU's EGL where it has one);
4. a learning run of the paper's agent (``sgfd_sac``: SGFD on AMBS) and of AMBS on SGFD/walker-walk-v0 with the
   zoo's paper-scale settings, the 4 training domains rendered in parallel processes: updates per second once
   learning has started, and the hours a paper-scale run (500k updates) would take at that rate.

Each row is written to the table (``--out``) and printed the moment its part ends, so a check stopped from
outside keeps every row it measured; a part that runs past its limit gets a row saying so, and the others run.

``--smoke`` runs the same on the CPU at toy sizes (the agents' overhead rows left out) in under 2 minutes on an
idle 2-core machine (CI runs it, so the script cannot rot between GPU sessions); its figures say nothing about
speed.

    python bench/device_check.py --out device_check.md          # on the GPU machine
    python bench/device_check.py --smoke                         # anywhere
"""

from __future__ import annotations

import argparse
import os
import re
import subprocess
import sys
import time
from argparse import Namespace
from collections.abc import Callable, Iterator
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
PAPER_UPDATES = 500_000
#: The whole check's worst case, seconds: every part stopped at its limit, plus this script's own start.
TOTAL_SECONDS = 8 * 60
#: Each part's time limit on the GPU host, seconds.
BUDGETS: dict[str, float] = {
    "cuda": 75,
    "overhead mlp": 40,
    "overhead cnn": 55,
    "overhead agents": 90,
    "throughput": 85,
    "learning sgfd_sac": 60,
    "learning ambs": 60,
}
#: What the script needs besides its parts (importing torch, writing the table).
OWN_SECONDS = 15
#: The same parts at toy sizes on the CPU (the agents' overhead left out): ceilings for a busy CI machine (on an
#: idle one the whole smoke run takes about 2 minutes).
SMOKE_BUDGETS: dict[str, float] = {
    "cuda": 150,
    "overhead mlp cnn": 150,
    "throughput": 120,
    "learning sgfd_sac": 120,
    "learning ambs": 120,
}
#: Seconds a learning run measures updates for, once learning has started (the rest of its budget builds it).
LEARNING_SECONDS = {False: 25.0, True: 5.0}
LEARNING_ENV = "SGFD/walker-walk-v0"


def run(command: list[str], budget: float) -> tuple[int, str, float]:
    """``command`` from the repository root, stopped after ``budget`` seconds: (exit code, output, seconds)."""
    start = time.perf_counter()
    try:
        done = subprocess.run(command, cwd=REPO, capture_output=True, text=True, timeout=budget)
        code, output = done.returncode, done.stdout + done.stderr
    except subprocess.TimeoutExpired as timeout:
        code, output = 124, _text(timeout.stdout) + _text(timeout.stderr) + f"\n(stopped after {budget:.0f} s)"
    return code, output, time.perf_counter() - start


def _text(value: bytes | str | None) -> str:
    return value.decode(errors="replace") if isinstance(value, bytes) else (value or "")


def _last_line(output: str) -> str:
    lines = [line for line in output.splitlines() if line.strip()]
    return lines[-1][:200] if lines else ""


def cuda_tests(budgets: dict[str, float], smoke: bool) -> Iterator[str]:
    # one process (-n 0): xdist's workers would each collect the whole suite for a handful of tests
    command = [sys.executable, "-m", "pytest", "-m", "cuda", "-n", "0", "-q", "-rs", "-p", "no:cacheprovider", "tests"]
    code, output, seconds = run(command, budgets["cuda"])
    summary = next((line for line in reversed(output.splitlines()) if re.search(r"passed|failed|skipped", line)), "")
    verdict, figures = "ok" if code == 0 else f"exit {code}", summary.strip(" =") or _last_line(output)
    yield f"| CUDA tests (`pytest -m cuda`) | {verdict} | {figures} ({seconds:.0f} s) |"


def overhead(budgets: dict[str, float], smoke: bool) -> Iterator[str]:
    """bench/update_overhead.py, one policy per row (in smoke mode all three in one process, at toy sizes)."""
    if smoke:
        toy = ["--rounds", "1", "--round-steps", "1", "--warmup", "1", "--fill", "20", "--batch-size", "8"]
        runs = [("mlp cnn", [*toy, "--image-size", "16", "--policies", "mlp", "cnn"])]
    else:
        runs = [(policy, ["--rounds", "4", "--policies", policy]) for policy in ("mlp", "cnn", "agents")]
    for label, flags in runs:
        code, output, seconds = run([sys.executable, "bench/update_overhead.py", *flags], budgets[f"overhead {label}"])
        if code != 0:
            yield f"| update_overhead {label} | exit {code} | {_last_line(output)} |"
            continue
        figures = [line.strip() for line in output.splitlines() if " / " in line and "x" in line]
        steps = [
            f"{cells[1].strip()} {cells[2].strip()} ms"
            for cells in (line.split("|") for line in output.splitlines())
            if len(cells) > 3 and cells[1].strip() in ("SAC", "SGFD steady", "SGFD on AMBS", "SGFD on AMBS (before)")
        ]
        yield f"| update_overhead {label} | ok | {'; '.join(steps + figures)} ({seconds:.0f} s) |"


def throughput(budgets: dict[str, float], smoke: bool) -> Iterator[str]:
    flags = ["--steps", "3", "--rounds", "1", "--warmup", "1"] if smoke else ["--rounds", "2"]
    code, output, seconds = run([sys.executable, "bench/env_throughput.py", *flags], budgets["throughput"])
    # one line per method compared: ours, theirs (the benchmark's own) and the fast path, and the ratios
    lines = [" ".join(line.split()) for line in output.splitlines() if "ours/theirs" in line]
    verdict = "ok" if code == 0 else f"exit {code}"
    yield (
        f"| env_throughput (MUJOCO_GL={os.environ.get('MUJOCO_GL', 'egl')}) | {verdict} | "
        f"{'; '.join(lines) or _last_line(output)} ({seconds:.0f} s) |"
    )


def learning(budgets: dict[str, float], smoke: bool) -> Iterator[str]:
    """Each agent's learning run in a subprocess of this script (``--learning-run``), stopped at its limit."""
    for algo in ("sgfd_sac", "ambs"):
        command = [sys.executable, __file__, "--learning-run", algo, *(["--smoke"] if smoke else [])]
        code, output, seconds = run(command, budgets[f"learning {algo}"])
        row = next((line for line in output.splitlines() if line.startswith(f"| {algo} on ")), None)
        if code != 0 or row is None:
            row = f"| {algo} learning run | exit {code} | {_last_line(output)} ({seconds:.0f} s) |"
        yield row


def learning_rate_of(algo: str, env_id: str, seconds: float, smoke: bool) -> str:
    """One zoo run of ``algo`` for ``seconds`` after learning starts: updates/s and a paper-scale run's hours."""
    import tempfile

    import torch as th
    from stable_baselines3.common.callbacks import BaseCallback

    from sgfd_zoo.experiment import SGFDExperimentManager

    class StopAfter(BaseCallback):
        """Counts updates from the first one, and stops ``seconds`` later."""

        def __init__(self) -> None:
            super().__init__()
            self.start: float | None = None
            self.first = 0

        def _on_step(self) -> bool:
            if self.start is None and self.model._n_updates > 0:
                self.start, self.first = time.perf_counter(), self.model._n_updates
            return self.start is None or time.perf_counter() - self.start < seconds

    device = "cuda" if th.cuda.is_available() and not smoke else "cpu"
    if smoke:
        th.set_num_threads(1)  # toy networks: more threads only contend
    with tempfile.TemporaryDirectory() as folder:
        manager = SGFDExperimentManager(
            Namespace(),
            algo,
            env_id,
            folder,
            eval_freq=-1,
            quick=smoke,
            seed=0,
            verbose=0,
            device=device,
            vec_env_type="dummy" if smoke else "subproc",
        )
        try:
            model, _ = manager.setup_experiment()
            if smoke:
                model.learning_starts = 50
            stop = StopAfter()
            model.learn(10**9, callback=stop)
            if stop.start is None:
                raise RuntimeError(f"no gradient step in the run (learning_starts {model.learning_starts})")
            rate = (model._n_updates - stop.first) / (time.perf_counter() - stop.start)
            shape = "x".join(str(size) for size in model.observation_space.shape)
            kind = f"{'quick' if smoke else 'paper scale'}, observations {shape}, batch {model.batch_size}"
            model.env.close()
        finally:
            manager.release_run_folder()
    hours = PAPER_UPDATES / rate / 3600
    return f"| {algo} on {env_id}, {kind}, {device} | ok | {rate:.1f} updates/s: a 500k-update run in {hours:.1f} h |"


# The parts in order; each yields its rows as they are measured.
PARTS: tuple[Callable[[dict[str, float], bool], Iterator[str]], ...] = (cuda_tests, overhead, throughput, learning)


class Table:
    """The markdown table, each row appended (and flushed to the disk) as it comes.

    :param path: the file, or None for stdout only
    :param header: the lines above the rows
    """

    def __init__(self, path: Path | None, header: list[str]):
        self.path = path
        self.rows: list[str] = []
        print("\n".join(header), flush=True)
        if path is not None:
            path.write_text("\n".join(header) + "\n")

    def add(self, row: str) -> None:
        self.rows.append(row)
        print(row, flush=True)
        if self.path is not None:
            with self.path.open("a") as handle:
                handle.write(row + "\n")
                handle.flush()
                os.fsync(handle.fileno())


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--smoke", action="store_true", help="toy sizes on the CPU, under 2 minutes")
    parser.add_argument("--out", type=Path, help="also write the table to this markdown file, row by row")
    parser.add_argument("--learning-run", metavar="ALGO", help=argparse.SUPPRESS)  # one learning row (a part)
    args = parser.parse_args()
    if args.smoke:  # the subprocesses' toy networks on one thread each: more only contend
        os.environ["OMP_NUM_THREADS"] = "1"
    if args.learning_run is not None:
        print(learning_rate_of(args.learning_run, LEARNING_ENV, LEARNING_SECONDS[args.smoke], args.smoke), flush=True)
        return
    import torch as th

    gpu = th.cuda.get_device_name(0) if th.cuda.is_available() else "no CUDA device"
    budgets = SMOKE_BUDGETS if args.smoke else BUDGETS
    header = [
        f"device check, {time.strftime('%Y-%m-%d %H:%M')}: {gpu}, {os.cpu_count()} CPU cores"
        + (" (--smoke: toy sizes, no speed figures)" if args.smoke else "")
        + f"; parts stopped at {sum(budgets.values()):.0f} s in all",
        "",
        "| check | result | figures |",
        "|---|---|---|",
    ]
    table = Table(args.out, header)
    for part in PARTS:
        for row in part(budgets, args.smoke):
            table.add(row)
    if any("| failed |" in row or "| exit" in row for row in table.rows):
        sys.exit(1)


if __name__ == "__main__":
    main()
