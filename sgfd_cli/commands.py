"""
The ``sgfd-zoo`` command: a dispatcher over the zoo's commands and the paper's figures. Each command imports its
module when it runs, so ``sgfd-zoo plot`` does not load rl-zoo3 or torch.

The dispatcher is the top floor, above both the zoo and the analysis package, whose figures are drawn from the
zoo's runs (``tests/project/test_layers.py`` holds the floors).
"""

from __future__ import annotations

import sys
from collections.abc import Callable, Sequence

from sgfd_zoo.exit_codes import INTERRUPTED

Command = Callable[[list[str]], int]


def _train(argv: list[str]) -> int:
    from sgfd_zoo import training

    return training.train(argv)


def _optimize(argv: list[str]) -> int:
    from sgfd_zoo import training

    return training.optimize(argv)


def _enjoy(argv: list[str]) -> int:
    from sgfd_zoo import enjoy

    return enjoy.main(argv)


def _record_video(argv: list[str]) -> int:
    from sgfd_zoo import video

    return video.main(argv)


def _push_to_hub(argv: list[str]) -> int:
    from sgfd_zoo.hub import push

    return push.main(argv)


def _load_from_hub(argv: list[str]) -> int:
    from sgfd_zoo.hub import load

    return load.main(argv)


def _evaluate(argv: list[str]) -> int:
    from sgfd_zoo.report import evaluate

    return evaluate.main(argv)


def _plot(argv: list[str]) -> int:
    from sgfd_zoo.report import plot

    return plot.main(argv)


def _quick(argv: list[str]) -> int:
    from sgfd_zoo import quick

    return quick.main(argv)


def _sweep(argv: list[str]) -> int:
    from sgfd_zoo.sweep import command

    return command.main(argv)


def _study(argv: list[str]) -> int:
    from sgfd_zoo import study

    return study.main(argv)


def _correlation_study(argv: list[str]) -> int:
    from sgfd_analysis import correlation

    return correlation.main(argv)


def _saliency_maps(argv: list[str]) -> int:
    from sgfd_analysis import figures

    return figures.saliency_maps_main(argv)


def _weighted_samples(argv: list[str]) -> int:
    from sgfd_analysis import figures

    return figures.weighted_samples_main(argv)


def _classifier_accuracy(argv: list[str]) -> int:
    from sgfd_analysis import figures

    return figures.classifier_accuracy_main(argv)


# command -> (its function, one-line description)
COMMANDS: dict[str, tuple[Command, str]] = {
    "train": (_train, "train an agent (rl-zoo3's flags, plus --quick, --resume, --no-progress)"),
    "optimize": (_optimize, "tune hyperparameters with Optuna (rl-zoo3's flags, --storage)"),
    "enjoy": (_enjoy, "watch or roll out a trained agent on any split and domain (rl-zoo3's flags)"),
    "record-video": (_record_video, "an mp4 of a trained agent on any split and domain"),
    "push-to-hub": (_push_to_hub, "a run to the Hugging Face Hub: model, settings, every split's evaluation, video"),
    "load-from-hub": (_load_from_hub, "a run from the Hugging Face Hub (or a local copy) into a log folder"),
    "evaluate": (_evaluate, "every trained model of a log folder on every split: tables, statistics"),
    "plot": (_plot, "learning curves per split and algorithm from a log folder"),
    "quick": (_quick, "the main job: SGFD and SAC briefly, on several seeds; tables with intervals"),
    "sweep": (_sweep, "algos x envs x seeds as Ray tasks (here or on a cluster), resumable; then evaluate"),
    "study": (_study, "a study from a spec file: its sweep, statistics and figures into studies/<name>"),
    "correlation-study": (
        _correlation_study,
        "|correlation| of the changed feature with the others: raw, global and SGFD weights",
    ),
    "saliency-maps": (
        _saliency_maps,
        "|d action / d pixel| of a trained pixel agent on training and test domains (PNG grid)",
    ),
    "weighted-samples": (_weighted_samples, "a batch from two domains, frames sorted by SGFD's learned weight (PNG)"),
    "classifier-accuracy": (
        _classifier_accuracy,
        "the domain classifier's accuracy during training, mean and band over seeds (PNG)",
    ),
}


#: what the optional extras install beyond the agents (pyproject.toml), by import name, and how to install them
EXTRA_OF_MODULE = {
    **dict.fromkeys(
        ["rl_zoo3", "sb3_contrib", "optuna", "ray", "rliable", "matplotlib", "pandas", "yaml", "rich", "tqdm"],
        "zoo",
    ),
    **dict.fromkeys(["huggingface_hub", "imageio_ffmpeg"], "zoo"),
    **dict.fromkeys(["tensorboard", "wandb"], "track"),
}
INSTALLS = {
    "zoo": "pip install -e ./sgfd_envs -e '.[zoo]' -c constraints.txt",
    "track": "pip install -e '.[track]' -c constraints.txt",
}


def usage() -> str:
    width = max(map(len, COMMANDS)) + 2
    lines = [f"  {name:<{width}}{description}" for name, (_, description) in COMMANDS.items()]
    return (
        "usage: sgfd-zoo COMMAND [options]\n\ncommands:\n"
        + "\n".join(lines)
        + "\n\n'sgfd-zoo COMMAND -h' shows a command's options."
    )


def main(argv: Sequence[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    if not argv or argv[0] in ("-h", "--help"):
        print(usage())
        return 0
    command, rest = argv[0], argv[1:]
    if command not in COMMANDS:
        print(f"sgfd-zoo: error: unknown command {command!r}; choose from {', '.join(COMMANDS)}", file=sys.stderr)
        return 2
    try:
        return run(command, rest)
    except KeyboardInterrupt:
        # Training handles Ctrl-C itself (it stops at a checkpoint); this is Ctrl-C anywhere else.
        print(f"sgfd-zoo {command}: interrupted", file=sys.stderr)
        return INTERRUPTED


def run(command: str, argv: Sequence[str]) -> int:
    """Run ``command``'s function on ``argv``; a ZooError is printed as one line and gives its exit code."""
    from sgfd_zoo.arguments import ZooError  # here, not at the top: a Ctrl-C while it imports sgfd_envs is caught

    try:
        return COMMANDS[command][0](list(argv)) or 0
    except ZooError as error:
        print(f"sgfd-zoo {command}: {error.label}: {error}", file=sys.stderr)
        return error.exit_code
    except ModuleNotFoundError as error:
        missing = (error.name or "").partition(".")[0]
        if missing not in EXTRA_OF_MODULE:
            raise
        extra = EXTRA_OF_MODULE[missing]
        which = "the zoo's install" if extra == "zoo" else f"the {extra} extra"
        print(
            f"sgfd-zoo {command}: error: it needs {missing}, which {which} brings: from the clone's root, "
            f"{INSTALLS[extra]}",
            file=sys.stderr,
        )
        return 2


if __name__ == "__main__":
    sys.exit(main())
