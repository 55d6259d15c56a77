"""
``sgfd-zoo quick``: the main job, SGFD against its SAC (Domain Randomisation) baseline. A sweep (``sgfd-zoo
sweep``) of both with the quick configuration (sgfd_zoo/hyperparams/quick: state observations with the morphology
parameter, 128-wide networks, 20k steps, SGFD's classifier from the fifth of the run) on two seeds, one run per CPU
core at a time, with live progress; then evaluation on the training domains and the unseen ones: the paper-style
tables, and the aggregate statistics with 95% confidence intervals over the seeds; and the learning curves.
``-n`` sets another length, and SGFD's classifier start moves with it; ``--short`` is the whole pipeline in a few
minutes, too short to learn the task. Runs already finished in the folder are kept, so running it again only
adds what is missing (e.g. more --seeds).
"""

from __future__ import annotations

import datetime
import json
import os
import platform
import shlex
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from sgfd_zoo.algos import SGFD_ALGOS, hyperparams_entry, is_sgfd
from sgfd_zoo.arguments import ZooArgumentParser, ZooError, check_at_least, check_env_id

DEFAULT_ENV = "SGFD/MT-walker-walk-v0"
DEFAULT_ALGOS = ("sgfd_sac", "sac")  # SGFD and its Domain Randomisation baseline
EVAL_EPISODES = 8  # episodes per split in the final evaluation: the tables
# --short: a run length and final evaluation episodes for a job of a few minutes.
SHORT_STEPS = 4_000
SHORT_EVAL_EPISODES = 4
CURVE_POINTS = 4  # evaluations during each run, the last at its end
# Episodes per split at each of them: one per training domain (the final evaluation, for the tables, has more).
CURVE_EPISODES = 4


def quick_setting(algo: str, env_id: str, key: str) -> object:
    """``key`` in the quick configuration of ``algo`` on ``env_id``, in the entry rl-zoo3 reads (None if unset)."""
    return hyperparams_entry(algo, env_id, quick=True).get(key)


def common_setting(algos: Sequence[str], env_id: str, key: str) -> object:
    """``key`` of the quick configuration, the same for each of ``algos``; a ZooError when they differ."""
    values = {algo: quick_setting(algo, env_id, key) for algo in algos}
    if len(set(values.values())) > 1:
        raise ZooError(f"--algos: their quick configurations differ in {key} ({values}); give it explicitly")
    return next(iter(values.values()))


def scaled_classifier_start(algos: Sequence[str], env_id: str, n_timesteps: int) -> int | None:
    """
    SGFD's ``classifier_start`` for a quick run of ``n_timesteps``: the quick configuration's, moved in proportion
    to the run's length, so that a shorter run still trains SGFD's classifier and reweights for the same share of
    it. None when no algorithm of ``algos`` is SGFD's or the run has the configuration's length.

    :param algos: the job's algorithm keys
    :param env_id: its env id
    :param n_timesteps: its run length
    """
    sgfd = [algo for algo in algos if is_sgfd(algo)]
    if not sgfd:
        return None
    start, length = (int(common_setting(sgfd, env_id, key)) for key in ("classifier_start", "n_timesteps"))  # type: ignore[call-overload]
    return None if n_timesteps == length else round(start * n_timesteps / length)


def check_run_lengths(folder: Path, algos: Sequence[str], env_id: str, n_timesteps: int) -> None:
    """A ZooError when ``folder`` holds runs of these algorithms on ``env_id`` of another length: the job keeps
    the runs it finds finished, and its tables would mix lengths."""
    from sgfd_zoo.runs.folders import find_runs

    other = []
    for run in find_runs(folder, algos, [env_id], finished=False):
        steps = int(run.args.get("n_timesteps") or -1)
        steps = steps if steps > 0 else int(quick_setting(run.algo, env_id, "n_timesteps"))  # type: ignore[call-overload]
        if steps != n_timesteps:
            other.append(f"{run.algo} seed {run.seed}: {steps}")
    if other:
        raise ZooError(
            f"--folder {folder} holds runs of another length ({', '.join(other)} steps); this job trains "
            f"{n_timesteps} steps per run: choose another --folder"
        )


def main(argv: list[str]) -> int:
    parser = ZooArgumentParser(prog="sgfd-zoo quick", description=__doc__)
    parser.add_argument("--env", default=DEFAULT_ENV, help="a registered id (sgfd_envs.ENV_IDS)")
    parser.add_argument(
        "--algos",
        nargs="+",
        default=list(DEFAULT_ALGOS),
        choices=sorted(SGFD_ALGOS),
        metavar="ALGO",
        help=f"algorithm keys (default: {' '.join(DEFAULT_ALGOS)}): {', '.join(SGFD_ALGOS)}",
    )
    parser.add_argument("--seeds", nargs="+", type=int, default=[0, 1], help="seeds: the spread of the results")
    parser.add_argument(
        "-f", "--folder", type=Path, help="log folder (default: logs/quick, with --short logs/quick-short)"
    )
    length = parser.add_mutually_exclusive_group()
    default_steps = common_setting(DEFAULT_ALGOS, DEFAULT_ENV, "n_timesteps")
    length.add_argument(
        "-n",
        "--n-timesteps",
        type=int,
        help=f"steps per run (default: the quick configuration's, {default_steps} on {DEFAULT_ENV}); SGFD's "
        "classifier start moves with it",
    )
    length.add_argument(
        "--short",
        action="store_true",
        help=f"-n {SHORT_STEPS} and --eval-episodes {SHORT_EVAL_EPISODES}: every part in a few minutes, too short "
        "to learn the task",
    )
    parser.add_argument(
        "--eval-episodes", type=int, help=f"episodes per split in the final evaluation (default: {EVAL_EPISODES})"
    )
    parser.add_argument(
        "--curve-episodes",
        type=int,
        help=f"episodes per split at each of the {CURVE_POINTS} evaluations during a run, the learning curves "
        f"(default: {CURVE_EPISODES}, or --eval-episodes if fewer)",
    )
    parser.add_argument(
        "--progress-interval", type=float, default=60.0, help="seconds between progress blocks in a log"
    )
    parser.add_argument(
        "--record", type=Path, help="write the job's command, machine, time, settings and final tables here (json)"
    )
    args = parser.parse_args(argv)
    check_env_id(args.env)
    check_at_least("--n-timesteps", args.n_timesteps, 1)
    check_at_least("--eval-episodes", args.eval_episodes, 1)
    check_at_least("--curve-episodes", args.curve_episodes, 1)

    if args.short:
        args.n_timesteps = SHORT_STEPS
    started, load_at_start = time.perf_counter(), _load()
    eval_episodes = args.eval_episodes or (SHORT_EVAL_EPISODES if args.short else EVAL_EPISODES)
    n_timesteps = args.n_timesteps or int(common_setting(args.algos, args.env, "n_timesteps"))  # type: ignore[call-overload]
    folder = args.folder or Path("logs/quick-short" if args.short else "logs/quick")
    check_run_lengths(folder, args.algos, args.env, n_timesteps)
    eval_freq = max(n_timesteps // CURVE_POINTS, 1)
    curve_episodes = args.curve_episodes or min(CURVE_EPISODES, eval_episodes)
    classifier_start = scaled_classifier_start(args.algos, args.env, n_timesteps)
    sweep_args = ["--algos", *args.algos, "--envs", args.env, "--seeds", *map(str, args.seeds)]
    sweep_args += ["-f", str(folder), "--n-episodes", str(eval_episodes)]
    sweep_args += ["--progress-interval", str(args.progress_interval)]
    train_args = ["--quick", "-n", str(n_timesteps), "--eval-freq", str(eval_freq)]
    train_args += ["--eval-episodes", str(curve_episodes), "--no-progress", "--verbose", "0"]
    if classifier_start is not None:
        train_args += ["--classifier-start", str(classifier_start)]
    settings = dict(
        algos=args.algos, env=args.env, seeds=args.seeds, n_timesteps=n_timesteps, classifier_start=classifier_start,
        eval_freq=eval_freq, curve_episodes=curve_episodes, eval_episodes=eval_episodes, folder=str(folder),
    )  # fmt: skip
    print(*settings_lines(settings), sep="\n", flush=True)
    # here: --help and a bad flag answer without loading the sweep
    from sgfd_zoo.report import plot
    from sgfd_zoo.sweep import command as sweep

    status = sweep.main([*sweep_args, *train_args])
    if status != 0:
        return status
    plot.main(["-f", str(folder)])
    print(
        f"quick: the tables above are the final figures: each run's final model evaluated on {eval_episodes} "
        f"episodes per split (the '[k/n] finished' lines gave each run's last evaluation during training, "
        f"{curve_episodes} episodes per split)"
    )
    print(*written_lines(folder), sep="\n")
    if args.record is not None:
        seconds = time.perf_counter() - started
        write_record(args.record, argv, folder, settings, seconds, load_at_start)
    return status


def settings_lines(settings: dict[str, Any]) -> list[str]:
    """What the job runs, said before it starts: algorithms, env, seeds, run length, SGFD's classifier start, the
    evaluations during training and at the end, the folder."""
    seeds = " ".join(map(str, settings["seeds"]))
    lines = [
        f"quick: {' and '.join(settings['algos'])} on {settings['env']}, seeds {seeds}, "
        f"{settings['n_timesteps']} steps per run, into {settings['folder']}"
    ]
    if settings["classifier_start"] is not None:
        lines.append(
            f"quick: SGFD's classifier starts at step {settings['classifier_start']} (the configuration's start moved "
            "with the run's length; the runs' logs print the configuration's value, then the one used)"
        )
    lines.append(
        f"quick: each run is evaluated every {settings['eval_freq']} steps on {settings['curve_episodes']} episodes "
        f"per split (the learning curves), and at the end on {settings['eval_episodes']} (the final tables)"
    )
    return lines


def _size(nbytes: int) -> str:
    """``2_345_678`` as ``2.3 MB``."""
    for unit, scale in (("GB", 1e9), ("MB", 1e6), ("kB", 1e3)):
        if nbytes >= scale:
            return f"{nbytes / scale:.1f} {unit}"
    return f"{nbytes} B"


def written_sizes(folder: Path) -> dict[str, int]:
    """The bytes under ``folder`` by kind: ``tables`` (its own files), ``plots``, ``runs`` (the run folders, their
    checkpoints left out), ``checkpoints`` and, of those, ``replay buffers``."""
    sizes = dict.fromkeys(("tables", "plots", "runs", "checkpoints", "replay buffers"), 0)
    for path in folder.rglob("*"):
        if path.is_symlink() or not path.is_file():
            continue
        parts, size = path.relative_to(folder).parts, path.stat().st_size
        if len(parts) == 1:
            sizes["tables"] += size
        elif parts[0] == "plots":
            sizes["plots"] += size
        elif path.name.startswith("checkpoint"):
            sizes["checkpoints"] += size
            sizes["replay buffers"] += size if path.name.startswith("checkpoint_replay_buffer") else 0
        else:
            sizes["runs"] += size
    return sizes


def written_lines(folder: Path) -> list[str]:
    """What the job wrote into ``folder``, a line per kind with its size."""
    sizes = written_sizes(folder)
    tables = sorted(path.name for path in folder.iterdir() if path.is_file() and not path.is_symlink())
    plots = sorted(folder.glob("plots/*.png"))
    return [
        f"quick: wrote {_size(sum(sizes[k] for k in ('tables', 'plots', 'runs', 'checkpoints')))} into {folder}:",
        f"  {', '.join(tables)}: the tables and statistics ({_size(sizes['tables'])})",
        f"  plots/: {len(plots)} figures, learning curves and statistics ({_size(sizes['plots'])})",
        f"  <algo>/<env>_<id>/: each run's model, logs and evaluations ({_size(sizes['runs'])}), and its checkpoints "
        f"({_size(sizes['checkpoints'])}, of which replay buffers {_size(sizes['replay buffers'])}): they resume a "
        "stopped run; a finished run no longer needs them",
    ]


def _load() -> float | None:
    """The 1-minute load average (None where the platform has none)."""
    return round(os.getloadavg()[0], 2) if hasattr(os, "getloadavg") else None


def sgfd_weights(folder: Path, algos: Sequence[str], env_id: str) -> dict[str, dict[str, float]]:
    """Per finished SGFD run: the first logged step with weights, and the least and most weight ESS logged
    (fractions of the batch)."""
    from sgfd_zoo.runs.folders import find_runs

    found = {}
    for run in find_runs(folder, [algo for algo in algos if is_sgfd(algo)], [env_id]):
        steps, ess = run.log("sgfd/weight_ess")
        if len(ess):
            name = f"{run.algo} seed {run.seed}"
            found[name] = {"first_step": int(steps[0]), "ess_min": float(ess.min()), "ess_max": float(ess.max())}
    return found


def write_record(
    path: Path, argv: Sequence[str], folder: Path, settings: dict[str, Any], seconds: float, load: float | None
) -> None:
    """The job's record (json): its command, date, machine, wall time, settings, final tables and statistics,
    SGFD's weights per run, and the sizes of what it wrote. The figures the docs quote come from such records.

    :param path: the json file
    :param argv: the job's command line (after ``sgfd-zoo quick``)
    :param folder: its log folder
    :param settings: what it ran (:func:`settings_lines`' dict)
    :param seconds: its wall time
    :param load: the 1-minute load average when it started
    """
    cpu = platform.processor()
    if Path("/proc/cpuinfo").is_file():
        names = [
            line.split(":", 1)[1].strip()
            for line in Path("/proc/cpuinfo").read_text().splitlines()
            if "model name" in line
        ]
        cpu = names[0] if names else cpu
    record = {
        "command": shlex.join(["sgfd-zoo", "quick", *argv]),
        "date": datetime.date.today().isoformat(),
        "machine": {"platform": platform.platform(), "cpu": cpu, "cpus": os.cpu_count(), "load_1min": load},
        "load_1min_at_end": _load(),
        "wall_seconds": round(seconds, 1),
        "settings": settings,
        "results": (folder / "results.md").read_text(),
        "aggregate": (folder / "aggregate.md").read_text(),
        "sgfd_weights": sgfd_weights(folder, settings["algos"], settings["env"]),
        "written_bytes": written_sizes(folder),
    }
    path.write_text(json.dumps(record, indent=2) + "\n")
