"""The one training entry of the zoo: rl-zoo3's train (and optimize) with SGFD's experiment manager.

``sgfd-zoo train``, ``optimize`` and the sweep's Ray tasks all call :func:`train`. The zoo reads the whole command
line itself (:mod:`sgfd_zoo.train_options`: its own options and every one of rl-zoo3's train script), checks it,
then does what ``rl_zoo3.train.train`` does, with rl-zoo3's public pieces: it seeds, sets torch's threads, starts
Weights & Biases for ``--track``, and builds :class:`~sgfd_zoo.experiment.SGFDExperimentManager` through its
constructor. Nothing rewrites ``sys.argv`` or replaces a name inside rl-zoo3.
"""

from __future__ import annotations

import argparse
import contextlib
import importlib.util
import io
import shlex
import time
import uuid
from collections.abc import Callable, Sequence
from typing import Any

from sgfd_zoo.arguments import ZooError, check_env_id, has_flag, import_gym_packages
from sgfd_zoo.runs.safe import redact_argv
from sgfd_zoo.train_options import check_run_arguments, rl_zoo3_arguments, train_parser

#: What ``pip install`` brings the tracking packages (pyproject.toml's ``track`` extra)
TRACK_INSTALL = "pip install -e '.[track]' -c constraints.txt"


def check_tracking(args: argparse.Namespace) -> None:
    """``-tb`` needs TensorBoard and ``--track`` needs Weights & Biases (and TensorBoard, whose logs it syncs):
    refused in one line naming the extra that brings them, before any run folder is made."""
    wanted = []
    if args.tensorboard_log or args.track:
        wanted.append(("tensorboard", "-tb" if args.tensorboard_log else "--track"))
    if args.track:
        wanted.append(("wandb", "--track"))
    for module, flag in wanted:
        if not installed(module):
            raise ZooError(
                f"{flag} needs {module}, which the track extra brings: from the clone's root, {TRACK_INSTALL}"
            )


def installed(module: str) -> bool:
    """Whether the top-level ``module`` can be imported (found without importing it)."""
    try:
        return importlib.util.find_spec(module) is not None
    except (ImportError, ValueError):  # a finder that refuses it; a module without a spec
        return False


def key_values(flag: str, items: Sequence[str] | None) -> dict[str, Any] | None:
    """``KEY:VALUE`` items (already checked by :func:`~sgfd_zoo.arguments.check_key_values`) as rl-zoo3 reads them:
    its ``StoreDict`` evaluates each value in rl-zoo3's namespace (``nn``, ``th``, ...)."""
    if items is None:
        return None
    from rl_zoo3.utils import StoreDict

    read = argparse.Namespace()
    StoreDict([flag], "values", nargs="+")(argparse.ArgumentParser(), read, list(items))
    return read.values


#: SGFDExperimentManager's keyword arguments that are the parsed options of the same name, as rl-zoo3's train passes
#: them: the run, its output, its settings, the hyperparameter search (Optuna), the zoo's own
SAME_NAMED_OPTIONS = (
    "algo", "log_folder", "tensorboard_log", "n_timesteps", "eval_freq", "trained_agent", "seed", "device",
    "log_interval", "save_replay_buffer", "verbose", "n_eval_envs",
    "hyperparams", "env_kwargs", "eval_env_kwargs",
    "optimize_hyperparameters", "storage", "study_name", "n_trials", "max_total_trials", "n_jobs", "sampler",
    "pruner", "optimization_log_path", "n_startup_trials", "n_evaluations", "trial_id", "truncate_last_trajectory",
    "no_optim_plots",
    "quick", "resume", "run_id", "classifier_start",
)  # fmt: skip
#: SGFDExperimentManager's keyword arguments that are parsed options of another name: keyword -> option
RENAMED_OPTIONS = {
    "env_id": "env",
    "n_eval_episodes": "eval_episodes",
    "vec_env_type": "vec_env",
    "config": "conf_file",
    "show_progress": "progress",
}


def manager_arguments(args: argparse.Namespace) -> dict[str, Any]:
    """SGFDExperimentManager's keyword arguments that the parsed options ``args`` give, as rl-zoo3's train passes
    them (an unset ``--save-freq``: -1, and the zoo's default checkpoint interval)."""
    arguments = {name: getattr(args, name) for name in SAME_NAMED_OPTIONS}
    arguments.update({keyword: getattr(args, option) for keyword, option in RENAMED_OPTIONS.items()})
    arguments["save_freq"] = -1 if args.save_freq is None else args.save_freq
    arguments["default_save_freq"] = args.save_freq is None
    arguments["uuid_str"] = f"_{uuid.uuid4()}" if args.uuid else ""
    arguments["progress"] = False if args.no_progress else None
    return arguments


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
    args = parser.parse_args(argv)
    check_env_id(args.env)
    check_run_arguments(args)
    check_tracking(args)
    args.optimize_hyperparameters = args.optimize_hyperparameters or optimize
    if args.optimize_hyperparameters:
        args.no_optim_plots = True  # the zoo's runs are on machines without a display; its plots need one
    args.hyperparams = key_values("-params", args.hyperparams)
    args.env_kwargs = key_values("--env-kwargs", args.env_kwargs)
    args.eval_env_kwargs = key_values("--eval-env-kwargs", args.eval_env_kwargs)
    quiet = contextlib.redirect_stdout(io.StringIO()) if check_only else contextlib.nullcontext()
    with quiet:
        return _run(args, argv, progress_reporter, check_only)


def _run(
    args: argparse.Namespace,
    argv: list[str],
    progress_reporter: Callable[[dict[str, Any]], None] | None,
    check_only: bool,
) -> int:
    """What ``rl_zoo3.train.train`` does after parsing, with the zoo's experiment manager."""
    import numpy as np
    import rl_zoo3  # noqa: F401 (before Stable-Baselines3: without the zoo's install, its line is the only one)
    import torch as th
    from stable_baselines3.common.utils import set_random_seed

    from sgfd_zoo.experiment import SGFDExperimentManager, register_algorithms

    import_gym_packages(args.gym_packages)
    register_algorithms()
    if args.seed < 0:
        args.seed = np.random.randint(2**32 - 1, dtype="int64").item()
    set_random_seed(args.seed)
    if args.num_threads > 0:
        th.set_num_threads(args.num_threads)
    print("=" * 10, args.env, "=" * 10)
    print(f"Seed: {args.seed}")
    command = redact_argv(argv)  # recorded and printed: no URL's credentials
    tracked = None if check_only or not args.track else _start_tracking(args, command)
    zoo3 = rl_zoo3_arguments(args)
    manager = SGFDExperimentManager(
        zoo3,
        **manager_arguments(args),
        progress_reporter=progress_reporter,
        check_only=check_only,
        command=command,
        default_eval_freq=not has_flag(argv, "--eval-freq"),
    )
    try:
        results = manager.setup_experiment()
        if results is None:
            manager.hyperparameters_optimization()
            return 0
        model, saved_hyperparams = results
        if tracked is not None:
            zoo3.saved_hyperparams = saved_hyperparams
            tracked.config.setdefaults(vars(zoo3))
        if model is not None:
            manager.learn(model)
            manager.save_trained_model(model)
    finally:
        manager.release_run_folder()  # whatever ended the run: its folder's lock is given back
    return 0


def _start_tracking(args: argparse.Namespace, command: list[str]) -> Any:
    """A Weights & Biases run for ``--track``, as rl-zoo3's train starts one: named after the env, algorithm, seed
    and time, with SB3's TensorBoard logs synced (they go to ``runs/<run name>``)."""
    import stable_baselines3 as sb3
    import wandb

    args.command = shlex.join(["sgfd-zoo", "optimize" if args.optimize_hyperparameters else "train", *command])
    # rl-zoo3's name, with the env's path name: an id's "/" would nest the folder (SGFD/MT-... -> SGFD-MT-...)
    run_name = f"{args.env.replace('/', '-')}__{args.algo}__{args.seed}__{int(time.time())}"
    run = wandb.init(
        name=run_name,
        project=args.wandb_project_name,
        entity=args.wandb_entity,
        group=args.wandb_group,
        tags=[*args.wandb_tags, f"v{sb3.__version__}"],
        config=vars(rl_zoo3_arguments(args)),
        sync_tensorboard=True,
        monitor_gym=True,
        save_code=True,
    )
    args.tensorboard_log = f"runs/{run_name}"
    return run


def optimize(argv: Sequence[str]) -> int:
    """rl-zoo3's Optuna search with the SGFD sampler (see sgfd_zoo.registration.sample_sgfd_sac_params)."""
    return train(argv, optimize=True)
