"""
The ``sgfd-zoo`` command: rl-zoo3's train / enjoy / optimize with SGFD's algorithms and envs, plus
evaluation on the unseen domains, the paper's tables and plots.

``train``, ``optimize`` and ``enjoy`` run rl-zoo3's own entry points, so every rl-zoo3 flag works;
rl-zoo3 builds its ExperimentManager by name, and we hand it :class:`SGFDExperimentManager`.
"""

from __future__ import annotations

import argparse
import contextlib
import difflib
import functools
import sys
from collections.abc import Callable, Iterator, Sequence

import sgfd_envs
from zoo.algos import SGFD_ALGOS, register_algorithms
from zoo.experiment import SGFDExperimentManager, ZooError

DEFAULT_SAVE_FREQ = 100_000
USAGE = """usage: sgfd-zoo COMMAND [options]

commands:
  train       train an agent (rl-zoo3's flags, plus --quick, --resume, --no-progress)
  optimize    tune hyperparameters with Optuna (rl-zoo3's flags; --storage sqlite:///f.db or f.log)
  enjoy       watch or roll out a trained agent (rl-zoo3's flags)
  evaluate    evaluate every trained model of a log folder on every split; write and print tables
  plot        learning curves per split and algorithm from a log folder
  quick       the quick demo: train SGFD and SAC briefly, evaluate on the unseen domains, print the table
  sweep       train algos x envs x seeds as Ray tasks (here or on a cluster, --address), resumable; then evaluate
  correlation-study    |correlation| of the changed feature with the others: raw, global and SGFD weights
  saliency-maps        |d action / d pixel| of a trained pixel agent on training and test domains (PNG grid)
  weighted-samples     a batch from two domains, frames sorted by SGFD's learned weight (PNG)
  classifier-accuracy  the domain classifier's accuracy during training, mean and band over seeds (PNG)

'sgfd-zoo COMMAND -h' shows a command's options."""


def main(argv: Sequence[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    if not argv or argv[0] in ("-h", "--help"):
        print(USAGE)
        return 0
    command, rest = argv[0], argv[1:]
    commands = _commands()
    if command not in commands:
        print(f"sgfd-zoo: error: unknown command {command!r}; choose from {', '.join(commands)}", file=sys.stderr)
        return 2
    try:
        return commands[command](rest) or 0
    except ZooError as error:
        print(f"sgfd-zoo {command}: error: {error}", file=sys.stderr)
        return 2


def _commands() -> dict[str, Callable[[list[str]], int | None]]:
    from zoo import correlation, evaluate, figures, plot, quick, sweep

    return {
        "train": train,
        "optimize": optimize,
        "enjoy": enjoy,
        "evaluate": evaluate.main,
        "plot": plot.main,
        "quick": quick.main,
        "sweep": sweep.main,
        "correlation-study": correlation.main,
        "saliency-maps": figures.saliency_maps_main,
        "weighted-samples": figures.weighted_samples_main,
        "classifier-accuracy": figures.classifier_accuracy_main,
    }


def train(argv: list[str], optimize: bool = False) -> int:
    """rl-zoo3's train, on SGFD's envs with the zoo's hyperparameters; extra flags: --quick --resume."""
    parser = argparse.ArgumentParser(prog=f"sgfd-zoo {'optimize' if optimize else 'train'}", add_help=False)
    parser.add_argument("--algo", default="sgfd_sac", choices=sorted(SGFD_ALGOS), help="algorithm key")
    parser.add_argument("--env", help="an SGFD id, e.g. SGFD/MT-walker-walk-v0")
    parser.add_argument("--quick", action="store_true", help="the quick configuration (zoo/hyperparams/quick)")
    parser.add_argument("--resume", action="store_true", help="continue the newest run from its last checkpoint")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")
    parser.add_argument(
        "--run-id", type=int, help="write to (and --resume) the run folder <EnvName>_<id>; default: newest id + 1"
    )
    ours, rest = parser.parse_known_args(argv)
    if "-h" in rest or "--help" in rest:
        parser.print_help()
        print("\nrl-zoo3's options follow (all accepted):\n")
    else:
        check_env_id(ours.env)
    rest = ["--algo", ours.algo, "--env", str(ours.env), *rest]
    if not _has_flag(rest, "--save-freq"):
        rest += ["--save-freq", str(DEFAULT_SAVE_FREQ)]
    if optimize:
        rest += ["-optimize"] + ([] if _has_flag(rest, "--no-optim-plots") else ["--no-optim-plots"])

    import rl_zoo3.train

    register_algorithms()
    manager = functools.partial(
        SGFDExperimentManager,
        quick=ours.quick,
        resume=ours.resume,
        progress=False if ours.no_progress else None,
        run_id=ours.run_id,
    )
    with _replaced(rl_zoo3.train, "ExperimentManager", manager), _argv(parser.prog, rest):
        rl_zoo3.train.train()
    return 0


def optimize(argv: list[str]) -> int:
    """rl-zoo3's Optuna search with the SGFD sampler (see zoo.algos.sample_sgfd_sac_params)."""
    return train(argv, optimize=True)


def enjoy(argv: list[str]) -> int:
    """rl-zoo3's enjoy on SGFD's registered envs; reads ./logs unless -f says otherwise."""
    import rl_zoo3.enjoy

    register_algorithms()
    if not (_has_flag(argv, "-f") or _has_flag(argv, "--folder")):
        argv = [*argv, "-f", "logs"]
    with _argv("sgfd-zoo enjoy", argv):
        rl_zoo3.enjoy.enjoy()
    return 0


def check_env_id(env_id: str | None) -> None:
    if env_id not in sgfd_envs.SGFD_IDS:
        known = ", ".join(sgfd_envs.SGFD_IDS)
        if env_id is None:
            raise ZooError(f"--env is required; one of {known}")
        close = difflib.get_close_matches(env_id, sgfd_envs.SGFD_IDS, n=1)
        hint = f" (did you mean {close[0]}?)" if close else ""
        raise ZooError(f"--env {env_id!r} is not an SGFD id{hint}; choose from {known}")


def _has_flag(argv: Sequence[str], flag: str) -> bool:
    return any(arg == flag or arg.startswith(f"{flag}=") for arg in argv)


@contextlib.contextmanager
def _argv(prog: str, args: Sequence[str]) -> Iterator[None]:
    saved = sys.argv
    sys.argv = [prog, *args]
    try:
        yield
    finally:
        sys.argv = saved


@contextlib.contextmanager
def _replaced(module: object, name: str, value: object) -> Iterator[None]:
    saved = getattr(module, name)
    setattr(module, name, value)
    try:
        yield
    finally:
        setattr(module, name, saved)


if __name__ == "__main__":
    sys.exit(main())
