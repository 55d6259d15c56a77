"""The training flags a study's spec may set (its ``train:`` list), read as data: a spec comes from a pull request.

Only per-run flags are allowed, each value parsed, never evaluated: numbers, a device, and rl-zoo3's
``KEY:VALUE`` settings whose values are literals or ``dict(...)`` of literals (``policy_kwargs:dict(net_arch=[256,
256])``), which rl-zoo3's own ``eval`` then reads alike. A flag that chooses a folder, a Ray cluster or code to load
(``-f``, ``--address``, ``-conf``, ``--gym-packages``, ...) belongs on the command line of whoever runs the study:
in a spec it is refused, in one line naming it.
"""

from __future__ import annotations

import re
from collections.abc import Callable, Sequence
from pathlib import Path

from sgfd_zoo.runs.safe import EVALUATED_HYPERPARAMETERS, RefusedFile, literal_expression, spec_setting_problem

SWITCHES = ("--quick", "--save-replay-buffer", "--no-progress")


def _device(value: str) -> str:
    if not re.fullmatch(r"cpu|auto|mps|cuda(:\d+)?", value):
        raise ValueError("expected cpu, cuda, cuda:N, mps or auto")
    return value


def _vec_env(value: str) -> str:
    if value not in ("dummy", "subproc"):
        raise ValueError("expected dummy or subproc")
    return value


#: Per-run flags with one value, and how the value is read.
VALUED: dict[str, Callable[[str], object]] = {
    **dict.fromkeys(("-n", "--n-timesteps", "--eval-freq", "--eval-episodes", "--save-freq"), int),
    **dict.fromkeys(("--classifier-start", "--num-threads", "--n-eval-envs", "--log-interval", "--verbose"), int),
    **dict.fromkeys(("--cpus-per-run", "--gpus-per-run"), float),  # what each run gets
    "--max-retries": int,
    "--device": _device,
    "--vec-env": _vec_env,
}
#: rl-zoo3's ``KEY:VALUE ...`` settings (it evaluates each value).
KEY_VALUES = ("-params", "--hyperparams", "--env-kwargs", "--eval-env-kwargs")
#: Why a flag that a command line may give is refused in a spec, for the message.
NOT_IN_A_SPEC = {
    **dict.fromkeys(
        ("-f", "--folder", "--log-folder", "-tb", "--tensorboard-log", "--optimization-log-path"), "a folder"
    ),
    **dict.fromkeys(("--address", "--storage", "--track", "--wandb-project-name", "--wandb-entity"), "a service"),
    **dict.fromkeys(("-conf", "--conf-file", "--gym-packages", "-i", "--trained-agent"), "code or a model to load"),
}


def check_train_flags(flags: Sequence[str], spec: Path) -> list[str]:
    """``flags`` (a spec's ``train:`` list) if every one is a per-run flag with a value that parses as data; a
    :class:`~sgfd_zoo.runs.safe.RefusedFile` naming the spec and every flag refused otherwise.

    :param flags: the spec's train flags, as strings
    :param spec: the spec file, for the message
    """
    refused: list[str] = []
    index = 0
    while index < len(flags):
        flag = flags[index]
        index += 1
        name, has_inline, inline = flag.partition("=") if flag.startswith("--") else (flag, "", "")
        if has_inline:
            values = [inline]
        elif name in VALUED:  # one value, which may look like a flag: --eval-freq -1
            values = list(flags[index : index + 1])
            index += len(values)
        else:
            values = []
            while index < len(flags) and not flags[index].startswith("-"):
                values.append(flags[index])
                index += 1
        refused += _problems(name, values)
    if refused:
        raise RefusedFile(
            f"SPEC {spec}: train: refused {'; '.join(refused)}: a spec sets per-run training flags only, with values "
            "read as data (docs/trust.md); folders, clusters and code belong on the command line of whoever runs it"
        )
    return list(flags)


def _problems(name: str, values: list[str]) -> list[str]:
    """What is wrong with flag ``name`` given ``values`` ([] when nothing is)."""
    if not name.startswith("-"):
        return [f"{name!r} (a value without its flag)"]
    if name in NOT_IN_A_SPEC:
        return [f"{name} ({NOT_IN_A_SPEC[name]})"]
    if name in SWITCHES:
        return [] if not values else [f"{name} {' '.join(values)} (a switch takes no value)"]
    if name in VALUED:
        if len(values) != 1:
            return [f"{name} (expected one value, got {len(values)})"]
        try:
            VALUED[name](values[0])
        except ValueError as error:
            return [f"{name} {values[0]!r} ({error})"]
        return []
    if name in KEY_VALUES:
        if not values:
            return [f"{name} (expected KEY:VALUE ...)"]
        return [problem for value in values if (problem := _key_value_problem(name, value)) is not None]
    return [f"{name} (not a per-run training flag)"]


def _key_value_problem(flag: str, setting: str) -> str | None:
    """What is wrong with ``flag KEY:VALUE`` in a spec: a value that is no literal (or, for a string rl-zoo3
    evaluates itself, whose text is no literal), or one that names code or a path at any depth
    (:func:`~sgfd_zoo.runs.safe.spec_setting_problem`); None when nothing is."""
    key, colon, text = setting.partition(":")
    if not colon or not key.isidentifier():
        return f"{flag} {setting!r} (expected KEY:VALUE)"
    try:
        value = literal_expression(text)
    except ValueError as error:
        return f"{flag} {key}: {error}"
    if flag in ("-params", "--hyperparams") and key in EVALUATED_HYPERPARAMETERS and isinstance(value, str):
        try:
            value = literal_expression(value)
        except ValueError as error:
            return f"{flag} {key}: {error} (rl-zoo3 evaluates it)"
    return spec_setting_problem(flag, key, value)
