"""Values read from others' files are data: each is checked before it becomes a path, a table cell or a number
(docs/trust.md). A split, an algorithm, an env or a seed read from a record must be one the record's place and its
env allow; a name that will name a file keeps to a safe alphabet; a return is a finite number. Anything else is
refused in one line naming the file and the value: a :class:`~sgfd_zoo.runs.bounded.RefusedFile` where the value would
become a path or a name (a split, an algorithm, an env), an :class:`~sgfd_zoo.runs.bounded.UnreadableFile` where it
is not what the zoo writes (a seed that is no whole number, a return that is not finite, a missing field).
"""

from __future__ import annotations

import functools
import math
import re
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from sgfd_zoo.runs.bounded import RefusedFile, UnreadableFile

#: A name that may become part of a file's name: letters, digits, ``.``, ``_`` and ``-``, starting with a letter or
#: a digit (so never ``..``, a hidden file or an option), at most 128 characters.
SAFE_NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9._-]{0,127}")
#: An algorithm's key, as the zoo and rl-zoo3 name their folders (``sgfd_sac``, ``ppo_lstm``).
ALGO_KEY = re.compile(r"[a-z][a-z0-9_]{0,63}")
MAX_SEED = 2**32 - 1  # numpy's, which rl-zoo3 seeds with


def safe_name(value: Any, what: str, source: Path | str) -> str:
    """``value`` when it is a :data:`SAFE_NAME`, else refused: it would name a file.

    :param value: the value read
    :param what: what it is, for the message (``split``)
    :param source: the file it was read from
    """
    if not isinstance(value, str) or not SAFE_NAME.fullmatch(value):
        raise RefusedFile(
            f"{source}: refused: {what} {value!r} is not a plain name (letters, digits, '.', '_', '-'; at most 128): "
            "it would become part of a file's name"
        )
    return value


def algo_key(value: Any, source: Path | str) -> str:
    """``value`` when it reads as an algorithm's key (:data:`ALGO_KEY`), else refused."""
    if not isinstance(value, str) or not ALGO_KEY.fullmatch(value):
        raise RefusedFile(f"{source}: refused: {value!r} is not an algorithm's key (lower-case letters, digits, '_')")
    return value


@functools.cache
def split_labels(env_id: str) -> tuple[str, ...]:
    """The splits an env id is evaluated on (``sgfd-zoo evaluate``'s labels: the splits, and DMC-GB2's
    ``distracting_cs`` once per intensity)."""
    import sgfd_envs

    return tuple(label for label, _ in sgfd_envs.evaluation_modes(env_id))


def checked_split(value: Any, env_id: str, source: Path | str) -> str:
    """``value`` when it is one of ``env_id``'s splits (:func:`split_labels`), else refused naming them."""
    labels = split_labels(env_id)
    if value not in labels:
        raise RefusedFile(f"{source}: refused: split {value!r} is not one of {env_id}'s: {', '.join(labels)}")
    return str(value)


def checked_env(value: Any, source: Path | str) -> str:
    """``value`` when it is a registered env id, else refused."""
    import sgfd_envs

    if value not in sgfd_envs.ENV_IDS:
        raise RefusedFile(f"{source}: refused: env {value!r} is not a registered id (sgfd_envs.ENV_IDS)")
    return str(value)


def whole_number(value: Any, what: str, source: Path | str, low: int = 0, high: int | None = None) -> int:
    """``value`` (an int, or its decimal digits as a CSV holds them; ``6000.0`` too) as an int in ``[low, high]``,
    else refused. A bool, ``6e3``, ``nan`` and fractions are refused: the zoo writes whole numbers as digits."""
    number: int | None = None
    if isinstance(value, int) and not isinstance(value, bool):
        number = value
    elif isinstance(value, float) and value.is_integer():
        number = int(value)
    elif isinstance(value, str) and re.fullmatch(r"-?[0-9]{1,19}(\.0*)?", value.strip()):
        number = int(value.strip().split(".")[0])
    if number is None or number < low or (high is not None and number > high):
        bounds = f">= {low}" + ("" if high is None else f" and <= {high}")
        raise UnreadableFile(f"{source} is unreadable ({what} {value!r} is not a whole number {bounds})")
    return number


def finite_number(value: Any, what: str, source: Path | str, low: float | None = None) -> float:
    """``value`` (a number, or its text) as a finite float (at least ``low``), else refused: NaN and infinities
    have no place in a table of returns or a curve."""
    number: float | None = None
    if isinstance(value, int | float) and not isinstance(value, bool):
        number = float(value)
    elif isinstance(value, str) and len(value) <= 64:
        try:
            number = float(value)
        except ValueError:
            number = None
    if number is None or not math.isfinite(number) or (low is not None and number < low):
        bound = "" if low is None else f" >= {low:g}"
        raise UnreadableFile(f"{source} is unreadable ({what} {value!r} is not a finite number{bound})")
    return number


def flag(value: Any, what: str, source: Path | str) -> bool:
    """``value`` as a bool: True or False, or their text (``True``, ``False``, ``1``, ``0``, empty for False)."""
    if isinstance(value, bool):
        return value
    text = "" if value is None else str(value).strip().lower()
    if text not in ("true", "1", "false", "0", ""):
        raise UnreadableFile(f"{source} is unreadable ({what} {value!r} is not True or False)")
    return text in ("true", "1")


def result_row(row: Mapping[str, Any], source: Path | str, algo: str | None = None, env_id: str | None = None) -> dict:
    """A row of the final model's evaluation (``sgfd-zoo evaluate``'s, a record's ``final_evaluation.csv``), each
    field checked and typed: the algorithm and env (those of the run it belongs to, when given), a split of the
    env, a seed, finite returns, a number of episodes; refused in one line naming the file and the field.

    :param row: the row as read (strings from a CSV file, or values)
    :param source: the file it was read from
    :param algo: the run's algorithm: the row must name it
    :param env_id: the run's env id: the row must name it
    """
    fields = ("algo", "env", "split", "seed", "mean_reward", "std_reward", "n_episodes")
    missing = [key for key in fields if key not in row]
    if missing:
        raise UnreadableFile(f"{source} is unreadable (a row lacks {', '.join(missing)})")
    checked: dict[str, Any] = {"algo": algo_key(row["algo"], source), "env": checked_env(row["env"], source)}
    for key, expected in (("algo", algo), ("env", env_id)):
        if expected is not None and checked[key] != expected:
            named = f"a row names {key} {checked[key]!r}, its run's is {expected!r}"
            raise UnreadableFile(f"{source} is unreadable ({named})")
    checked["split"] = checked_split(row["split"], checked["env"], source)
    checked["seed"] = whole_number(row["seed"], "seed", source, 0, MAX_SEED)
    checked["mean_reward"] = finite_number(row["mean_reward"], "mean_reward", source)
    checked["std_reward"] = finite_number(row["std_reward"], "std_reward", source, low=0.0)
    checked["n_episodes"] = whole_number(row["n_episodes"], "n_episodes", source, 1)
    if row.get("stand_in") not in (None, ""):
        checked["stand_in"] = flag(row["stand_in"], "stand_in", source)
    return checked
