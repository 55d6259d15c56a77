"""
``sgfd-zoo sweep``: train every (algorithm, env, seed) as a Ray task, on this machine or on an existing
Ray cluster (``--address``), then evaluate the finished runs and print the paper's tables.

Each run is ``sgfd-zoo train`` in a fresh Ray worker process, writing the log layout ``train`` writes:
LOGDIR/<algo>/<EnvName>_<run id>/, its output going to LOGDIR/<algo>/<EnvName>_<run id>.log. A run's id
is its seed unless that folder already holds another seed's run. Running the same command again resumes
the sweep: finished runs are skipped, and unfinished ones continue from their last checkpoint (one none of
whose checkpoints verifies starts again from step 0, saying so in its log). Ctrl-C stops each running run
at a checkpoint, as it stops ``sgfd-zoo train``. A run folder with unreadable files is reported and planned
around; if the progress board dies, the runs go on without live progress.
"""

from __future__ import annotations

import argparse
import contextlib
import logging
import math
import os
import socket
import sys
import time
import traceback
from collections.abc import Collection, Iterator, Sequence
from pathlib import Path
from typing import Any

import sgfd_envs  # before anything imports dm_control: it picks MuJoCo's headless GL backend
from sgfd_zoo import evaluate, training
from sgfd_zoo.algos import SGFD_ALGOS
from sgfd_zoo.arguments import TrainingStopped, ZooError, checked_names, flag_value, has_flag
from sgfd_zoo.progress import LiveView, ProgressBoard, progress_block, returns_text
from sgfd_zoo.runs import NoUsableCheckpoint, find_runs
from sgfd_zoo.sweep_plan import Job, plan

# Train flags the sweep sets per run itself, and what to use instead.
SWEEP_OWNED_FLAGS = {
    "--algo": "--algos",
    "--env": "--envs",
    "--seed": "--seeds",
    "--resume": "nothing (the sweep resumes every run that has a checkpoint)",
    "-uuid": "nothing (each run gets its own folder)",
    "--uuid": "nothing (each run gets its own folder)",
    "-optimize": "sgfd-zoo optimize",
    "--optimize-hyperparameters": "sgfd-zoo optimize",
}
MAX_SEED = 2**32 - 1  # numpy's limit, which rl-zoo3 seeds with
BOARD_NAME = "sgfd-zoo sweep progress"  # the progress board actor, in this sweep's Ray namespace


# -- one run, in a Ray worker -----------------------------------------------------------------------


def train_job(job: Job, train_args: list[str], cwd: str, board: Any = None) -> bool:
    """
    The Ray task: ``sgfd-zoo train`` of ``job`` in this worker process, its output appended to the job's
    log file, its progress sent to ``board``. Resumes from the run's checkpoint when it has one, and starts
    it again from step 0 when none of its checkpoints verifies. Returns whether it resumed.

    :param job: The run
    :param train_args: Flags for ``sgfd-zoo train`` besides --algo, --env, --seed, -f
    :param cwd: The driver's working directory (relative paths in ``train_args`` are relative to it)
    :param board: A ``ProgressBoard`` actor handle, or None
    """
    if os.path.isdir(cwd):
        os.chdir(cwd)
    # Decided here, not when planning: a retry after a crash continues from the newest checkpoint.
    resume = job.run.checkpoint is not None
    argv = ["--algo", job.algo, "--env", job.env_id, "--seed", str(job.seed), "-f", str(job.folder)]
    argv += ["--run-id", str(job.run_id), *train_args]
    reporter = None if board is None else (lambda report: board.report.remote(job.name, report))
    job.log_file.parent.mkdir(parents=True, exist_ok=True)
    with _output_to(job.log_file):
        what = "resuming from its checkpoint" if resume else "new run"
        print(f"=== sgfd-zoo sweep, {time.strftime('%Y-%m-%d %H:%M:%S')}: {job} in {job.run_dir} ({what})", flush=True)
        try:
            try:
                training.train([*argv, "--resume"] if resume else argv, progress_reporter=reporter)
            except NoUsableCheckpoint as error:
                print(f"{error}\n=== so starting it again from step 0", flush=True)
                resume = False
                training.train(argv, progress_reporter=reporter)
        except TrainingStopped as error:
            print(f"sgfd-zoo train: {error}", flush=True)  # where it stopped and how it goes on, in one line
            raise
        except SystemExit as error:
            # argparse exits on bad flags; a SystemExit would end the Ray worker (a "crash" Ray retries).
            sys.stderr.flush()
            raise RuntimeError(f"sgfd-zoo train exited with status {error.code}: {_last_line(job.log_file)}") from None
        except BaseException:
            traceback.print_exc()
            raise
    if not job.run.finished:
        raise RuntimeError(f"sgfd-zoo train ended, but {job.run_dir} is not a finished run")
    return resume


@contextlib.contextmanager
def _output_to(path: Path) -> Iterator[None]:
    """Send this process's stdout and stderr (file descriptors, so C libraries' output too) to ``path``."""
    sys.stdout.flush()
    sys.stderr.flush()
    saved = os.dup(1), os.dup(2)
    log = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_APPEND, 0o644)
    try:
        os.dup2(log, 1)
        os.dup2(log, 2)
        yield
    finally:
        sys.stdout.flush()
        sys.stderr.flush()
        os.dup2(saved[0], 1)
        os.dup2(saved[1], 2)
        for fd in (log, *saved):
            os.close(fd)


def _last_line(path: Path, tail: int = 4096) -> str:
    with path.open("rb") as handle:
        handle.seek(max(path.stat().st_size - tail, 0))
        lines = [line.strip() for line in handle.read().decode(errors="replace").splitlines()]
    return next((line for line in reversed(lines) if line), "")


# -- the command ------------------------------------------------------------------------------------


def parse_args(argv: Sequence[str]) -> tuple[argparse.Namespace, list[str]]:
    """The sweep's options, checked, and the flags left for ``sgfd-zoo train``."""
    parser = argparse.ArgumentParser(
        prog="sgfd-zoo sweep",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
        # An abbreviation such as --algo must reach the check below, not silently mean --algos.
        allow_abbrev=False,
        epilog="Every other option goes to each run's `sgfd-zoo train` (see sgfd-zoo train -h), e.g.\n"
        "  sgfd-zoo sweep --algos sgfd_sac sac --envs SGFD/MT-walker-walk-v0 --seeds 0 1 2 --quick -n 20000",
    )
    parser.add_argument("--algos", nargs="+", required=True, help=f"algorithm keys: {', '.join(SGFD_ALGOS)}")
    parser.add_argument("--envs", nargs="+", required=True, help="SGFD env ids")
    parser.add_argument("--seeds", nargs="+", type=int, required=True, help="training seeds (>= 0)")
    parser.add_argument(
        "-f", "--folder", "--log-folder", type=Path, default=Path("logs"), help="log folder (default: logs)"
    )
    parser.add_argument(
        "--address",
        help="an existing Ray cluster (host:port, or 'auto' for the one `ray start` started here); the log "
        "folder must then be a path every node sees. Default: a Ray instance on this machine, for this sweep",
    )
    parser.add_argument("--num-cpus", type=int, help="CPUs of the local Ray instance (default: all)")
    parser.add_argument("--cpus-per-run", type=float, default=1.0, help="CPUs Ray reserves for each run (default: 1)")
    parser.add_argument(
        "--gpus-per-run", type=float, default=0.0, help="GPUs for each run; fractions share one (default: 0)"
    )
    parser.add_argument(
        "--max-retries",
        type=int,
        default=3,
        help="restarts of a run whose worker process died (killed, out of memory, node lost); it continues "
        "from its last checkpoint. Python errors are reported, not retried (default: 3)",
    )
    parser.add_argument("--n-episodes", type=int, default=10, help="evaluation episodes per split (default: 10)")
    parser.add_argument("--no-evaluate", action="store_true", help="train only; no tables")
    parser.add_argument("--reference", default="sgfd_sac", help="the algorithm the statistics compare with the others")
    parser.add_argument(
        "--progress-interval",
        type=float,
        default=60.0,
        help="seconds between progress blocks when the output is not a terminal (a terminal redraws live)",
    )
    parser.add_argument("--ray-logs", action="store_true", help="show Ray's own warnings and log lines")
    args, train_args = parser.parse_known_args(argv)

    args.algos = checked_names("--algos", args.algos, list(SGFD_ALGOS))
    args.envs = checked_names("--envs", args.envs, list(sgfd_envs.ENV_IDS))
    args.seeds = list(dict.fromkeys(args.seeds))
    for seed in args.seeds:
        if not 0 <= seed <= MAX_SEED:
            raise ZooError(f"--seeds: {seed} is not in 0..{MAX_SEED}")
    for flag, instead in SWEEP_OWNED_FLAGS.items():
        if has_flag(train_args, flag):
            raise ZooError(f"{flag} is set per run by the sweep; use {instead}")
    if args.cpus_per_run <= 0:
        raise ZooError(f"--cpus-per-run must be > 0, got {args.cpus_per_run}")
    if args.gpus_per_run < 0:
        raise ZooError(f"--gpus-per-run must be >= 0, got {args.gpus_per_run}")
    if args.max_retries < 0:
        raise ZooError(f"--max-retries must be >= 0, got {args.max_retries}")
    if args.n_episodes < 1:
        raise ZooError(f"--n-episodes must be >= 1, got {args.n_episodes}")
    if args.address is not None and args.num_cpus is not None:
        raise ZooError("--num-cpus sizes the local Ray instance; a cluster given by --address has its own size")
    if args.num_cpus is not None and args.num_cpus < 1:
        raise ZooError(f"--num-cpus must be >= 1, got {args.num_cpus}")
    local_cpus = args.num_cpus or os.cpu_count() or 1
    if args.address is None and args.cpus_per_run > local_cpus:
        raise ZooError(f"--cpus-per-run {args.cpus_per_run:g} is more than the {local_cpus} CPUs of the local instance")
    if args.folder.exists() and not args.folder.is_dir():
        raise ZooError(f"--folder {args.folder} is not a folder")
    args.folder = args.folder.resolve()
    # torch's threads per run follow the CPUs Ray reserves for it, unless the user says otherwise.
    if args.progress_interval <= 0:
        raise ZooError(f"--progress-interval must be > 0, got {args.progress_interval:g}")
    if not has_flag(train_args, "--num-threads"):
        train_args += ["--num-threads", str(max(math.floor(args.cpus_per_run), 1))]
    return args, train_args


def main(argv: list[str], recorded: Collection[tuple[str, str, int]] = ()) -> int:
    """``sgfd-zoo sweep``.

    :param argv: its command line
    :param recorded: (algo, env, seed) finished elsewhere, not to train (a study's records)
    """
    args, train_args = parse_args(argv)
    jobs, done, problems = plan(args.folder, args.algos, args.envs, args.seeds, recorded)
    for problem in problems:
        print(f"sweep: {problem}; read as if it were absent")
    n_resume = sum(job.run.checkpoint is not None for job in jobs)
    print(
        f"sweep: {len(jobs) + len(done)} runs ({len(args.algos)} algos x {len(args.envs)} envs x {len(args.seeds)} "
        f"seeds) in {args.folder}: {len(done)} finished already, {len(jobs)} to train ({n_resume} to resume)"
    )
    # Each (algorithm, env) configuration is read and checked here first: a flag that does not fit fails
    # once, in one line, instead of in every Ray task.
    for algo, env_id in dict.fromkeys((job.algo, job.env_id) for job in jobs):
        argv = ["--algo", algo, "--env", env_id, "-f", str(args.folder), "--seed", "0", *train_args]
        training.train(argv, check_only=True)
    failures: list[tuple[Job, str]] = []
    if jobs:
        try:
            failures = run_jobs(jobs, train_args, args)
        except KeyboardInterrupt:
            print("\nsweep: interrupted; the same command resumes it (unfinished runs from their checkpoints)")
            return 130
    if not args.no_evaluate:
        _evaluate(args, train_args)
    print(f"\nsweep: {len(jobs) - len(failures)} trained, {len(done)} already finished, {len(failures)} failed")
    for job, error in failures:
        print(f"  FAILED {job}: {error} (log: {job.log_file})")
    return 1 if failures else 0


def run_jobs(jobs: list[Job], train_args: list[str], args: argparse.Namespace) -> list[tuple[Job, str]]:
    """Run ``jobs`` as Ray tasks, showing their progress; returns the failed ones with a one-line reason.
    Ray is shut down after. Ctrl-C stops the running runs at a checkpoint each, then raises
    KeyboardInterrupt; a second Ctrl-C stops them at once."""
    import ray

    _start_ray(args)
    try:
        board = ray.remote(num_cpus=0)(ProgressBoard).options(name=BOARD_NAME).remote()
        task = ray.remote(
            num_cpus=args.cpus_per_run,
            num_gpus=args.gpus_per_run,
            # A fresh process per run: rl-zoo3's train() sets process-wide state (torch threads, seeds,
            # sys.argv, the algorithm table), and a long run's memory is given back when it ends.
            max_calls=1,
            max_retries=args.max_retries,
            retry_exceptions=False,
        )(train_job)
        cwd = os.getcwd()
        pending = {task.options(name=f"sweep {job}").remote(job, train_args, cwd, board): job for job in jobs}
        failures: list[tuple[Job, str]] = []
        with LiveView(args.progress_interval) as view:
            try:
                _wait_for(pending, jobs, board, view, failures)
            except KeyboardInterrupt:
                _stop_at_checkpoints(pending, view)
                raise
        return failures
    finally:
        ray.shutdown()


def _wait_for(
    pending: dict[Any, Job], jobs: list[Job], board: Any, view: LiveView, failures: list[tuple[Job, str]]
) -> None:
    """Until no run is ``pending``: show their progress, a line per run as it ends, the failed ones added to
    ``failures``."""
    import ray

    status: dict[str, str] = {}
    reports: dict[str, dict[str, Any]] = {}
    while pending:
        done, _ = ray.wait(list(pending), num_returns=1, timeout=1.0)
        if board is not None:
            try:
                reports = ray.get(board.snapshot.remote())
            except ray.exceptions.RayActorError as error:
                # Only the live view is lost: the runs report to a dead actor, which Ray drops.
                board, reports = None, {}
                view.message(f"sweep: the progress board stopped ({_reason(error)}); the runs go on")
        for ref in done:
            job = pending.pop(ref)
            count = f"[{len(jobs) - len(pending)}/{len(jobs)}]"
            report = reports.get(job.name, {})
            try:
                resumed = ray.get(ref)
            except ray.exceptions.RayError as error:
                failures.append((job, _reason(error)))
                status[job.name] = "FAILED"
                view.message(f"{count} FAILED {job}: {failures[-1][1]} (log: {job.log_file})")
            else:
                status[job.name] = "finished"
                evaluated = returns_text(report)
                view.message(
                    f"{count} finished {job}{' (resumed)' if resumed else ''}"
                    + (f": {evaluated}" if evaluated else "")
                    + f" ({job.run_dir})"
                )
        view.show(progress_block([job.name for job in jobs], reports, status), force=not pending)


def _stop_at_checkpoints(pending: dict[Any, Job], view: LiveView) -> None:
    """Stop every ``pending`` run as a Ctrl-C stops ``sgfd-zoo train`` (at a checkpoint, at a step boundary),
    wait for them, and say where each stopped. A waiting run is dropped. A second Ctrl-C stops the waiting
    (then ``ray.shutdown`` ends the runs where they are)."""
    import ray

    view.message(
        "sweep: interrupted; the running runs stop at a checkpoint each (Ctrl-C again: at once, losing the steps "
        "since their last checkpoint)"
    )
    # A running Ray task's cancel raises KeyboardInterrupt in it through its SIGINT handler: the train's own
    # deferred Ctrl-C, which checkpoints and stops. A terminal's Ctrl-C does not reach the workers themselves
    # (each has a process group of its own), so this is their only one.
    before = {job: job.run.checkpoint for job in pending.values()}
    for ref in pending:
        ray.cancel(ref)
    ray.wait(list(pending), num_returns=len(pending))
    for job in pending.values():
        run = job.run
        checkpoint = None if run.finished else run.checkpoint
        if run.finished:
            view.message(f"finished {job} ({job.run_dir})")
        elif checkpoint is not None and checkpoint != before[job]:
            view.message(f"stopped {job} at its checkpoint at {checkpoint.num_timesteps} steps ({job.run_dir})")


def _start_ray(args: argparse.Namespace) -> None:
    import ray

    # Each run's output is in its log file; Ray's own warnings (token authentication, ...) only when asked for.
    quiet = {"log_to_driver": False, "logging_level": logging.WARNING if args.ray_logs else logging.ERROR}
    if args.address is not None:
        _check_reachable(args.address)
        try:
            ray.init(address=args.address, **quiet)
        except (ConnectionError, ValueError, RuntimeError) as error:
            raise ZooError(f"--address {args.address}: no Ray cluster to connect to ({error})") from None
        cpus, gpus = ray.cluster_resources().get("CPU", 0), ray.cluster_resources().get("GPU", 0)
        print(f"sweep: Ray cluster at {args.address}: {cpus:g} CPUs, {gpus:g} GPUs")
        return
    # "local": a new instance even if `ray start` left one running on this machine.
    ray.init(address="local", num_cpus=args.num_cpus, include_dashboard=False, **quiet)
    cpus, gpus = ray.cluster_resources().get("CPU", 0), ray.cluster_resources().get("GPU", 0)
    if args.ray_logs:
        print(f"sweep: local Ray instance: {cpus:g} CPUs, {gpus:g} GPUs")
    if args.gpus_per_run > gpus:
        # Ray would wait forever for a GPU no node of this instance has.
        ray.shutdown()
        raise ZooError(f"--gpus-per-run {args.gpus_per_run:g}: Ray sees {gpus:g} GPUs on this machine")


def _check_reachable(address: str, timeout: float = 10.0) -> None:
    """
    Refuse a host:port nothing listens on: Ray itself retries such an address for minutes (13 on our
    machine) before it gives up. Other forms ('auto', 'ray://...') are left to Ray.

    :param address: The --address value
    :param timeout: Seconds to wait for a TCP connection
    """
    host, _, port = address.rpartition(":")
    if "://" in address or not host or not port.isdigit():
        return
    try:
        with socket.create_connection((host.strip("[]"), int(port)), timeout=timeout):
            pass
    except OSError as error:
        raise ZooError(f"--address {address}: no Ray cluster answers there ({error})") from None


def _reason(error: Exception) -> str:
    """One line for the summary: the run's own exception when it raised one, else what Ray says."""
    cause = getattr(error, "cause", None)
    if isinstance(cause, BaseException):
        text, name = str(cause), type(cause).__name__
    else:
        text, name = str(error), type(error).__name__
    lines = [line.strip() for line in text.splitlines() if line.strip()]
    return f"{name}: {lines[0] if lines else '(no message)'}"


def _evaluate(args: argparse.Namespace, train_args: list[str]) -> None:
    if not find_runs(args.folder, args.algos, args.envs):
        print("sweep: no finished run to evaluate")
        return
    # Evaluation is small-batch inference: as many threads as each run had.
    threads = flag_value(train_args, "--num-threads") or "1"
    evaluate_args = ["-f", str(args.folder), "--algo", *args.algos, "--env", *args.envs]
    evaluate_args += ["--reference", args.reference]
    evaluate.main([*evaluate_args, "--n-episodes", str(args.n_episodes), "--num-threads", threads])
