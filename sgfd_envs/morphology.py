"""Morphology settings of the MT ids, import-light (the id table reads them without loading a simulator).

Each MT robot has one task-relevant length with ten monotone settings, each a scale of the
unmodified dm_control length. Setting 3 is always the unmodified robot. The default scales are
0.8, 0.9, 1.0, ..., 1.7 (the prior MT benchmark's walker foot range); a robot may narrow them where
a setting would break its task. The robot files in :mod:`sgfd_envs.domains` apply the scale to the
dm_control XML in code.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

N_SETTINGS = 10
SETTINGS = tuple(range(1, N_SETTINGS + 1))
UNMODIFIED_SETTING = 3
DEFAULT_SCALES = tuple((7 + setting) / 10 for setting in SETTINGS)

# Paper: four training robots drawn from settings 1..5, extrapolation = the tenth setting.
# Setting 3 (the unmodified robot) lies between the training ones, hence "interpolation".
DEFAULT_SPLIT_SETTINGS: dict[str, tuple[int, ...]] = {
    "train": (1, 2, 4, 5),
    "interpolation": (3,),
    "extrapolation": (10,),
}
MORPHOLOGY_SPLITS = tuple(DEFAULT_SPLIT_SETTINGS)


def check_setting(setting: int) -> int:
    """Return ``setting`` if it is one of the ten settings, else raise.

    :param setting: morphology setting, an int in 1..10
    """
    if isinstance(setting, bool) or not isinstance(setting, (int, np.integer)) or setting not in SETTINGS:
        raise ValueError(f"setting must be an int in 1..{N_SETTINGS}, got {setting!r}")
    return int(setting)


def resolve_split_settings(
    split_settings: Mapping[str, Sequence[int]] | None = None,
) -> dict[str, tuple[int, ...]]:
    """The default split table with the given splits replaced.

    :param split_settings: split name -> settings, for some of ``train``, ``interpolation``,
        ``extrapolation``; the others keep their defaults
    """
    resolved = dict(DEFAULT_SPLIT_SETTINGS)
    for split, settings in (split_settings or {}).items():
        if split not in DEFAULT_SPLIT_SETTINGS:
            raise ValueError(f"split_settings: unknown split {split!r}, expected one of {MORPHOLOGY_SPLITS}")
        if isinstance(settings, (str, bytes)) or not isinstance(settings, Sequence) or len(settings) == 0:
            raise ValueError(f"split_settings[{split!r}] must be a non-empty sequence of settings in 1..10")
        checked = tuple(check_setting(setting) for setting in settings)
        if len(set(checked)) != len(checked):
            raise ValueError(f"split_settings[{split!r}] repeats a setting: {checked}")
        resolved[split] = checked
    return resolved


def check_domain(domain: int, count: int, split: str) -> int:
    """Return ``domain`` as an int if it indexes one of the ``count`` domains of ``split``, else raise.

    :param domain: index of a domain within its split
    :param count: number of domains in the split
    :param split: the split's name, for the message
    """
    if isinstance(domain, bool) or not isinstance(domain, (int, np.integer)) or not 0 <= domain < count:
        raise ValueError(f"domain must be an int in 0..{count - 1} for split {split!r}, got {domain!r}")
    return int(domain)


def split_settings_of(
    split: str, split_settings: Mapping[str, Sequence[int]] | None = None, ids: str = "MT ids"
) -> tuple[int, ...]:
    """The settings of one split, after ``split_settings`` replaced some splits.

    :param split: ``train``, ``interpolation`` or ``extrapolation``
    :param split_settings: see :func:`resolve_split_settings`
    :param ids: the family of ids, for the message
    """
    table = resolve_split_settings(split_settings)
    if split not in table:
        raise ValueError(f"split must be one of {MORPHOLOGY_SPLITS} for {ids}, got {split!r}")
    return table[split]


def select_setting(
    split: str | None,
    domain: int | None,
    setting: int | None,
    split_settings: Mapping[str, Sequence[int]] | None = None,
    ids: str = "MT ids",
) -> tuple[str | None, int, int, int]:
    """Which setting an env gets: ``setting`` itself (domain 0 of no split), or domain ``domain``
    (default 0) of split ``split`` (default ``train``).

    :return: split (None with ``setting=``), domain index, number of domains in the split, setting
    """
    if setting is not None:
        if split is not None or domain is not None:
            raise ValueError(
                f"give either setting= or split=/domain=, not both (got setting={setting!r}, "
                f"split={split!r}, domain={domain!r})"
            )
        return None, 0, 1, check_setting(setting)
    split = "train" if split is None else split
    settings = split_settings_of(split, split_settings, ids)
    domain = check_domain(0 if domain is None else domain, len(settings), split)
    return split, domain, len(settings), settings[domain]


@dataclass(frozen=True)
class Morphology:
    """The one length an MT robot varies, and its ten settings.

    :param parameter: name of the length, e.g. ``"torso_length"``
    :param default_length: the unmodified dm_control length in metres
    :param scales: the ten scales of ``default_length``, increasing, setting 3 = 1.0
    """

    parameter: str
    default_length: float
    scales: tuple[float, ...] = DEFAULT_SCALES

    def __post_init__(self) -> None:
        if len(self.scales) != N_SETTINGS or not np.all(np.diff(self.scales) > 0):
            raise ValueError(f"scales must be {N_SETTINGS} increasing numbers, got {self.scales}")
        if self.scales[UNMODIFIED_SETTING - 1] != 1.0:
            raise ValueError(f"setting {UNMODIFIED_SETTING} must be the unmodified robot (scale 1.0)")

    def scale(self, setting: int) -> float:
        """Scale of the default length at one setting.

        :param setting: morphology setting, an int in 1..10
        """
        return self.scales[check_setting(setting) - 1]

    def value(self, setting: int) -> float:
        """Length in metres at one setting.

        :param setting: morphology setting, an int in 1..10
        """
        return round(self.default_length * self.scale(setting), 6)
