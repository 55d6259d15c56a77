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
