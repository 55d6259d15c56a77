"""Argument and data checks, in one place and with one policy: values are checked where they enter (a
constructor, a public function, the replay buffer's ``add``), never on every gradient step, and a refusal names
the argument, the value and what was expected.

Pure torch and numpy, no Stable-Baselines3 import: the math modules check their tensors with these too. A check
that would read a GPU tensor back to the host (its values, not its shape) is only made where the caller asks.

Only what more than one part of the package checks is here; a check that one algorithm alone needs lives in that
algorithm's folder, beside the code it guards.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Collection, Mapping
from typing import Any

import numpy as np
import torch
from torch import Tensor


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


def _positive_number(value: object) -> bool:
    number = not isinstance(value, bool) and isinstance(value, (int, float, np.floating))
    return number and 0 < value < math.inf  # type: ignore[operator]


def check_positive(**values: float) -> None:
    """Refuse any of ``values`` that is not a finite number > 0, by name."""
    for name, value in values.items():
        if not _positive_number(value):
            raise ValueError(f"{name} must be a finite number > 0, got {value!r}")


def check_optional_positive(name: str, value: object) -> None:
    """Refuse ``value`` unless it is a finite number > 0 or None, naming the argument ``name``."""
    if value is not None and not _positive_number(value):
        raise ValueError(f"{name} must be a finite number > 0 or None, got {value!r}")


def check_interval(
    name: str,
    value: object,
    low: float,
    high: float,
    *,
    low_open: bool = False,
    high_open: bool = False,
    also: str = "",
) -> None:
    """Refuse ``value`` unless it is a number in the interval from ``low`` to ``high`` (open at an end where said),
    naming the argument ``name`` (and ``also``, what else it may be)."""
    number = isinstance(value, (int, float, np.floating)) and not isinstance(value, bool)
    above = number and (low < value if low_open else low <= value)  # type: ignore[operator]
    below = number and (value < high if high_open else value <= high)  # type: ignore[operator]
    if not (above and below):
        interval = f"{'(' if low_open else '['}{low:g}, {high:g}{')' if high_open else ']'}"
        alternative = f" or {also}" if also else ""
        raise ValueError(f"{name} must be a number in {interval}{alternative}, got {value!r}")


def check_bool(**values: bool) -> None:
    """Refuse any of ``values`` that is not True or False, by name."""
    for name, value in values.items():
        if not isinstance(value, (bool, np.bool_)):
            raise ValueError(f"{name} must be True or False, got {value!r}")


# --- the arguments of SB3's SAC, which every agent here takes ---


def _learning_rate(name: str, value: Any) -> None:
    if callable(value):
        return
    if isinstance(value, bool) or not isinstance(value, (int, float, np.floating)) or not 0 < value < math.inf:
        raise ValueError(
            f"{name} must be a number > 0 or a schedule (a function of the remaining progress), got {value!r}"
        )


def _train_freq(name: str, value: Any) -> None:
    if isinstance(value, (tuple, list)):
        if len(value) != 2 or value[1] not in ("step", "episode"):
            raise ValueError(f"{name} must be an int >= 1 or (int >= 1, 'step' or 'episode'), got {value!r}")
        value = value[0]
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 1:
        raise ValueError(f"{name} must be an int >= 1 or (int >= 1, 'step' or 'episode'), got {value!r}")


def _gradient_steps(name: str, value: Any) -> None:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or not (value >= 0 or value == -1):
        raise ValueError(f"{name} must be an int >= 0, or -1 (as many as env steps were collected), got {value!r}")


def _ent_coef(name: str, value: Any) -> None:
    if isinstance(value, str):
        if value == "auto":
            return
        start = value.removeprefix("auto_")
        try:
            valid = value.startswith("auto_") and 0 < float(start) < math.inf
        except ValueError:
            valid = False
        if valid:
            return
    elif not isinstance(value, bool) and isinstance(value, (int, float, np.floating)) and 0 < value < math.inf:
        return
    raise ValueError(f"{name} must be 'auto', 'auto_<initial value>' or a number > 0, got {value!r}")


def _target_entropy(name: str, value: Any) -> None:
    number = not isinstance(value, bool) and isinstance(value, (int, float, np.floating))
    if value == "auto" or (number and math.isfinite(value)):
        return
    raise ValueError(f"{name} must be 'auto' or a finite number, got {value!r}")


def _seed(name: str, value: Any) -> None:
    if value is not None:
        check_non_negative_int(**{name: value})


#: SB3 SAC's arguments and their checks (the agents' own are their ``check_arguments``)
SAC_ARGUMENT_CHECKS: dict[str, Callable[[str, Any], None]] = {
    "learning_rate": _learning_rate,
    "buffer_size": lambda name, value: check_positive_int(**{name: value}),
    "learning_starts": lambda name, value: check_non_negative_int(**{name: value}),
    "batch_size": lambda name, value: check_positive_int(**{name: value}),
    "tau": lambda name, value: check_interval(name, value, 0.0, 1.0),
    "gamma": lambda name, value: check_interval(name, value, 0.0, 1.0),
    "train_freq": _train_freq,
    "gradient_steps": _gradient_steps,
    "n_steps": lambda name, value: check_positive_int(**{name: value}),
    "ent_coef": _ent_coef,
    "target_update_interval": lambda name, value: check_positive_int(**{name: value}),
    "target_entropy": _target_entropy,
    "stats_window_size": lambda name, value: check_positive_int(**{name: value}),
    "seed": _seed,
}


def check_sac_arguments(arguments: Mapping[str, Any]) -> None:
    """Refuse a bad value of any of SB3 SAC's arguments among ``arguments`` (SAC itself takes them unchecked: a
    batch size of 0 or a one-slot buffer would train on), naming the argument, the value and what is allowed."""
    for name, value in arguments.items():
        if name in SAC_ARGUMENT_CHECKS:
            SAC_ARGUMENT_CHECKS[name](name, value)


def _augmentation_views(name: str, value: Any) -> None:
    if isinstance(value, bool) or value not in (0, 1, 2):
        raise ValueError(f"{name} must be 0, 1 or 2, got {value!r}")


def _optional_rate(name: str, value: Any) -> None:
    if value is not None:
        check_interval(name, value, 0.0, 1.0, low_open=True)


#: The arguments EncoderSAC adds to SAC's, and their checks
ENCODER_SAC_ARGUMENT_CHECKS: dict[str, Callable[[str, Any], None]] = {
    "actor_update_interval": lambda name, value: check_positive_int(**{name: value}),
    "augmentation_views": _augmentation_views,
    "augmentation_pad": lambda name, value: check_non_negative_int(**{name: value}),
    "encoder_tau": _optional_rate,
    "max_grad_norm": check_optional_positive,
    "ent_coef_lr": check_optional_positive,
    "ent_coef_beta": lambda name, value: check_interval(name, value, 0.0, 1.0, high_open=True),
    "actor_reuses_features": lambda name, value: check_bool(**{name: value}),
}


def check_encoder_sac_arguments(arguments: Mapping[str, Any]) -> None:
    """Refuse a bad value of any of the arguments EncoderSAC adds to SAC's among ``arguments``, by name."""
    for name, value in arguments.items():
        if name in ENCODER_SAC_ARGUMENT_CHECKS:
            ENCODER_SAC_ARGUMENT_CHECKS[name](name, value)


def check_fixed_representation(algorithm: str, fixed: str | None, representation: str | None) -> None:
    """Refuse an algorithm with an objective of its own (``fixed``) given another ``representation``."""
    if fixed is not None and representation != fixed:
        raise ValueError(
            f"{algorithm} trains the {fixed!r} representation, got representation={representation!r} (EncoderSAC "
            "takes any)"
        )


def check_hyperparameters(algo_class: type, hyperparameters: Mapping[str, Any]) -> None:
    """Refuse, before anything is built, a bad value of a constructor argument of ``algo_class`` among
    ``hyperparameters``: through the algorithm's own ``check_arguments`` (the agents of this package: SAC's
    arguments, their own and the objective's ``representation_kwargs``), else SAC's checks.

    :param algo_class: the algorithm class the hyperparameters are for (an agent of this package or SB3's ``SAC``)
    :param hyperparameters: its keyword arguments, as the zoo's yaml gives them
    :raises ValueError: one line naming the argument, the value and what is allowed
    """
    check = getattr(algo_class, "check_arguments", None)
    if check is not None:
        check(hyperparameters)
    else:
        check_sac_arguments(hyperparameters)


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


# --- tensors of the math modules ---


def check_matrix(
    x: object, name: str, rows: int | None = None, cols: int | None = None, *, min_rows: int = 1, finite: bool = False
) -> None:
    """Refuse ``x`` unless it is a floating-point (n, d) tensor, with ``rows`` rows and ``cols`` columns where given
    (at least ``min_rows`` and 1 otherwise); with ``finite``, also a NaN or inf in it (a host read)."""
    if not isinstance(x, Tensor):
        raise TypeError(f"{name} must be a torch.Tensor, got {type(x).__name__}")
    if not x.is_floating_point():
        raise TypeError(f"{name} must be a floating-point tensor, got {x.dtype}")
    wrong_rows = x.dim() == 2 and (x.shape[0] != rows if rows is not None else x.shape[0] < min_rows)
    wrong_cols = x.dim() == 2 and (x.shape[1] != cols if cols is not None else x.shape[1] < 1)
    if x.dim() != 2 or wrong_rows or wrong_cols:
        expected = f"({'n' if rows is None else rows}, {'d' if cols is None else cols})"
        at_least = f" with n >= {min_rows}" if rows is None and min_rows > 1 else ""
        raise ValueError(f"{name} must have shape {expected}{at_least}, got {tuple(x.shape)}")
    if finite and not torch.isfinite(x).all():
        raise ValueError(f"{name} contains NaN or inf values")


def check_same_shape(x: object, name: str, like: Tensor, like_name: str) -> None:
    """Refuse ``x`` unless it is a floating-point matrix of the shape of ``like`` (called ``like_name``)."""
    check_matrix(x, name)
    assert isinstance(x, Tensor)
    if x.shape != like.shape:
        raise ValueError(f"{name} must have the shape of {like_name} {tuple(like.shape)}, got {tuple(x.shape)}")


def check_rewards(rewards: object, n: int) -> Tensor:
    """Rewards (n,) or (n, 1) as a (n,) tensor."""
    if not isinstance(rewards, Tensor) or rewards.shape not in ((n,), (n, 1)):
        shape = tuple(rewards.shape) if isinstance(rewards, Tensor) else type(rewards).__name__
        raise ValueError(f"rewards must be a tensor of shape ({n},) or ({n}, 1), got {shape}")
    return rewards.reshape(n)


def check_perm(perm: object, n: int) -> None:
    """Refuse a pairing of n rows that is not an integer (n,) tensor. Its values are not read: whether it is a
    permutation would be a host read on every gradient step, and any pairing of the rows is a well-defined loss."""
    if not isinstance(perm, Tensor) or perm.shape != (n,) or perm.dtype not in (torch.int32, torch.int64):
        shape = f"{tuple(perm.shape)} {perm.dtype}" if isinstance(perm, Tensor) else type(perm).__name__
        raise ValueError(f"perm must be an integer tensor of shape ({n},), got {shape}")


def check_gamma(gamma: object) -> None:
    """Refuse a discount that is not a number in [0, 1)."""
    check_interval("gamma", gamma, 0.0, 1.0, high_open=True)
