"""The device check: what a GPU machine's minutes are for, in one script and one markdown table.

Runs, each in a subprocess stopped at its own time limit (:data:`BUDGETS`; with this script's own start they add up
to :data:`TOTAL_SECONDS`, 6 minutes, the worst case on a GPU host with 16 CPU cores, so a 15-minute slot holds the
check twice):

1. the tests marked ``cuda`` (each has a CPU twin that CI runs): pinned replay transfers, models saved on the GPU
   loading on the CPU and back, the paper's agent with its weights started and every tensor on the GPU, its
   update replayed as CUDA graphs;
2. ``bench/update_overhead.py`` for the MLP, the CNN and the agents: the eager and the compiled (captured) update
   side by side in one process, with the operator dispatches per update;
3. ``bench/env_throughput.py`` (rendering with MUJOCO_GL=egl): each split's cost over the undistracted render;
4. a learning run of the paper's agent (``sgfd_sac``: SGFD on AMBS) with the zoo's paper-scale settings, the 4
   training domains rendered in subprocesses, its update captured, measured in SGFD's phase (the classifier from
   ``CLASSIFIER_START`` on, the burst of updates left out): updates per second, the env steps (transitions)
   collected per update and per second of collecting (the env step in the subprocesses with the policy's action and
   the buffer's add), the hours of a paper-scale run (200,800 updates and 1e6 env steps), and where an update's wall
   time goes (the env step, the replay sample and its transfer, the update itself);
5. 4 and 8 such runs at once on the one GPU (each with 4 env processes): their updates per second in all, over a
   window they share.

Each row is written to the table (``--out``) and printed the moment its part ends, so a check stopped from
outside keeps every row it measured; a part that runs past its limit gets a row saying so, and the others run.

``--smoke`` runs the same on the CPU at toy sizes (2 concurrent runs) in about 3 minutes on an idle 2-core machine
(CI runs it, so the script cannot rot between GPU sessions); its figures say nothing about speed.

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
#: A paper-scale run (the authors' protocol, sgfd_zoo/hyperparams): its updates and its env steps.
PAPER_UPDATES, PAPER_ENV_STEPS = 200_800, 1_000_000
#: The whole check's worst case, seconds: every part stopped at its limit, plus this script's own start.
TOTAL_SECONDS = 6 * 60
#: Each part's time limit on the GPU host, seconds.
BUDGETS: dict[str, float] = {
    "cuda": 40,
    "overhead mlp": 30,
    "overhead cnn": 30,
    "overhead agents": 45,
    "throughput": 30,
    "learning sgfd_sac": 55,
    "concurrent 4": 55,
    "concurrent 8": 60,
}
#: What the script needs besides its parts (importing torch, writing the table).
OWN_SECONDS = 15
#: The same parts at toy sizes on the CPU (the agents' overhead and 8 runs left out): ceilings for a busy CI machine
#: (on an idle one the whole smoke run takes about 3 minutes).
SMOKE_BUDGETS: dict[str, float] = {
    "cuda": 150,
    "overhead mlp cnn": 200,
    "throughput": 120,
    "learning sgfd_sac": 150,
    "concurrent 2": 200,
}
#: Seconds a learning run measures for, once its measured phase has started (the rest of its budget builds it).
LEARNING_SECONDS = {False: 20.0, True: 4.0}
#: Seconds concurrent runs are given to start (build, fill, reach SGFD's phase and capture), and to measure.
CONCURRENT_START = {False: 32.0, True: 15.0}
CONCURRENT_WINDOW = {False: 12.0, True: 4.0}
LEARNING_ENV = "SGFD/walker-walk-v0"
#: SGFD's classifier from this env step in the learning runs (the zoo's paper setting is 100k): at its first update
#: (paper scale: learning_starts 1000), so that every measured update is one of SGFD's phase.
CLASSIFIER_START = {False: 1000, True: 50}


def run(command: list[str], budget: float) -> tuple[int, str, float]:
    """``command`` from the repository root, stopped after ``budget`` seconds: (exit code, output, seconds)."""
    start = time.perf_counter()
    try:
        done = subprocess.run(command, cwd=REPO, capture_output=True, text=True, timeout=budget)
        code, output = done.returncode, done.stdout + done.stderr
    except subprocess.TimeoutExpired as timeout:
        code, output = 124, _text(timeout.stdout) + _text(timeout.stderr) + f"\n(stopped after {budget:.0f} s)"
    return code, output, time.perf_counter() - start


def run_together(commands: list[list[str]], budget: float) -> tuple[list[str], float]:
    """``commands`` at once from the repository root, each stopped at ``budget`` seconds from the start: their
    outputs, and the seconds it took."""
    began = time.perf_counter()
    processes = [
        subprocess.Popen(command, cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
        for command in commands
    ]
    outputs = []
    for process in processes:
        try:
            outputs.append(process.communicate(timeout=max(1.0, budget - (time.perf_counter() - began)))[0])
        except subprocess.TimeoutExpired:
            process.kill()
            outputs.append(_text(process.communicate()[0]) + f"\n(stopped after {budget:.0f} s)")
    return outputs, time.perf_counter() - began


def _text(value: bytes | str | None) -> str:
    return value.decode(errors="replace") if isinstance(value, bytes) else (value or "")


def _last_line(output: str) -> str:
    lines = [line for line in output.splitlines() if line.strip()]
    return lines[-1][:200] if lines else ""


def cuda_tests(budgets: dict[str, float], smoke: bool) -> Iterator[str]:
    # one process (-n 0): xdist's workers would each collect the files for a handful of tests
    command = [sys.executable, "-m", "pytest", "-m", "cuda", "-n", "0", "-q", "-rs", "-p", "no:cacheprovider"]
    code, output, seconds = run([*command, "tests/agents"], budgets["cuda"])
    summary = next((line for line in reversed(output.splitlines()) if re.search(r"passed|failed|skipped", line)), "")
    verdict, figures = "ok" if code in (0, 5) and "failed" not in summary else f"exit {code}", summary.strip(" =")
    yield f"| CUDA tests (`pytest -m cuda`) | {verdict} | {figures or _last_line(output)} ({seconds:.0f} s) |"


def overhead(budgets: dict[str, float], smoke: bool) -> Iterator[str]:
    """bench/update_overhead.py, one policy per row (in smoke mode the two policies in one process, at toy sizes)."""
    if smoke:
        toy = ["--rounds", "1", "--round-steps", "1", "--warmup", "3", "--fill", "20", "--batch-size", "8"]
        runs = [("mlp cnn", [*toy, "--image-size", "16", "--policies", "mlp", "cnn"])]
    else:
        rounds = {"mlp": ["--rounds", "3", "--round-steps", "100"], "cnn": ["--rounds", "3", "--round-steps", "25"]}
        rounds["agents"] = ["--rounds", "2", "--round-steps", "15"]
        runs = [(policy, [*rounds[policy], "--warmup", "6", "--policies", policy]) for policy in rounds]
    for label, flags in runs:
        code, output, seconds = run([sys.executable, "bench/update_overhead.py", *flags], budgets[f"overhead {label}"])
        if code != 0:
            yield f"| update_overhead {label} | exit {code} | {_last_line(output)} |"
            continue
        steps = [
            f"{cells[1].strip()} {cells[2].strip()} ms ({cells[4].strip()} dispatches)"
            for cells in (line.split("|") for line in output.splitlines())
            if len(cells) > 5 and re.match(r" (SAC|SGFD (steady|mixed)|AMBS|SGFD on AMBS) ", cells[1])
        ]
        ratios = [line.strip() for line in output.splitlines() if re.search(r" / .*[0-9]x", line)]
        yield f"| update_overhead {label} | ok | {'; '.join(steps + ratios)} ({seconds:.0f} s) |"


#: A split's line of bench/env_throughput.py: our ms per agent step, and the ratios to theirs and to undistracted.
SPLIT_LINE = r" ours +[\d.]+ \( *([\d.]+) ms\).*ours/theirs +([\d.]+)x.*ours/undistracted +(\S+)"


def throughput(budgets: dict[str, float], smoke: bool) -> Iterator[str]:
    flags = ["--steps", "3", "--rounds", "1", "--warmup", "1"] if smoke else ["--steps", "10", "--rounds", "2"]
    code, output, seconds = run([sys.executable, "bench/env_throughput.py", *flags], budgets["throughput"])
    # one line per split compared: ours, theirs (the benchmark's own) and the undistracted render, and the ratios
    lines = [
        f"{line[:58].strip()}: ours {found[1]} ms, ours/theirs {found[2]}x, ours/undistracted {found[3]}"
        for line in output.splitlines()
        if (
            found := re.search(
                r" ours +[\d.]+ \( *([\d.]+) ms\).*ours/theirs +([\d.]+)x.*ours/undistracted +(\S+)", line
            )
        )
    ]
    verdict = "ok" if code == 0 else f"exit {code}"
    yield (
        f"| env_throughput (MUJOCO_GL={os.environ.get('MUJOCO_GL', 'egl')}) | {verdict} | "
        f"{'; '.join(lines) or _last_line(output)} ({seconds:.0f} s) |"
    )


def learning(budgets: dict[str, float], smoke: bool) -> Iterator[str]:
    """The paper's agent's learning run in a subprocess of this script (``--learning-run``), stopped at its limit."""
    command = [sys.executable, __file__, "--learning-run", "sgfd_sac", *(["--smoke"] if smoke else [])]
    code, output, seconds = run(command, budgets["learning sgfd_sac"])
    row = next((line for line in output.splitlines() if line.startswith("| sgfd_sac on ")), None)
    if code != 0 or row is None:
        row = f"| sgfd_sac learning run | exit {code} | {_last_line(output)} ({seconds:.0f} s) |"
    yield row


def concurrent(budgets: dict[str, float], smoke: bool) -> Iterator[str]:
    """Several learning runs at once on one device, each a subprocess measuring the same window of wall time."""
    for n_runs in (2,) if smoke else (4, 8):
        budget = budgets[f"concurrent {n_runs}"]
        start = time.time() + CONCURRENT_START[smoke]
        window = CONCURRENT_WINDOW[smoke]
        command = [sys.executable, __file__, "--learning-run", "sgfd_sac", "--window", f"{start}:{window}"]
        command += ["--threads", "1", *(["--smoke"] if smoke else [])]
        outputs, seconds = run_together([command] * n_runs, budget)
        found = [re.search(r"WINDOW ([0-9.]+) updates/s, ([0-9.]+) env steps per update", out) for out in outputs]
        rates = [float(match[1]) for match in found if match]
        inside = [float(match[2]) for match in found if match]
        late = sum("late" in out for out in outputs)
        if len(rates) < n_runs:
            yield f"| {n_runs} concurrent runs | exit | {len(rates)} of {n_runs} measured: {_last_line(outputs[-1])} |"
            continue
        lateness = f", {late} started measuring late" if late else ""
        yield (
            f"| {n_runs} concurrent sgfd_sac runs, 4 env processes and 1 torch thread each | ok | "
            f"{sum(rates):.1f} updates/s in all, {sum(inside) / len(inside):.2f} env steps per update (each "
            f"{min(rates):.1f}-{max(rates):.1f} updates/s) over a shared {window:.0f} s window{lateness} "
            f"({seconds:.0f} s) |"
        )


class PhaseClock:
    """Where a learning run's wall time goes: collecting (the env step in the subprocesses, the policy's action,
    the buffer's add), the replay sample with its transfer, and the update (with the device waited for at the end
    of each ``train`` call, so that the update's GPU time counts as the update's)."""

    def __init__(self, model, synchronize: Callable[[], None]) -> None:  # type: ignore[no-untyped-def]
        self.totals = {"env step": 0.0, "sample and transfer": 0.0, "update": 0.0}
        self.on = False
        collect, sample, train = model.collect_rollouts, model.replay_buffer.sample, model.train

        def timed(name: str, function: Callable, sync: bool = False) -> Callable:
            def wrapper(*args, **kwargs):  # type: ignore[no-untyped-def]
                if not self.on:
                    return function(*args, **kwargs)
                start = time.perf_counter()
                result = function(*args, **kwargs)
                if sync:
                    synchronize()
                self.totals[name] += time.perf_counter() - start
                return result

            return wrapper

        model.collect_rollouts = timed("env step", collect)
        model.replay_buffer.sample = timed("sample and transfer", sample)
        model.train = timed("update", train, sync=True)

    def per_update(self, updates: int) -> str:
        # the update's time as measured includes the samples it drew
        update = self.totals["update"] - self.totals["sample and transfer"]
        parts = {**self.totals, "update": update}
        return ", ".join(f"{name} {1e3 * seconds / updates:.2f} ms" for name, seconds in parts.items())


def learning_run(algo: str, env_id: str, smoke: bool, window: tuple[float, float] | None, threads: int | None) -> str:
    """One zoo run of ``algo`` at the zoo's settings, its update captured on CUDA; measured from the first update of
    SGFD's phase: updates/s over :data:`LEARNING_SECONDS` (or the shared ``window``: start time, seconds), then
    where an update's time goes."""
    import tempfile

    import torch as th
    from stable_baselines3.common.callbacks import BaseCallback

    from sgfd_zoo.experiment import SGFDExperimentManager

    device = "cuda" if th.cuda.is_available() and not smoke else "cpu"
    if smoke or threads:
        th.set_num_threads(threads or 1)  # toy networks, or one of several runs: more threads only contend

    def synchronize() -> None:
        if device == "cuda":
            th.cuda.synchronize()

    class Measure(BaseCallback):
        """Counts updates from SGFD's phase (a few updates in, past the first captures) and stops at the end."""

        def __init__(self, clock_of: Callable[[], PhaseClock]) -> None:
            super().__init__()
            self.clock_of, self.marks, self.stage = clock_of, [], "wait"

        def _on_step(self) -> bool:
            model, now = self.model, (time.perf_counter(), self.model._n_updates, self.model.num_timesteps)
            ready = model.num_timesteps >= CLASSIFIER_START[smoke] and model._n_updates > 0
            if self.stage == "wait" and ready and window is None:
                self.stage, self.warm_until = "warm", model._n_updates + 40
            elif self.stage == "wait" and ready and window is not None and time.time() >= window[0]:
                self.stage, self.late = "rate", time.time() - window[0] > 1.0
                self.marks = [now]
            elif self.stage == "warm" and model._n_updates >= self.warm_until:
                self.stage, self.marks = "rate", [now]
            elif self.stage == "rate" and now[0] - self.marks[0][0] >= (
                window[1] if window else LEARNING_SECONDS[smoke]
            ):
                self.marks.append(now)
                if window is not None:
                    return False
                self.stage, self.clock_of().on = "split", True
                self.marks.append(now)
            elif self.stage == "split" and now[0] - self.marks[2][0] >= LEARNING_SECONDS[smoke] / 2:
                self.marks.append(now)
                return False
            return True

    clock: list[PhaseClock] = []
    with tempfile.TemporaryDirectory() as folder:
        manager = SGFDExperimentManager(
            Namespace(), algo, env_id, folder, eval_freq=-1, quick=smoke, seed=0, verbose=0, device=device,
            vec_env_type="dummy" if smoke else "subproc", classifier_start=CLASSIFIER_START[smoke],
            hyperparams={"compile_update": True, "callback": []},  # the burst would take the part's minute
        )  # fmt: skip
        try:
            model, _ = manager.setup_experiment()
            if smoke:
                model.learning_starts = 50
            clock.append(PhaseClock(model, synchronize))
            measure = Measure(lambda: clock[0])
            model.learn(10**9, callback=measure)
            if len(measure.marks) < 2:
                raise RuntimeError(f"nothing measured (learning_starts {model.learning_starts})")
            (t0, u0, n0), (t1, u1, n1) = measure.marks[:2]
            rate, inside = (u1 - u0) / (t1 - t0), (n1 - n0) / max(u1 - u0, 1)
            captured = bool(model._update.pieces.graphs)
            weighted = model.weighting is not None and bool(model.weighting.ready)
            shape = "x".join(str(size) for size in model.observation_space.shape)
            model.env.close()
        finally:
            manager.release_run_folder()
    if window is not None:
        return f"WINDOW {rate:.2f} updates/s, {inside:.2f} env steps per update{' (late)' if measure.late else ''}"
    (_, u2, n2), (_, u3, n3) = measure.marks[2:4]
    split = clock[0].per_update(max(1, u3 - u2))
    collecting = (n3 - n2) / max(clock[0].totals["env step"], 1e-9)
    kind = (
        f"{'quick' if smoke else 'paper scale'}, observations {shape}, batch {model.batch_size}, {device}, update "
        f"{'captured' if captured else 'eager'}, SGFD's phase (classifier from step {CLASSIFIER_START[smoke]}, "
        f"weights {'on' if weighted else 'not yet on'})"
    )
    hours = (PAPER_UPDATES * max(1 / rate - inside / collecting, 0.0) + PAPER_ENV_STEPS / collecting) / 3600
    return (
        f"| {algo} on {env_id}, {kind} | ok | {rate:.1f} updates/s, {inside:.2f} env steps per update; collecting "
        f"{collecting:.0f} env steps/s: a paper-scale run ({PAPER_UPDATES:,} updates, {PAPER_ENV_STEPS:,} env steps) "
        f"in {hours:.2f} h; per update (device waited for): {split} |"
    )


def append_rates(path: Path, rows: list[str], machine: str) -> None:
    """The learning runs' updates/s with the env steps inside each (one run, and several at once), and the one run's
    collecting rate (an ``envs`` row), as rows of the zoo's rate table, which ``sgfd-zoo study --plan`` reads (its
    newest date's rows)."""
    import csv

    single = r"\| sgfd_sac on (\S+),.* update (captured|eager).*\| ok \| ([0-9.]+) updates/s, ([0-9.]+) env steps per "
    single += r"update; collecting ([0-9.]+) env steps/s"
    several = (
        r"\| ([0-9]+) concurrent sgfd_sac runs.*\| ok \| ([0-9.]+) updates/s in all, ([0-9.]+) env steps per update"
    )
    date, note = (
        time.strftime("%Y-%m-%d"),
        "bench/device_check.py: zoo paper settings, 4 subprocess envs each, SGFD's phase",
    )
    found = []
    for row in rows:
        if match := re.search(single, row):
            env_id, update = match[1], match[2]
            found.append(["sgfd_sac", env_id, 1, match[3], match[4], "", update, f"{note}, 1 at once"])
            found.append(
                ["envs", env_id, 1, "", "", match[5], "", f"{note}: collecting (env step, action, buffer add)"]
            )
        if match := re.search(several, row):
            runs = int(match[1])
            found.append(
                ["sgfd_sac", LEARNING_ENV, runs, match[2], match[3], "", "captured", f"{note}, {runs} at once"]
            )
    with path.open("a", newline="") as handle:
        writer = csv.writer(handle, lineterminator="\n")
        for algo, env_id, runs, updates, inside, env_steps, update, text in found:
            writer.writerow(
                [
                    date,
                    machine,
                    os.cpu_count(),
                    1,
                    algo,
                    "pixels",
                    env_id,
                    runs,
                    updates,
                    inside,
                    env_steps,
                    update,
                    text,
                ]
            )


# The parts in order; each yields its rows as they are measured.
PARTS: tuple[Callable[[dict[str, float], bool], Iterator[str]], ...] = (
    cuda_tests,
    overhead,
    throughput,
    learning,
    concurrent,
)


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
    parser.add_argument("--smoke", action="store_true", help="toy sizes on the CPU, about 3 minutes")
    parser.add_argument("--out", type=Path, help="also write the table to this markdown file, row by row")
    parser.add_argument(
        "--rates",
        type=Path,
        help="append the learning runs' updates/s to this rate table (sgfd_zoo/sweep/device_rates.csv)",
    )
    parser.add_argument("--learning-run", metavar="ALGO", help=argparse.SUPPRESS)  # one learning row (a part)
    parser.add_argument("--window", help=argparse.SUPPRESS)  # START:SECONDS, a concurrent run's shared window
    parser.add_argument("--threads", type=int, help=argparse.SUPPRESS)  # torch threads of a learning run
    args = parser.parse_args()
    if args.smoke:  # the subprocesses' toy networks on one thread each: more only contend
        os.environ["OMP_NUM_THREADS"] = "1"
    if args.learning_run is not None:
        window = tuple(float(part) for part in args.window.split(":")) if args.window else None
        print(learning_run(args.learning_run, LEARNING_ENV, args.smoke, window, args.threads), flush=True)  # type: ignore[arg-type]
        return
    import torch as th

    gpu = th.cuda.get_device_name(0) if th.cuda.is_available() else "no CUDA device"
    budgets = SMOKE_BUDGETS if args.smoke else BUDGETS
    header = [
        f"device check, {time.strftime('%Y-%m-%d %H:%M')}: {gpu}, {os.cpu_count()} CPU cores, torch {th.__version__}"
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
    if args.rates is not None and not args.smoke:
        append_rates(args.rates, table.rows, gpu)
    if any("| failed |" in row or "| exit" in row for row in table.rows):
        sys.exit(1)


if __name__ == "__main__":
    main()
