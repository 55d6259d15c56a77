"""
The ``sgfd-zoo`` command: a dispatcher over the zoo's functions. Each command's module is imported only when
it runs, so ``sgfd-zoo plot`` does not load rl-zoo3 or torch.
"""

from __future__ import annotations

import importlib
import sys
from collections.abc import Sequence

from sgfd_zoo.exit_codes import INTERRUPTED

# command -> (module:function, one-line description)
COMMANDS: dict[str, tuple[str, str]] = {
    "train": ("sgfd_zoo.training:train", "train an agent (rl-zoo3's flags, plus --quick, --resume, --no-progress)"),
    "optimize": (
        "sgfd_zoo.training:optimize",
        "tune hyperparameters with Optuna (rl-zoo3's flags, --storage)",
    ),
    "enjoy": ("sgfd_zoo.training:enjoy", "watch or roll out a trained agent (rl-zoo3's flags)"),
    "evaluate": (
        "sgfd_zoo.evaluate:main",
        "every trained model of a log folder on every split: tables, statistics",
    ),
    "plot": ("sgfd_zoo.plot:main", "learning curves per split and algorithm from a log folder"),
    "quick": ("sgfd_zoo.quick:main", "the main job: SGFD and SAC briefly, on several seeds; tables with intervals"),
    "sweep": (
        "sgfd_zoo.sweep:main",
        "algos x envs x seeds as Ray tasks (here or on a cluster), resumable; then evaluate",
    ),
    "study": ("sgfd_zoo.study:main", "a study from a spec file: its sweep, statistics and figures into studies/<name>"),
    "correlation-study": (
        "sgfd_analysis.correlation:main",
        "|correlation| of the changed feature with the others: raw, global and SGFD weights",
    ),
    "saliency-maps": (
        "sgfd_analysis.figures:saliency_maps_main",
        "|d action / d pixel| of a trained pixel agent on training and test domains (PNG grid)",
    ),
    "weighted-samples": (
        "sgfd_analysis.figures:weighted_samples_main",
        "a batch from two domains, frames sorted by SGFD's learned weight (PNG)",
    ),
    "classifier-accuracy": (
        "sgfd_analysis.figures:classifier_accuracy_main",
        "the domain classifier's accuracy during training, mean and band over seeds (PNG)",
    ),
}


#: what the ``zoo`` extra installs beyond the agents (pyproject.toml), by import name
ZOO_EXTRA_MODULES = frozenset(
    ["rl_zoo3", "sb3_contrib", "optuna", "ray", "rliable", "matplotlib", "pandas", "yaml", "rich", "tqdm"]
)


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

    module, _, function = COMMANDS[command][0].partition(":")
    try:
        return getattr(importlib.import_module(module), function)(argv) or 0
    except ZooError as error:
        print(f"sgfd-zoo {command}: {error.label}: {error}", file=sys.stderr)
        return error.exit_code
    except ModuleNotFoundError as error:
        missing = (error.name or "").partition(".")[0]
        if missing not in ZOO_EXTRA_MODULES:
            raise
        print(
            f"sgfd-zoo {command}: error: it needs {missing}, which the zoo's install brings: from the clone's root, "
            "pip install -e ./sgfd_envs -e '.[zoo]' -c constraints.txt",
            file=sys.stderr,
        )
        return 2


if __name__ == "__main__":
    sys.exit(main())
