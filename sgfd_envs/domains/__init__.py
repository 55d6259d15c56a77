"""The robots of the SGFD ids: HiP-BMDP's robot files (:mod:`sgfd_envs.domains.hipbmdp`, the paper's), and this
package's scaled robots, one file each (their XML edit, tasks and a ``load(task, scale)`` like ``suite.load``); and
the unmodified dm_control tasks the benchmarks run on (:func:`load_suite`)."""

from __future__ import annotations

import importlib
from types import ModuleType

from dm_control.rl import control

from sgfd_envs.domains import cheetah, finger, walker
from sgfd_envs.domains import hipbmdp as hipbmdp  # after the robots it builds on
from sgfd_envs.morphology import HIPBMDP, HIPBMDP_FILES, Morphology, RobotFiles, check_robots

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
    """The length a robot of the scaled family varies.

    :param robot: ``"walker"``, ``"cheetah"`` or ``"finger"``
    """
    return robot_module(robot).MORPHOLOGY


def mt_morphology(robots: str, robot: str) -> Morphology | RobotFiles:
    """What a family's settings of ``robot`` change: its ``parameter`` and ``value(setting)``.

    :param robots: ``"hipbmdp"`` or ``"scaled"`` (:data:`sgfd_envs.morphology.MT_ROBOTS`)
    :param robot: ``"walker"``, ``"cheetah"`` or ``"finger"``
    """
    if check_robots(robots) == HIPBMDP:
        robot_module(robot)
        return HIPBMDP_FILES[robot]
    return morphology(robot)


def load_mt(robots: str, robot: str, task: str, setting: int) -> control.Environment:
    """The task on setting ``setting`` of a family of MT robots.

    :param robots: ``"hipbmdp"`` (HiP-BMDP's file ``setting``) or ``"scaled"`` (this package's robot scaled as
        its setting says)
    :param robot: ``"walker"``, ``"cheetah"`` or ``"finger"``
    :param task: a task of that robot
    :param setting: the setting, 1..10
    """
    if check_robots(robots) == HIPBMDP:
        return hipbmdp.load(robot, task, setting)
    return load(robot, task, morphology(robot).scale(setting))


# The dm_control tasks of DMC-GB, DMC-GB2 and the Distracting Control Suite, unmodified: (domain, task).
SUITE_TASKS = (
    ("walker", "walk"),
    ("walker", "stand"),
    ("cheetah", "run"),
    ("finger", "spin"),
    ("cartpole", "swingup"),
    ("ball_in_cup", "catch"),
    ("reacher", "easy"),
)


def load_suite(domain: str, task: str) -> control.Environment:
    """dm_control's own task with no time limit (the gymnasium env counts steps), as ``suite.load`` builds it.

    :param domain: a dm_control domain of :data:`SUITE_TASKS`, e.g. ``"ball_in_cup"``
    :param task: its task, e.g. ``"catch"``
    """
    if (domain, task) not in SUITE_TASKS:
        raise ValueError(f"(domain, task) must be one of {SUITE_TASKS}, got {(domain, task)!r}")
    if domain == "cheetah":
        # The same model as dm_control's, without MuJoCo's deprecation warning at every compile.
        return cheetah.load(task)
    module = importlib.import_module(f"dm_control.suite.{domain}")
    return getattr(module, task)(time_limit=float("inf"))
