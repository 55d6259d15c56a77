"""The one training entry of the zoo: rl-zoo3's train (and optimize, enjoy) with SGFD's ExperimentManager.

``sgfd-zoo train``, ``optimize`` and the sweep's Ray tasks all call :func:`train`; every rl-zoo3 flag works.
rl-zoo3 builds its ExperimentManager by name from ``sys.argv``, so we hand it :class:`SGFDExperimentManager`
and the arguments for the duration of the call. The zoo's own flags, and the values it checks itself (steps,
frequencies, the seed, the log folder), are read here first, without importing rl-zoo3: ``-h`` is instant and
a bad value is refused before anything loads.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import sys
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from typing import Any

from sgfd_zoo.algos import SGFD_ALGOS
from sgfd_zoo.arguments import (
    ZooError,
    check_at_least,
    check_env_id,
    check_key_values,
    check_log_folder,
    flag_items,
    flag_value,
    has_flag,
    without_flags,
)
from sgfd_zoo.runs.safe import redact_argv

MAX_SEED = 2**32 - 1  # numpy's limit, which rl-zoo3 seeds with
# The zoo's own flags: not rl-zoo3's, taken out before its parser sees the command line.
ZOO_SWITCHES = ("--quick", "--resume", "--no-progress")
ZOO_OPTIONS = ("--algo", "--env", "--run-id", "--classifier-start")


def train_parser(prog: str, optimize: bool = False) -> argparse.ArgumentParser:
    """The options of ``sgfd-zoo train`` (``optimize``): the zoo's own, and rl-zoo3's that the zoo documents and
    checks. Any other rl-zoo3 option is passed on unread."""
    parser = argparse.ArgumentParser(
        prog=prog,
        description="Train an agent with rl-zoo3 on an SGFD env id, with the zoo's hyperparameters"
        + (", searching them with Optuna." if optimize else "."),
        epilog="rl-zoo3's other train options are passed on to it unchanged (e.g. -tb, --vec-env, --log-interval, "
        "--n-eval-envs, --track).",
    )
    zoo = parser.add_argument_group("the zoo's options")
    algos = ", ".join(SGFD_ALGOS)
    zoo.add_argument("--algo", default="sgfd_sac", choices=SGFD_ALGOS, metavar="ALGO", help=f"one of: {algos}")
    zoo.add_argument("--env", metavar="ENV_ID", help="a registered id (sgfd_envs.ENV_IDS), e.g. SGFD/MT-walker-walk-v0")
    zoo.add_argument("--quick", action="store_true", help="the quick configuration (sgfd_zoo/hyperparams/quick)")
    zoo.add_argument("--resume", action="store_true", help="continue the newest run from its last checkpoint")
    zoo.add_argument("--no-progress", action="store_true", help="no progress bar")
    zoo.add_argument(
        "--classifier-start",
        type=int,
        metavar="STEPS",
        help="env steps before SGFD's domain classifier starts training (the SGFD algorithms' classifier_start; "
        "the others have none, so a sweep may mix them)",
    )
    zoo.add_argument(
        "--run-id",
        type=int,
        metavar="ID",
        help="write to (and --resume) the run folder <EnvName>_<id>; default: a new folder",
    )
    run = parser.add_argument_group("the run (rl-zoo3's options, checked by the zoo)")
    run.add_argument(
        "-n", "--n-timesteps", type=int, metavar="STEPS", help="steps to train (default: the configuration's)"
    )
    run.add_argument("-f", "--log-folder", default="logs", metavar="FOLDER", help="log folder (default: logs)")
    run.add_argument("--seed", type=int, default=-1, help=f"0..{MAX_SEED}; -1 (default): a random one")
    run.add_argument(
        "--eval-freq", type=int, default=25000, metavar="STEPS", help="evaluate every n steps; <= 0: never"
    )
    run.add_argument("--eval-episodes", type=int, default=5, metavar="N", help="episodes per split and evaluation")
    run.add_argument(
        "--save-freq", type=int, metavar="STEPS", help="checkpoint every n steps; default: a fifth of the run, <= 100k"
    )
    run.add_argument("--save-replay-buffer", action="store_true", help="keep the replay buffer with the final model")
    run.add_argument(
        "-params", "--hyperparams", nargs="+", metavar="KEY:VALUE", help="override hyperparameters, e.g. batch_size:64"
    )
    run.add_argument(
        "--env-kwargs",
        nargs="+",
        metavar="KEY:VALUE",
        help="env settings merged into the configuration's, e.g. image_size:64",
    )
    run.add_argument(
        "--eval-env-kwargs",
        nargs="+",
        metavar="KEY:VALUE",
        help="env settings of the evaluation envs (default: the same)",
    )
    run.add_argument("-conf", "--conf-file", metavar="YAML", help="a yaml of hyperparameters instead of the zoo's")
    run.add_argument(
        "-i", "--trained-agent", metavar="ZIP", help="a model zip to continue training in a new run folder"
    )
    run.add_argument("--num-threads", type=int, metavar="N", help="torch's CPU threads")
    run.add_argument("--device", help="cpu, cuda, cuda:1, ... (default: auto)")
    run.add_argument("--verbose", type=int, metavar="LEVEL", help="0: quiet, 1: rl-zoo3's output (default)")
    if optimize:
        search = parser.add_argument_group("the search (rl-zoo3's options)")
        search.add_argument("--n-trials", type=int, help="trials of this process")
        search.add_argument("--n-jobs", type=int, help="parallel trials")
        search.add_argument("--storage", help="an Optuna storage shared by processes (a journal .log file, a URL)")
        search.add_argument("--study-name", help="the study's name in the storage")
        search.add_argument("--sampler", choices=["random", "tpe", "auto"], help="Optuna's sampler")
        search.add_argument("--pruner", choices=["halving", "median", "none"], help="Optuna's pruner")
    return parser


def check_run_arguments(args: argparse.Namespace) -> None:
    """The values the zoo checks itself, each refused in one line naming the flag, the value and what fits."""
    check_at_least("-n", args.n_timesteps, 1)
    if not (args.seed == -1 or 0 <= args.seed <= MAX_SEED):
        raise ZooError(f"--seed {args.seed}: expected 0..{MAX_SEED}, or -1 for a random seed")
    check_at_least("--eval-episodes", args.eval_episodes, 1)
    check_at_least("--classifier-start", args.classifier_start, 0)
    check_at_least("--run-id", args.run_id, 0)
    check_log_folder("-f", Path(args.log_folder))
    check_key_values("-params", args.hyperparams)
    check_key_values("--env-kwargs", args.env_kwargs)
    check_key_values("--eval-env-kwargs", args.eval_env_kwargs)


def train(
    argv: Sequence[str],
    optimize: bool = False,
    progress_reporter: Callable[[dict[str, Any]], None] | None = None,
    check_only: bool = False,
) -> int:
    """rl-zoo3's train on SGFD's envs with the zoo's hyperparameters; extra flags: --quick --resume --run-id.

    :param argv: the command line after ``sgfd-zoo train``
    :param optimize: run rl-zoo3's Optuna search instead (``sgfd-zoo optimize``)
    :param progress_reporter: receives progress reports while training (the sweep's live view)
    :param check_only: read and check the configuration (a ZooError if it does not fit), build nothing
    """
    argv = list(argv)
    parser = train_parser(f"sgfd-zoo {'optimize' if optimize else 'train'}", optimize)
    if "-h" in argv or "--help" in argv:
        parser.print_help()
        return 0
    ours, _ = parser.parse_known_args(argv)
    check_env_id(ours.env)
    check_run_arguments(ours)

    import rl_zoo3.train

    from sgfd_zoo.experiment import SGFDExperimentManager, register_algorithms

    rest = ["--algo", ours.algo, "--env", str(ours.env), *without_flags(argv, ZOO_SWITCHES, ZOO_OPTIONS)]
    if optimize:
        rest += ["-optimize"] + ([] if has_flag(rest, "--no-optim-plots") else ["--no-optim-plots"])
    register_algorithms()
    managers: list[SGFDExperimentManager] = []

    def manager(*args: Any, **kwargs: Any) -> SGFDExperimentManager:
        made = SGFDExperimentManager(
            *args,
            quick=ours.quick,
            resume=ours.resume,
            progress=False if ours.no_progress else None,
            run_id=ours.run_id,
            progress_reporter=progress_reporter,
            check_only=check_only,
            command=redact_argv(argv),  # recorded and printed: no URL's credentials
            default_save_freq=ours.save_freq is None,
            default_eval_freq=not has_flag(argv, "--eval-freq"),
            classifier_start=ours.classifier_start,
            **kwargs,
        )
        managers.append(made)
        return made

    quiet = contextlib.redirect_stdout(io.StringIO()) if check_only else contextlib.nullcontext()
    try:
        with replaced(rl_zoo3.train, "ExperimentManager", manager), command_line(parser.prog, rest), quiet:
            rl_zoo3.train.train()
    finally:
        for made in managers:  # whatever ended the run: its folder's lock is given back
            made.release_run_folder()
    return 0


def optimize(argv: Sequence[str]) -> int:
    """rl-zoo3's Optuna search with the SGFD sampler (see sgfd_zoo.registration.sample_sgfd_sac_params)."""
    return train(argv, optimize=True)


def enjoy(argv: Sequence[str]) -> int:
    """rl-zoo3's enjoy on SGFD's registered envs; reads ./logs unless -f says otherwise. Without --exp-id it
    watches the newest finished run (rl-zoo3's newest folder may be a run still training or stopped)."""
    import rl_zoo3.enjoy

    from sgfd_zoo.config_checks import first_line
    from sgfd_zoo.experiment import register_algorithms
    from sgfd_zoo.runs.folders import select_run

    argv = list(argv)
    check_key_values("--env-kwargs", flag_items(argv, "--env-kwargs"))
    register_algorithms()
    if not (has_flag(argv, "-f") or has_flag(argv, "--folder")):
        argv += ["-f", "logs"]
    folder = flag_value(argv, "-f") or flag_value(argv, "--folder") or "logs"
    algo, env_id = flag_value(argv, "--algo"), flag_value(argv, "--env")
    chosen = ("--exp-id", "--load-best", "--load-checkpoint", "--load-last-checkpoint")
    if algo is not None and env_id is not None and not any(has_flag(argv, flag) for flag in chosen):
        argv += ["--exp-id", str(select_run(Path(folder), env_id, algo).run_id)]
    check_saved_hyperparameters(Path(folder), algo or "ppo", env_id or "CartPole-v1", flag_value(argv, "--exp-id"))
    try:
        with command_line("sgfd-zoo enjoy", argv):
            rl_zoo3.enjoy.enjoy()
    except ValueError as error:
        if any(sign in str(error) for sign in ("spaces do not match", "Unexpected observation shape")):
            # SB3's checks when an env does not fit the agent: most often --env-kwargs that change the observations.
            raise ZooError(
                "the env does not give the observations the agent was trained on (leave out --env-kwargs that "
                f"change obs_type, image_size or observe_parameter; split:'...' and domain:... are fine): {error}"
            ) from None
        # Otherwise what rl-zoo3 and the env refuse: no model in the folder, an env kwarg the id does not take.
        raise ZooError(first_line(error)) from None
    return 0


def check_saved_hyperparameters(folder: Path, algo: str, env_id: str, exp_id: str | None) -> None:
    """Read the ``config.yml`` and ``args.yml`` that rl-zoo3's enjoy is about to read, as data first: rl-zoo3 loads
    them with PyYAML's unsafe loader and evaluates a ``normalize`` string, so a tag naming Python code, or a
    hyperparameter that would run code, is refused here in one line (a :class:`~sgfd_zoo.runs.safe.RefusedFile`).
    The model zip (SB3's format, a pickle) is loaded because the user asked for it.

    :param folder: the log folder (``-f``)
    :param algo: the algorithm key (rl-zoo3's default: ppo)
    :param env_id: the env id (rl-zoo3's default: CartPole-v1)
    :param exp_id: ``--exp-id`` (None or 0: the newest run, as rl-zoo3 picks it)
    """
    from rl_zoo3.utils import get_latest_run_id

    from sgfd_zoo.runs.folders import env_name, read_yaml
    from sgfd_zoo.runs.safe import RefusedFile, hyperparameter_problem

    name = env_name(env_id).replace(":", "-")
    run_id = int(exp_id) if exp_id is not None and exp_id.lstrip("-").isdigit() else 0
    if run_id == 0:
        run_id = get_latest_run_id(str(folder / algo), name)
    log_path = folder / algo / f"{name}_{run_id}" if run_id > 0 else folder / algo  # as rl-zoo3's get_model_path
    config_dir = log_path / name
    for file in ("config.yml", "args.yml"):
        saved, _ = read_yaml(config_dir / file)
        for key, value in saved.items():
            if (problem := hyperparameter_problem(str(key), value)) is not None:
                raise RefusedFile(f"{config_dir / file}: refused: {problem}")


@contextlib.contextmanager
def command_line(prog: str, args: Sequence[str]) -> Iterator[None]:
    """``sys.argv`` set to ``[prog, *args]`` while the block runs."""
    saved = sys.argv
    sys.argv = [prog, *args]
    try:
        yield
    finally:
        sys.argv = saved


@contextlib.contextmanager
def replaced(module: object, name: str, value: object) -> Iterator[None]:
    """``module.name`` replaced by ``value`` while the block runs."""
    saved = getattr(module, name)
    setattr(module, name, value)
    try:
        yield
    finally:
        setattr(module, name, saved)
