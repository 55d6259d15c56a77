"""The device check: what a GPU machine's minutes are for, in one script and one markdown table.

Runs, each within its own time budget (the whole in about 8 minutes on one GPU with 16 CPU cores):

1. the tests marked ``cuda`` (pinned replay transfers, GPU-saved models loading on the CPU and back, the paper's
   agent with every tensor on the GPU);
2. ``bench/update_overhead.py`` for the MLP, the CNN and the agents, with GPU-sized warm-up and rounds;
3. ``bench/env_throughput.py`` (rendering with MUJOCO_GL=egl, which uses the GPU's EGL where it has one);
4. a learning run of the paper's agent (``sgfd_sac``: SGFD on AMBS) and of AMBS on SGFD/walker-walk-v0 with the
   zoo's paper-scale settings, the 4 training domains rendered in parallel processes: updates per second once
   learning has started, and the hours a paper-scale run (500k updates) would take at that rate.

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
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
PAPER_UPDATES = 500_000


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


def cuda_tests(smoke: bool) -> list[str]:
    code, output, seconds = run([sys.executable, "-m", "pytest", "-m", "cuda", "-q", "-rs", "tests"], 120)
    summary = next((line for line in reversed(output.splitlines()) if re.search(r"passed|failed|skipped", line)), "")
    verdict = "ok" if code == 0 else f"exit {code}"
    return [f"| CUDA tests (`pytest -m cuda`) | {verdict} | {summary.strip(' =')} ({seconds:.0f} s) |"]


def overhead(smoke: bool) -> list[str]:
    """bench/update_overhead.py, one policy per row (in smoke mode all three in one process, at toy sizes)."""
    if smoke:
        toy = ["--rounds", "1", "--round-steps", "1", "--warmup", "1", "--fill", "20", "--batch-size", "8"]
        runs = [("mlp cnn", [*toy, "--image-size", "16", "--policies", "mlp", "cnn"], 60)]
    else:
        runs = [(policy, ["--rounds", "5", "--policies", policy], budget) for policy, budget in OVERHEAD_BUDGETS]
    rows = []
    for label, flags, budget in runs:
        code, output, seconds = run([sys.executable, "bench/update_overhead.py", *flags], budget)
        if code != 0:
            rows.append(f"| update_overhead {label} | exit {code} | {_last_line(output)} |")
            continue
        figures = [line.strip() for line in output.splitlines() if " / " in line and "x" in line]
        steps = [
            f"{cells[1].strip()} {cells[2].strip()} ms"
            for cells in (line.split("|") for line in output.splitlines())
            if len(cells) > 3 and cells[1].strip() in ("SAC", "SGFD steady", "SGFD on AMBS", "SGFD on AMBS (before)")
        ]
        rows.append(f"| update_overhead {label} | ok | {'; '.join(steps + figures)} ({seconds:.0f} s) |")
    return rows


OVERHEAD_BUDGETS = (("mlp", 60), ("cnn", 90), ("agents", 150))


def throughput(smoke: bool) -> list[str]:
    flags = ["--steps", "3", "--rounds", "1", "--benchmark-steps", "2", "--warmup", "1"] if smoke else ["--rounds", "2"]
    code, output, seconds = run([sys.executable, "bench/env_throughput.py", *flags], 60 if smoke else 150)
    lines = [line.strip() for line in output.splitlines() if "steps/s" in line or "speed-up" in line]
    verdict = "ok" if code == 0 else f"exit {code}"
    return [
        f"| env_throughput (MUJOCO_GL={os.environ.get('MUJOCO_GL', 'egl')}) | {verdict} | "
        f"{'; '.join(lines[:4])} ({seconds:.0f} s) |"
    ]


def _last_line(output: str) -> str:
    lines = [line for line in output.splitlines() if line.strip()]
    return lines[-1][:200] if lines else ""


def learning_rate_of(algo: str, env_id: str, seconds: float, smoke: bool) -> str:
    """One zoo run of ``algo`` for ``seconds`` after learning starts: updates/s and a paper-scale run's hours."""
    import tempfile

    import torch as th
    from stable_baselines3.common.callbacks import BaseCallback

    from sgfd_zoo.experiment import SGFDExperimentManager, register_algorithms

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

    register_algorithms()
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
        model, _ = manager.setup_experiment()
        if smoke:
            model.learning_starts = 50
        stop = StopAfter()
        model.learn(10**9, callback=stop)
        if stop.start is None:
            raise RuntimeError(f"no gradient step in the run (learning_starts {model.learning_starts})")
        rate = (model._n_updates - stop.first) / (time.perf_counter() - stop.start)
        model.env.close()
    hours = PAPER_UPDATES / rate / 3600
    kind = "quick (states)" if smoke else "paper scale, 84x84, 3 frames, batch 128"
    return f"| {algo} on {env_id}, {kind}, {device} | ok | {rate:.1f} updates/s: a 500k-update run in {hours:.1f} h |"


def learning(smoke: bool) -> list[str]:
    rows = []
    for algo in ("sgfd_sac", "ambs"):
        try:
            rows.append(learning_rate_of(algo, "SGFD/walker-walk-v0", 5 if smoke else 120, smoke))
        except Exception as error:  # the table says what failed; the other checks still run
            rows.append(f"| {algo} learning run | failed | {type(error).__name__}: {str(error)[:200]} |")
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--smoke", action="store_true", help="toy sizes on the CPU, under 2 minutes")
    parser.add_argument("--out", type=Path, help="also write the table to this markdown file")
    args = parser.parse_args()
    if args.smoke:  # the subprocesses' toy networks on one thread each: more only contend
        os.environ["OMP_NUM_THREADS"] = "1"
    import torch as th

    gpu = th.cuda.get_device_name(0) if th.cuda.is_available() else "no CUDA device"
    header = [
        f"device check, {time.strftime('%Y-%m-%d %H:%M')}: {gpu}, {os.cpu_count()} CPU cores"
        + (" (--smoke: toy sizes, no speed figures)" if args.smoke else ""),
        "",
        "| check | result | figures |",
        "|---|---|---|",
    ]
    rows = []
    for check in (cuda_tests, overhead, throughput, learning):
        rows += check(args.smoke)
        print(rows[-1], flush=True)
    table = "\n".join(header + rows) + "\n"
    print("\n" + table)
    if args.out is not None:
        args.out.write_text(table)
    if any("| failed |" in row or "| exit" in row for row in rows):
        sys.exit(1)


if __name__ == "__main__":
    main()
