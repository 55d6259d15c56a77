"""The zoo's error type and its argument checks, in one place, with no heavy import (plotting and ``-h`` need
them too: the env registry is imported only to check an env id)."""

from __future__ import annotations

import difflib
import os
import shlex
from collections.abc import Iterable, Sequence
from pathlib import Path


class ZooError(Exception):
    """Something the user must change (an argument, a file, free space); the CLI prints it as one line, after
    ``sgfd-zoo COMMAND: <label>:``, and exits with ``exit_code``."""

    label = "error"
    exit_code = 2


class TrainingStopped(ZooError):
    """Training stopped before its end (Ctrl-C, a checkpoint that could not be written); the run is not finished
    and the message says how to continue it.

    :param message: what happened, what is kept, what to type
    :param exit_code: ``exit_codes.INTERRUPTED`` for an interrupt (the shell's 128 + SIGINT), 1 otherwise
    """

    label = "stopped"

    def __init__(self, message: str, exit_code: int = 1):
        super().__init__(message)
        self.exit_code = exit_code


def check_env_id(env_id: str | None, flag: str = "--env") -> str:
    """``env_id`` if it is a registered id (``sgfd_envs.ENV_IDS``), else a ZooError naming the flag, the closest
    id and the known ones.

    :param env_id: the value given
    :param flag: the option it came from
    """
    import sgfd_envs

    if env_id not in sgfd_envs.ENV_IDS:
        known = ", ".join(sgfd_envs.ENV_IDS)
        if env_id is None:
            raise ZooError(f"{flag} is required; one of {known}")
        close = difflib.get_close_matches(env_id, sgfd_envs.ENV_IDS, n=1)
        hint = f" (did you mean {close[0]}?)" if close else ""
        raise ZooError(f"{flag} {env_id!r} is not a registered id{hint}; choose from {known}")
    return env_id


def check_log_folder(flag: str, folder: Path) -> None:
    """A ZooError unless run folders can be made in ``folder``: a folder (or one to create) that this process may
    write, on a file system mounted for writing.

    :param flag: the option it came from, e.g. ``-f``
    :param folder: the log folder
    """
    folder = Path(folder)
    if folder.exists() and not folder.is_dir():
        raise ZooError(f"{flag} {folder}: is a file, not a folder; give a log folder (made if missing)")
    existing = next(path for path in [folder, *folder.absolute().parents] if path.exists())
    if not existing.is_dir():
        raise ZooError(f"{flag} {folder}: {existing} is a file, so the folder cannot be made")
    if not os.access(existing, os.W_OK | os.X_OK):
        where = "it is" if folder == existing else f"{existing} is"
        raise ZooError(f"{flag} {folder}: cannot be written ({where} read-only for this user or its file system)")


def checked_names(flag: str, values: Sequence[str], known: Sequence[str]) -> list[str]:
    """``values`` without repeats if each is one of ``known``, else a ZooError naming the flag and a close match.

    :param flag: the option they came from
    :param values: the values given
    :param known: the allowed values
    """
    for value in values:
        if value not in known:
            close = difflib.get_close_matches(value, list(known), n=1)
            hint = f" (did you mean {close[0]}?)" if close else ""
            raise ZooError(f"{flag}: {value!r} is unknown{hint}; choose from {', '.join(known)}")
    return list(dict.fromkeys(values))


def check_at_least(flag: str, value: float | None, low: float, strict: bool = False) -> None:
    """A ZooError unless ``value`` is None or at least ``low`` (above it with ``strict``).

    :param flag: the option, for the message
    :param value: the value given
    :param low: the bound
    :param strict: require value > low
    """
    if value is None:
        return
    if value < low or (strict and value == low):
        raise ZooError(f"{flag} must be {'>' if strict else '>='} {low:g}, got {value:g}")


def check_keywords(
    where: str,
    given: Iterable[str],
    valid: Iterable[str],
    message: str = "unknown key(s) in {where}: {keys}; it takes {valid}",
) -> None:
    """A ZooError naming the keys of ``given`` that are not in ``valid``, a close match, and the valid ones.

    :param where: what the keys are given to, e.g. ``policy_kwargs of sgfd_sac (MlpPolicy)``
    :param given: the keys given
    :param valid: the keys it takes
    :param message: the error's line, formatted with ``where``, ``keys`` (each unknown key with its close match)
        and ``valid`` (the valid keys in name order)
    """
    valid = sorted(valid)
    unknown = [key for key in given if key not in valid]
    if not unknown:
        return
    hints = []
    for key in unknown:
        close = difflib.get_close_matches(key, valid, n=1)
        hints.append(f"{key!r}" + (f" (did you mean {close[0]!r}?)" if close else ""))
    raise ZooError(message.format(where=where, keys=", ".join(hints), valid=", ".join(valid) or "none"))


def has_flag(argv: Sequence[str], flag: str) -> bool:
    """Whether ``argv`` sets ``flag`` (as ``flag value`` or ``flag=value``)."""
    return any(arg == flag or arg.startswith(f"{flag}=") for arg in argv)


def flag_value(argv: Sequence[str], flag: str) -> str | None:
    """The last value ``argv`` gives ``flag``, or None."""
    value = None
    for index, arg in enumerate(argv):
        if arg == flag and index + 1 < len(argv):
            value = argv[index + 1]
        elif arg.startswith(f"{flag}="):
            value = arg.split("=", 1)[1]
    return value


def without_flags(argv: Sequence[str], switches: Iterable[str] = (), options: Iterable[str] = ()) -> list[str]:
    """``argv`` without the flags ``switches`` (no value) and ``options`` (with their value)."""
    switches, options = set(switches), set(options)
    kept, skip = [], False
    for arg in argv:
        if skip:
            skip = False
        elif arg in switches or any(arg.startswith(f"{option}=") for option in options):
            continue
        elif arg in options:
            skip = True
        else:
            kept.append(arg)
    return kept


def train_command(argv: Sequence[str], run_id: int | None, resume: bool) -> str:
    """The ``sgfd-zoo train`` command line of ``argv`` that continues (``resume``) or restarts run ``run_id``.

    :param argv: the flags the run was started with (after ``sgfd-zoo train``)
    :param run_id: its folder's ``_<id>``; None: leave the choice to ``--resume`` (the newest run)
    :param resume: continue from the checkpoint, else start again from step 0
    """
    flags = without_flags(argv, switches=["--resume"], options=["--run-id"])
    flags += [] if run_id is None else ["--run-id", str(run_id)]
    return shlex.join(["sgfd-zoo", "train", *flags, *(["--resume"] if resume else [])])
