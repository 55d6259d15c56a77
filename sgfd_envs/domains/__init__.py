"""The robots, one file each: their XML edit, tasks and a ``load(task, scale)`` like ``suite.load``."""

from __future__ import annotations

from types import ModuleType

from dm_control.rl import control

from sgfd_envs.domains import cheetah, finger, walker
from sgfd_envs.morphology import Morphology

ROBOTS: dict[str, ModuleType] = {"walker": walker, "cheetah": cheetah, "finger": finger}


def robot_module(robot: str) -> ModuleType:
    """The module of one robot.

    :param robot: ``"walker"``, ``"cheetah"`` or ``"finger"``
    """
    if robot not in ROBOTS:
        raise ValueError(f"robot must be one of {tuple(ROBOTS)}, got {robot!r}")
    return ROBOTS[robot]


def load(robot: str, task: str, scale: float = 1.0) -> control.Environment:
    """A dm_control environment of a robot task with its morphology length scaled.

    :param robot: ``"walker"``, ``"cheetah"`` or ``"finger"``
    :param task: a task of that robot, e.g. ``"walk"``
    :param scale: length relative to the dm_control robot (1.0 = unmodified)
    """
    return robot_module(robot).load(task, scale)


def morphology(robot: str) -> Morphology:
    """The length an MT robot varies.

    :param robot: ``"walker"``, ``"cheetah"`` or ``"finger"``
    """
    return robot_module(robot).MORPHOLOGY
