"""The one training entry of the zoo: rl-zoo3's train (and optimize, enjoy) with SGFD's ExperimentManager.

``sgfd-zoo train``, ``optimize`` and the sweep's Ray tasks all call :func:`train`; every rl-zoo3 flag works.
rl-zoo3 builds its ExperimentManager by name from ``sys.argv``, so we hand it :class:`SGFDExperimentManager`
and the arguments for the duration of the call.
"""

from __future__ import annotations

import argparse
import contextlib
import functools
import io
import sys
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from typing import Any

from sgfd_zoo.algos import SGFD_ALGOS
from sgfd_zoo.arguments import ZooError, check_at_least, check_env_id, flag_value, has_flag


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
    import rl_zoo3.train

    from sgfd_zoo.experiment import SGFDExperimentManager, register_algorithms

    parser = argparse.ArgumentParser(prog=f"sgfd-zoo {'optimize' if optimize else 'train'}", add_help=False)
    parser.add_argument("--algo", default="sgfd_sac", choices=sorted(SGFD_ALGOS), help="algorithm key")
    parser.add_argument("--env", help="a registered id (sgfd_envs.ENV_IDS), e.g. SGFD/MT-walker-walk-v0")
    parser.add_argument("--quick", action="store_true", help="the quick configuration (sgfd_zoo/hyperparams/quick)")
    parser.add_argument("--resume", action="store_true", help="continue the newest run from its last checkpoint")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")
    parser.add_argument(
        "--classifier-start",
        type=int,
        metavar="STEPS",
        help="env steps before SGFD's domain classifier starts training (classifier_start of the SGFD algorithms; "
        "the others have none, so a sweep may mix them)",
    )
    parser.add_argument(
        "--run-id", type=int, help="write to (and --resume) the run folder <EnvName>_<id>; default: newest id + 1"
    )
    ours, rest = parser.parse_known_args(list(argv))
    if "-h" in rest or "--help" in rest:
        parser.print_help()
        print("\nrl-zoo3's options follow (all accepted):\n")
    else:
        check_env_id(ours.env)
        check_at_least("--classifier-start", ours.classifier_start, 0)
    rest = ["--algo", ours.algo, "--env", str(ours.env), *rest]
    if optimize:
        rest += ["-optimize"] + ([] if has_flag(rest, "--no-optim-plots") else ["--no-optim-plots"])

    register_algorithms()
    manager = functools.partial(
        SGFDExperimentManager,
        quick=ours.quick,
        resume=ours.resume,
        progress=False if ours.no_progress else None,
        run_id=ours.run_id,
        progress_reporter=progress_reporter,
        check_only=check_only,
        command=list(argv),
        default_save_freq=not has_flag(rest, "--save-freq"),
        classifier_start=ours.classifier_start,
    )
    quiet = contextlib.redirect_stdout(io.StringIO()) if check_only else contextlib.nullcontext()
    with replaced(rl_zoo3.train, "ExperimentManager", manager), command_line(parser.prog, rest), quiet:
        rl_zoo3.train.train()
    return 0


def optimize(argv: Sequence[str]) -> int:
    """rl-zoo3's Optuna search with the SGFD sampler (see sgfd_zoo.experiment.sample_sgfd_sac_params)."""
    return train(argv, optimize=True)


def enjoy(argv: Sequence[str]) -> int:
    """rl-zoo3's enjoy on SGFD's registered envs; reads ./logs unless -f says otherwise. Without --exp-id it
    watches the newest finished run (rl-zoo3's newest folder may be a run still training or stopped)."""
    import rl_zoo3.enjoy

    from sgfd_zoo.experiment import register_algorithms
    from sgfd_zoo.runs import select_run

    register_algorithms()
    argv = list(argv)
    if not (has_flag(argv, "-f") or has_flag(argv, "--folder")):
        argv += ["-f", "logs"]
    folder = flag_value(argv, "-f") or flag_value(argv, "--folder")
    algo, env_id = flag_value(argv, "--algo"), flag_value(argv, "--env")
    chosen = ("--exp-id", "--load-best", "--load-checkpoint", "--load-last-checkpoint")
    if algo is not None and env_id is not None and not any(has_flag(argv, flag) for flag in chosen):
        argv += ["--exp-id", str(select_run(Path(folder), env_id, algo).run_id)]
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
        lines = [line.strip() for line in str(error).splitlines() if line.strip()]
        raise ZooError(lines[0] if lines else repr(error)) from None
    return 0


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
