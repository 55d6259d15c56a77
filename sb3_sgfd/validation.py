"""Argument and data checks, in one place and with one policy: values are checked where they enter (a
constructor, a public function, the replay buffer's ``add``), never on every gradient step, and a refusal names
the argument and what was expected."""

from __future__ import annotations

import math
from collections.abc import Collection

import numpy as np


def check_choice(name: str, value: object, choices: Collection[str]) -> None:
    """Refuse ``value`` unless it is one of ``choices``, naming the argument ``name`` and the choices."""
    if not isinstance(value, str) or value not in choices:
        raise ValueError(f"{name} must be one of {sorted(choices)}, got {value!r}")


def check_positive_int(**values: int) -> None:
    """Refuse any of ``values`` that is not a positive integer, by name."""
    for name, value in values.items():
        if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 1:
            raise ValueError(f"{name} must be a positive integer, got {value!r}")


def check_non_negative_int(**values: int) -> None:
    """Refuse any of ``values`` that is not an integer >= 0, by name."""
    for name, value in values.items():
        if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 0:
            raise ValueError(f"{name} must be an integer >= 0, got {value!r}")


def check_non_negative(**values: float) -> None:
    """Refuse any of ``values`` that is not a finite number >= 0, by name."""
    for name, value in values.items():
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not 0 <= value < math.inf:
            raise ValueError(f"{name} must be a finite number >= 0, got {value!r}")


class RefusedTransition(ValueError):
    """An env's transition the replay buffer would not store (:func:`check_transitions`): training stops at it,
    nothing of it is stored."""


def check_transitions(
    *,
    observations: np.ndarray,
    next_observations: np.ndarray,
    actions: np.ndarray,
    rewards: np.ndarray,
    domains: np.ndarray,
    n_domains: int | None,
    add_index: int,
) -> None:
    """Refuse one add's transitions (one row per sub-env) if an observation, next observation, action or reward is
    not finite, or a domain label lies outside [0, ``n_domains``): the error names the sub-env, its domain, the add
    and the value, before anything is stored.

    :param add_index: the buffer's count of earlier adds (the vector step of the run, for an unbroken run)
    """
    n_envs = len(domains)
    where = "at add {add} (sub-env {env}, domain {domain})"
    if n_domains is not None:
        outside = np.flatnonzero(domains >= n_domains)
        if len(outside) > 0:
            env = int(outside[0])
            raise RefusedTransition(
                f"the replay buffer refuses domain label {int(domains[env])} from info['domain'] "
                + where.format(add=add_index, env=env, domain=int(domains[env]))
                + f": labels must lie in [0, n_domains={n_domains}); pass n_domains= at least one more than the "
                "largest label"
            )
    for name, values in (
        ("observation", observations),
        ("next observation", next_observations),
        ("action", actions),
        ("reward", rewards),
    ):
        array = np.asarray(values)
        if array.dtype.kind not in "fc":
            continue  # integer images are finite
        rows = array.reshape(n_envs, -1)
        finite = np.isfinite(rows).all(axis=1)
        if not finite.all():
            env = int(np.flatnonzero(~finite)[0])
            value = rows[env][~np.isfinite(rows[env])][0]
            raise RefusedTransition(
                f"the replay buffer refuses a non-finite {name} ({value}) "
                + where.format(add=add_index, env=env, domain=int(domains[env]))
                + ": the env produced it; nothing of this add was stored"
            )
