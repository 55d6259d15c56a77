"""The options of ``sgfd-zoo train`` and ``sgfd-zoo optimize``: the zoo's own and every option of rl-zoo3's train
script, with rl-zoo3's names, destinations and defaults, so that the zoo reads the whole command line itself and
builds rl-zoo3's experiment manager from what it read (nothing is passed on to another parser, so no option can
be read two ways). No heavy import: ``-h`` is instant and a bad value is refused before anything loads."""

from __future__ import annotations

import argparse
from pathlib import Path

from sgfd_zoo.algos import SGFD_ALGOS
from sgfd_zoo.arguments import (
    ZooArgumentParser,
    ZooError,
    check_at_least,
    check_key_values,
    check_log_folder,
)

MAX_SEED = 2**32 - 1  # numpy's limit, which rl-zoo3 seeds with
#: The destinations of the zoo's own options: everything else is rl-zoo3's, and goes to its experiment manager
#: (and into the run's ``args.yml``) as rl-zoo3's own train script would put it.
ZOO_DESTS = ("quick", "resume", "no_progress", "classifier_start", "run_id")


def train_parser(prog: str, optimize: bool = False) -> argparse.ArgumentParser:
    """The options of ``sgfd-zoo train`` (``optimize``): the zoo's, then rl-zoo3's, in groups.

    :param prog: the command's name in the help and in errors
    :param optimize: the Optuna search's options first among rl-zoo3's (``sgfd-zoo optimize``)
    """
    parser = ZooArgumentParser(
        prog=prog,
        description="Train an agent with rl-zoo3 on an SGFD env id, with the zoo's hyperparameters"
        + (", searching them with Optuna." if optimize else "."),
        epilog="Every option has its whole name: an abbreviation (--qui for --quick) is refused.",
    )
    _zoo_options(parser.add_argument_group("the zoo's options"))
    _run_options(parser.add_argument_group("the run (rl-zoo3's options, checked by the zoo)"))
    _tracking_options(parser.add_argument_group("tracking (rl-zoo3's options; pip install -e '.[track]')"))
    _search_options(parser.add_argument_group("the search (rl-zoo3's options" + (")" if optimize else "; optimize)")))
    return parser


def _zoo_options(zoo: argparse._ArgumentGroup) -> None:
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


def _run_options(run: argparse._ArgumentGroup) -> None:
    run.add_argument(
        "-n", "--n-timesteps", type=int, default=-1, metavar="STEPS", help="steps to train (default: the yaml's)"
    )
    run.add_argument("-f", "--log-folder", default="logs", metavar="FOLDER", help="log folder (default: logs)")
    run.add_argument("--seed", type=int, default=-1, help=f"0..{MAX_SEED}; -1 (default): a random one")
    run.add_argument(
        "--eval-freq", type=int, default=25000, metavar="STEPS", help="evaluate every n steps; <= 0: never"
    )
    run.add_argument("--eval-episodes", type=int, default=5, metavar="N", help="episodes per split and evaluation")
    run.add_argument("--n-eval-envs", type=int, default=1, metavar="N", help="rl-zoo3's evaluation envs (optimize)")
    run.add_argument(
        "--save-freq", type=int, metavar="STEPS", help="checkpoint every n steps; default: a fifth of the run, <= 100k"
    )
    run.add_argument("--save-replay-buffer", action="store_true", help="keep the replay buffer with the final model")
    for flags, what in (
        (("-params", "--hyperparams"), "override hyperparameters, e.g. batch_size:64"),
        (("--env-kwargs",), "env settings merged into the configuration's, e.g. image_size:64"),
        (("--eval-env-kwargs",), "env settings of the evaluation envs (default: the same)"),
    ):
        run.add_argument(*flags, nargs="+", metavar="KEY:VALUE", help=what)
    run.add_argument("-conf", "--conf-file", metavar="YAML", help="a yaml of hyperparameters instead of the zoo's")
    run.add_argument(
        "-i", "--trained-agent", default="", metavar="ZIP", help="a model zip to continue training in a new run folder"
    )
    run.add_argument(
        "--truncate-last-trajectory",
        default=True,
        type=bool,
        help="HER only (rl-zoo3's): truncate the last trajectory of a reloaded replay buffer",
    )
    run.add_argument("--num-threads", type=int, default=-1, metavar="N", help="torch's CPU threads (-1: torch's)")
    run.add_argument("--device", default="auto", help="cpu, cuda, cuda:1, ... (default: auto)")
    run.add_argument("--verbose", type=int, default=1, metavar="LEVEL", help="0: quiet, 1: rl-zoo3's output (default)")
    run.add_argument("--vec-env", default="dummy", choices=["dummy", "subproc"], help="the training envs' VecEnv")
    run.add_argument(
        "--log-interval",
        type=int,
        default=-1,
        metavar="N",
        help="log every n episodes (-1: the algorithm's, -2: never)",
    )
    run.add_argument("-P", "--progress", action="store_true", help="a progress bar even when not on a terminal")
    run.add_argument("-uuid", "--uuid", action="store_true", help="rl-zoo3's unique suffix of the run folder")
    run.add_argument(
        "--gym-packages", nargs="+", default=[], metavar="MODULE", help="modules to import first (they register ids)"
    )


def _tracking_options(tracking: argparse._ArgumentGroup) -> None:
    tracking.add_argument(
        "-tb", "--tensorboard-log", default="", metavar="FOLDER", help="TensorBoard logs under FOLDER/<ALGO>_<n>"
    )
    tracking.add_argument(
        "--track", action="store_true", help="track the run with Weights & Biases (its TensorBoard logs synced)"
    )
    tracking.add_argument("--wandb-project-name", default="sb3", metavar="NAME", help="W&B's project (default: sb3)")
    tracking.add_argument("--wandb-entity", metavar="ENTITY", help="W&B's entity (team)")
    tracking.add_argument("--wandb-group", metavar="GROUP", help="W&B's group")
    tracking.add_argument("-tags", "--wandb-tags", nargs="+", default=[], metavar="TAG", help="W&B's tags of the run")


def _search_options(search: argparse._ArgumentGroup) -> None:
    search.add_argument(
        "-optimize",
        "--optimize-hyperparameters",
        action="store_true",
        help="search hyperparameters (what sgfd-zoo optimize does)",
    )
    search.add_argument("--n-trials", type=int, default=500, help="trials of this process (default: 500)")
    search.add_argument("--max-total-trials", type=int, help="trials of the whole study, pruned ones included")
    search.add_argument("--n-jobs", type=int, default=1, help="parallel trials")
    search.add_argument("--sampler", default="tpe", choices=["random", "tpe", "auto"], help="Optuna's sampler")
    search.add_argument("--pruner", default="median", choices=["halving", "median", "none"], help="Optuna's pruner")
    search.add_argument("--n-startup-trials", type=int, default=10, help="trials before the sampler learns")
    search.add_argument("--n-evaluations", type=int, help="evaluations per trial (default: one per 100k steps)")
    search.add_argument("--storage", help="an Optuna storage shared by processes (a journal .log file, a URL)")
    search.add_argument("--study-name", help="the study's name in the storage")
    search.add_argument("--trial-id", type=int, help="a trial of the storage to load")
    search.add_argument("--optimization-log-path", metavar="FOLDER", help="each trial's evaluations and model")
    search.add_argument("--no-optim-plots", action="store_true", help="no Optuna plots at the end")


def check_run_arguments(args: argparse.Namespace) -> None:
    """The values the zoo checks itself, each refused in one line naming the flag, the value and what fits."""
    check_at_least("-n", None if args.n_timesteps == -1 else args.n_timesteps, 1)
    if not (args.seed == -1 or 0 <= args.seed <= MAX_SEED):
        raise ZooError(f"--seed {args.seed}: expected 0..{MAX_SEED}, or -1 for a random seed")
    check_at_least("--eval-episodes", args.eval_episodes, 1)
    check_at_least("--n-eval-envs", args.n_eval_envs, 1)
    check_at_least("--classifier-start", args.classifier_start, 0)
    check_at_least("--run-id", args.run_id, 0)
    check_log_folder("-f", Path(args.log_folder))
    check_key_values("-params", args.hyperparams)
    check_key_values("--env-kwargs", args.env_kwargs)
    check_key_values("--eval-env-kwargs", args.eval_env_kwargs)
    if args.trained_agent and not (args.trained_agent.endswith(".zip") and Path(args.trained_agent).is_file()):
        raise ZooError(f"-i {args.trained_agent}: expected a model zip (a file ending in .zip)")


def rl_zoo3_arguments(args: argparse.Namespace) -> argparse.Namespace:
    """What rl-zoo3's train script would have parsed: ``args`` without the zoo's own options (the run's
    ``args.yml`` holds these, as rl-zoo3 writes it)."""
    return argparse.Namespace(**{key: value for key, value in vars(args).items() if key not in ZOO_DESTS})
