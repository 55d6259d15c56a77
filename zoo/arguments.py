"""The zoo's error type and its argument checks, in one place, with no heavy import (plotting needs them too)."""

from __future__ import annotations

import difflib
from collections.abc import Sequence

import sgfd_envs


class ZooError(Exception):
    """A mistake in what the user asked for; the CLI prints it as one line and exits non-zero."""


def check_env_id(env_id: str | None, flag: str = "--env") -> str:
    """``env_id`` if it is an SGFD id, else a ZooError naming the flag, the closest id and the known ones.

    :param env_id: the value given
    :param flag: the option it came from
    """
    if env_id not in sgfd_envs.SGFD_IDS:
        known = ", ".join(sgfd_envs.SGFD_IDS)
        if env_id is None:
            raise ZooError(f"{flag} is required; one of {known}")
        close = difflib.get_close_matches(env_id, sgfd_envs.SGFD_IDS, n=1)
        hint = f" (did you mean {close[0]}?)" if close else ""
        raise ZooError(f"{flag} {env_id!r} is not an SGFD id{hint}; choose from {known}")
    return env_id


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
