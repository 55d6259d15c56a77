"""Morphology settings of the MT ids, import-light (the id table reads them without loading a simulator).

The MT ids come in two families of robots (the ``robots=`` keyword), ten settings each:

- ``"hipbmdp"`` (the default): HiP-BMDP's robot files, which the SGFD paper's Table 2 ran (its train.py builds
  mtenv's ``MT-HiPBMDP-*`` envs; the files are mtenv's ``local_dm_control_suite/``): setting N is file N of
  ``walker_len_N`` (the left foot's half-length 0.07 + 0.01 N m), ``cheetah_torso_length_N`` (the torso from
  -(0.4 + 0.1 N) to 0.4 + 0.1 N m) or ``finger_size_N`` (the size of the finger class's invisible touch-sensor
  sites, 0.025 N m), with the authors' splits: train files 2, 3, 5, 6, interpolation 4, extrapolation 10
  (their ``initial_task_state`` [1, 2, 4, 5] and [3, 9] index mtenv's list of files from zero);
  :data:`HIPBMDP_FILES`, built by :mod:`sgfd_envs.domains.hipbmdp`;
- ``"scaled"``: this package's own family, one task-relevant length per robot scaled by ten monotone factors
  (:class:`Morphology`), setting 3 the unmodified dm_control robot, split train 1, 2, 4, 5, interpolation 3,
  extrapolation 10 (:data:`PACKAGE_SPLIT_SETTINGS`); its robot files are :mod:`sgfd_envs.domains`' walker,
  cheetah and finger. The ids' only family before version 0.3.0.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

N_SETTINGS = 10
SETTINGS = tuple(range(1, N_SETTINGS + 1))
UNMODIFIED_SETTING = 3
DEFAULT_SCALES = tuple((7 + setting) / 10 for setting in SETTINGS)

HIPBMDP, SCALED = "hipbmdp", "scaled"
MT_ROBOTS = (HIPBMDP, SCALED)
DEFAULT_MT_ROBOTS = HIPBMDP

# The SGFD authors' splits of HiP-BMDP's files (train.py: initial_task_state [1, 2, 4, 5] and [3, 9], indices into
# mtenv's list of the files 1..10).
HIPBMDP_SPLIT_SETTINGS: dict[str, tuple[int, ...]] = {
    "train": (2, 3, 5, 6),
    "interpolation": (4,),
    "extrapolation": (10,),
}
# This package's own: four training robots from settings 1..5 (the paper's text), extrapolation the tenth setting;
# setting 3 (the unmodified robot) lies between the training ones, hence "interpolation". The scaled family's and
# the Causal World ids' splits.
PACKAGE_SPLIT_SETTINGS: dict[str, tuple[int, ...]] = {
    "train": (1, 2, 4, 5),
    "interpolation": (3,),
    "extrapolation": (10,),
}
SPLIT_SETTINGS_OF_ROBOTS = {HIPBMDP: HIPBMDP_SPLIT_SETTINGS, SCALED: PACKAGE_SPLIT_SETTINGS}
# The MT ids' default splits.
DEFAULT_SPLIT_SETTINGS = SPLIT_SETTINGS_OF_ROBOTS[DEFAULT_MT_ROBOTS]
MORPHOLOGY_SPLITS = tuple(DEFAULT_SPLIT_SETTINGS)
SplitTable = Mapping[str, tuple[int, ...]]


def check_robots(robots: str) -> str:
    """Return ``robots`` if it names a family of MT robots (:data:`MT_ROBOTS`), else raise naming them."""
    if robots not in MT_ROBOTS:
        raise ValueError(f"robots must be one of {MT_ROBOTS} for MT ids, got {robots!r}")
    return robots


@dataclass(frozen=True)
class RobotFiles:
    """HiP-BMDP's ten robot files of one robot: file N is setting N.

    :param prefix: the files' names without ``_N.xml``, as mtenv names them (``"walker_len"``)
    :param parameter: what the files change, e.g. ``"left_foot_half_length"``
    :param values: that quantity in file 1..10 (metres)
    :param unmodified_setting: the file that is dm_control's robot (walker 3, cheetah and finger 1)
    """

    prefix: str
    parameter: str
    values: tuple[float, ...]
    unmodified_setting: int

    def value(self, setting: int) -> float:
        """What file ``setting`` gives the quantity, in metres.

        :param setting: morphology setting, an int in 1..10
        """
        return self.values[check_setting(setting) - 1]


# The files' edits (mtenv's local_dm_control_suite): each changes one number of dm_control's robot.
HIPBMDP_FILES: dict[str, RobotFiles] = {
    "walker": RobotFiles("walker_len", "left_foot_half_length", tuple(round(0.07 + 0.01 * n, 6) for n in SETTINGS), 3),
    "cheetah": RobotFiles("cheetah_torso_length", "torso_length", tuple(round(0.8 + 0.2 * n, 6) for n in SETTINGS), 1),
    "finger": RobotFiles("finger_size", "touch_site_size", tuple(round(0.025 * n, 6) for n in SETTINGS), 1),
}


def check_setting(setting: int) -> int:
    """Return ``setting`` if it is one of the ten settings, else raise.

    :param setting: morphology setting, an int in 1..10
    """
    if isinstance(setting, bool) or not isinstance(setting, (int, np.integer)) or setting not in SETTINGS:
        raise ValueError(f"setting must be an int in 1..{N_SETTINGS}, got {setting!r}")
    return int(setting)


def resolve_split_settings(
    split_settings: Mapping[str, Sequence[int]] | None = None, defaults: SplitTable = DEFAULT_SPLIT_SETTINGS
) -> dict[str, tuple[int, ...]]:
    """A default split table with the given splits replaced.

    :param split_settings: split name -> settings, for some of ``train``, ``interpolation``,
        ``extrapolation``; the others keep their defaults
    :param defaults: the split table of the family (:data:`SPLIT_SETTINGS_OF_ROBOTS`)
    """
    resolved = dict(defaults)
    for split, settings in (split_settings or {}).items():
        if split not in defaults:
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
    split: str,
    split_settings: Mapping[str, Sequence[int]] | None = None,
    ids: str = "MT ids",
    defaults: SplitTable = DEFAULT_SPLIT_SETTINGS,
) -> tuple[int, ...]:
    """The settings of one split, after ``split_settings`` replaced some splits.

    :param split: ``train``, ``interpolation`` or ``extrapolation``
    :param split_settings: see :func:`resolve_split_settings`
    :param ids: the family of ids, for the message
    :param defaults: the split table of the family (:data:`SPLIT_SETTINGS_OF_ROBOTS`)
    """
    table = resolve_split_settings(split_settings, defaults)
    if split not in table:
        raise ValueError(f"split must be one of {MORPHOLOGY_SPLITS} for {ids}, got {split!r}")
    return table[split]


def select_setting(
    split: str | None,
    domain: int | None,
    setting: int | None,
    split_settings: Mapping[str, Sequence[int]] | None = None,
    ids: str = "MT ids",
    defaults: SplitTable = DEFAULT_SPLIT_SETTINGS,
) -> tuple[str | None, int, int, int]:
    """Which setting an env gets: ``setting`` itself (domain 0 of no split), or domain ``domain``
    (default 0) of split ``split`` (default ``train``) of the split table ``defaults`` after ``split_settings``.

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
    settings = split_settings_of(split, split_settings, ids, defaults)
    domain = check_domain(0 if domain is None else domain, len(settings), split)
    return split, domain, len(settings), settings[domain]


@dataclass(frozen=True)
class Morphology:
    """The one length a robot of the scaled family varies, and its ten settings.

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
