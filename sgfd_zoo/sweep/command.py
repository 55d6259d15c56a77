"""
``sgfd-zoo sweep``: train every (algorithm, env, seed) as a Ray task, on this machine or on an existing
Ray cluster (``--address``), then evaluate the finished runs and print the paper's tables.

Each run is ``sgfd-zoo train`` in a fresh Ray worker process, writing the log layout ``train`` writes:
LOGDIR/<algo>/<EnvName>_<run id>/, its output going to LOGDIR/<algo>/<EnvName>_<run id>.log. A run's id
is its seed unless that folder already holds another seed's run. Running the same command again resumes
the sweep: finished runs are skipped, and unfinished ones continue from their last checkpoint (one none of
whose checkpoints verifies starts again from step 0, saying so in its log). Ctrl-C stops each running run
at a checkpoint, as it stops ``sgfd-zoo train``. A run folder with unreadable files is reported and planned
around; a run another process writes (its lock held) is left alone and reported; if the progress board dies,
the runs go on without live progress.

Where Ray sees GPUs, the runs share them by a rule from each GPU's share of the node's cores
(:func:`sgfd_zoo.sweep.plan.packing`: 8 paper-scale runs on a GPU with 16 cores, each with 1 torch thread and its
training envs in processes of their own); ``--gpus-per-run`` sets the share, ``--gpus-per-run 0`` trains on the CPUs.

Exit status: 0 when every run finished; 1 when one failed or was left alone; 75 when the Ray cluster went away
(the runs keep their checkpoints); 130 on Ctrl-C. Each but 0 ends with a summary (what finished, what failed
and why, what stopped at which checkpoint) and the command that continues the sweep.

``--address`` attaches to a ``ray start`` cluster; when it uses Ray's token authentication (a ``ray start`` that
finds a token turns it on), this machine needs the cluster's token: in ~/.ray/auth_token, RAY_AUTH_TOKEN or
RAY_AUTH_TOKEN_PATH.
"""

from __future__ import annotations

import argparse
import math
import os
import shlex
from collections.abc import Collection, Sequence
from pathlib import Path

import sgfd_envs  # before anything imports dm_control: it picks MuJoCo's headless GL backend
from sgfd_zoo import training
from sgfd_zoo.algos import SGFD_ALGOS
from sgfd_zoo.arguments import (
    ZooArgumentParser,
    ZooError,
    check_log_folder,
    checked_names,
    flag_value,
    has_flag,
    printable,
)
from sgfd_zoo.exit_codes import INTERRUPTED
from sgfd_zoo.report import evaluate
from sgfd_zoo.runs.folders import find_runs
from sgfd_zoo.sweep.plan import Job, envs_per_run, gpu_fraction, locked_runs, plan, replay_bytes
from sgfd_zoo.sweep.ray_runs import ClusterLost, run_jobs

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


# -- the command ------------------------------------------------------------------------------------


def parse_args(argv: Sequence[str]) -> tuple[argparse.Namespace, list[str]]:
    """The sweep's options, checked, and the flags left for ``sgfd-zoo train``."""
    parser = ZooArgumentParser(
        prog="sgfd-zoo sweep",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
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
    parser.add_argument(
        "--cpus-per-run",
        type=float,
        help="CPUs Ray reserves for each run (default: 1 without a GPU, and as many torch threads; with one, the "
        "GPU's share of the node's cores)",
    )
    parser.add_argument(
        "--gpus-per-run",
        metavar="FRACTION",
        help="GPUs for each run: 0.25 packs 4 runs on a GPU, 0 trains on the CPUs. Default: where Ray sees GPUs, "
        "as many runs per GPU as the node's cores feed (up to 8; 2 cores a run at paper scale: see "
        "sgfd_zoo.sweep.plan.packing), each with 1 torch thread and its training envs in processes of their own; "
        "else 0",
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
    if args.cpus_per_run is not None and args.cpus_per_run <= 0:
        raise ZooError(f"--cpus-per-run must be > 0, got {args.cpus_per_run}")
    args.gpus_per_run = gpu_fraction(args.gpus_per_run)
    if args.gpus_per_run is None and flag_value(train_args, "--device") == "cpu":
        args.gpus_per_run = 0.0  # runs told to train on the CPU take no GPU
    if args.max_retries < 0:
        raise ZooError(f"--max-retries must be >= 0, got {args.max_retries}")
    if args.n_episodes < 1:
        raise ZooError(f"--n-episodes must be >= 1, got {args.n_episodes}")
    if args.address is not None and args.num_cpus is not None:
        raise ZooError("--num-cpus sizes the local Ray instance; a cluster given by --address has its own size")
    if args.num_cpus is not None and args.num_cpus < 1:
        raise ZooError(f"--num-cpus must be >= 1, got {args.num_cpus}")
    local_cpus = args.num_cpus or os.cpu_count() or 1
    if args.address is None and args.cpus_per_run is not None and args.cpus_per_run > local_cpus:
        raise ZooError(f"--cpus-per-run {args.cpus_per_run:g} is more than the {local_cpus} CPUs of the local instance")
    check_log_folder("--folder", args.folder)
    args.folder = args.folder.resolve()
    if args.progress_interval <= 0:
        raise ZooError(f"--progress-interval must be > 0, got {args.progress_interval:g}")
    # How many envs a run trains on, and its replay buffer's memory: the packing rule gives each env a process of its
    # own on a GPU node, and puts no more runs on a GPU than their buffers fit in its share of the node's memory.
    quick = has_flag(train_args, "--quick")
    args.envs_per_run = envs_per_run(args.algos, args.envs, quick=quick)
    args.replay_bytes = replay_bytes(args.algos, args.envs, quick=quick)
    return args, train_args


#: The exit code of a sweep whose Ray cluster went away: a temporary failure (sysexits' EX_TEMPFAIL); the same
#: command continues the sweep on a running cluster.
EXIT_CLUSTER_LOST = 75


def main(argv: list[str], recorded: Collection[tuple[str, str, int | None]] = (), rerun: str | None = None) -> int:
    """``sgfd-zoo sweep``. Exits 0 when every run finished, 1 when one failed or was refused (another process
    writes it), 75 when the Ray cluster went away, 130 on Ctrl-C; each but 0 with a summary and the command that
    continues the sweep.

    :param argv: its command line
    :param recorded: (algo, env, seed) finished elsewhere, not to train (a study's records)
    :param rerun: the command that continues the sweep (default: ``sgfd-zoo sweep`` with ``argv``)
    """
    rerun = rerun or shlex.join(["sgfd-zoo", "sweep", *argv])
    args, train_args = parse_args(argv)
    jobs, done, problems = plan(args.folder, args.algos, args.envs, args.seeds, recorded)
    for problem in problems:
        print(printable(f"sweep: {problem}; read as if it were absent"))
    for job in jobs:  # a link in a run's place would take its writes out of the log folder
        job.run.refuse_links()
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
    failures = locked_runs(jobs)  # another process writes them: not started
    for job, reason in failures:
        print(printable(f"sweep: {job}: {reason}"))
    runnable = [job for job in jobs if job not in dict(failures)]
    lost = None
    if runnable:
        try:
            failures += run_jobs(runnable, train_args, args)
        except KeyboardInterrupt:
            print(
                f"\nsweep: interrupted; the same command resumes it (unfinished runs from their checkpoints): {rerun}"
            )
            return INTERRUPTED
        except ClusterLost as error:
            lost = f"the Ray cluster{'' if args.address is None else f' at {args.address}'} went away: {error}"
    if lost is None and not args.no_evaluate:
        _evaluate(args, train_args)
    return summary(jobs, done, failures, lost, rerun)


def summary(
    jobs: list[Job], done: list[tuple[str, str, int]], failures: list[tuple[Job, str]], lost: str | None, rerun: str
) -> int:
    """Print what became of each run (finished, failed and why, stopped at which checkpoint, not started) and,
    unless all finished, the command that continues the sweep; returns the sweep's exit code.

    :param jobs: the runs the sweep trained
    :param done: those finished before it started
    :param failures: the failed runs, with why
    :param lost: why the cluster counts as gone, or None
    :param rerun: the command that continues the sweep
    """
    failed = dict(failures)
    trained = [job for job in jobs if job not in failed and job.run.finished]
    stopped = [job for job in jobs if job not in failed and job not in trained]
    counts = f"{len(trained)} trained, {len(done)} already finished, {len(failed)} failed"
    print(f"\nsweep: {counts}" + (f", {len(stopped)} not finished" if stopped else ""))
    for job, error in failures:
        checkpoint = job.run.checkpoint
        kept = "no checkpoint" if checkpoint is None else f"its checkpoint at {checkpoint.num_timesteps} steps is kept"
        print(printable(f"  FAILED {job}: {error} ({kept}; log: {job.log_file})"))
    for job in stopped:
        checkpoint = job.run.checkpoint
        state = (
            "not started" if checkpoint is None else f"stopped at its checkpoint at {checkpoint.num_timesteps} steps"
        )
        print(f"  {state}: {job} ({job.run_dir})")
    if lost is not None:
        print(f"sweep: {lost}; every checkpoint is kept: on a running cluster, this continues the sweep: {rerun}")
        return EXIT_CLUSTER_LOST
    if failures or stopped:
        print(f"sweep: not every run finished; once the failures are fixed, this continues the sweep: {rerun}")
        return 1
    return 0


def _evaluate(args: argparse.Namespace, train_args: list[str]) -> None:
    if not find_runs(args.folder, args.algos, args.envs):
        print("sweep: no finished run to evaluate")
        return
    # Evaluation is small-batch inference: as many threads as each run had.
    threads = flag_value(train_args, "--num-threads") or str(max(math.floor(args.cpus_per_run or 1), 1))
    evaluate_args = ["-f", str(args.folder), "--algo", *args.algos, "--env", *args.envs]
    evaluate_args += ["--reference", args.reference]
    evaluate.main([*evaluate_args, "--n-episodes", str(args.n_episodes), "--num-threads", threads])
