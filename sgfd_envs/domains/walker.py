"""Planar walker: dm_control's walker with a scalable torso length (walk and run tasks)."""

from __future__ import annotations

from dm_control.rl import control
from dm_control.suite import common
from dm_control.suite import walker as dm_walker
from dm_control.utils import rewards

from sgfd_envs.domains.suite_xml import find_named, get_floats, read_suite_model, set_floats, to_xml_string
from sgfd_envs.morphology import Morphology

CONTROL_TIMESTEP = 0.025
MOVE_SPEEDS = {"walk": 1.0, "run": 8.0}
TASKS = tuple(MOVE_SPEEDS)

_TORSO_HALF_LENGTH = 0.3
# In the standing pose the hips sit this high above the floor (legs straight, feet flat).
_HIP_HEIGHT = 1.0
# dm_control rewards a torso centre 0.1 m below its standing height (1.2 for the 1.3 m default).
_STAND_SLACK = 0.1

MORPHOLOGY = Morphology(parameter="torso_length", default_length=2 * _TORSO_HALF_LENGTH)


def stand_height(scale: float = 1.0) -> float:
    """Torso height that earns the full standing reward for a torso scaled by ``scale``.

    :param scale: torso length relative to dm_control's walker
    """
    return _HIP_HEIGHT + _TORSO_HALF_LENGTH * scale - _STAND_SLACK


def model_xml(scale: float = 1.0) -> str:
    """The walker XML with its torso ``scale`` times dm_control's length.

    The hips move with the torso's lower end and the torso starts high enough for straight legs
    to reach the floor, so the legs are the same robot at every scale.

    :param scale: torso length relative to dm_control's walker
    """
    root = read_suite_model("walker.xml")
    half_length = _TORSO_HALF_LENGTH * scale
    torso_geom = find_named(root, "geom", "torso")
    radius = get_floats(torso_geom, "size")[0]
    set_floats(torso_geom, "size", [radius, half_length])
    torso = find_named(root, "body", "torso")
    set_floats(torso, "pos", [0.0, 0.0, _HIP_HEIGHT + half_length])
    for thigh_name in ("right_thigh", "left_thigh"):
        thigh = find_named(root, "body", thigh_name)
        x, y, _ = get_floats(thigh, "pos")
        set_floats(thigh, "pos", [x, y, -half_length])
    return to_xml_string(root)


class Move(dm_walker.PlanarWalker):
    """dm_control's walk/run task with the stand height following the torso length.

    :param move_speed: target horizontal speed (m/s)
    :param stand_height: torso height for the full standing reward
    :param random: seed or RandomState of the task
    """

    def __init__(self, move_speed: float, stand_height: float, random=None) -> None:
        self._stand_height = stand_height
        super().__init__(move_speed=move_speed, random=random)

    def get_reward(self, physics: dm_walker.Physics) -> float:
        """dm_control's walker reward with ``stand_height`` in place of its fixed 1.2."""
        standing = rewards.tolerance(
            physics.torso_height(), bounds=(self._stand_height, float("inf")), margin=self._stand_height / 2
        )
        upright = (1 + physics.torso_upright()) / 2
        stand_reward = (3 * standing + upright) / 4
        move_reward = rewards.tolerance(
            physics.horizontal_velocity(),
            bounds=(self._move_speed, float("inf")),
            margin=self._move_speed / 2,
            value_at_margin=0.5,
            sigmoid="linear",
        )
        return stand_reward * (5 * move_reward + 1) / 6


def load(task: str, scale: float = 1.0) -> control.Environment:
    """A dm_control environment of the walker with no time limit (the gymnasium env counts steps).

    :param task: ``"walk"`` or ``"run"``
    :param scale: torso length relative to dm_control's walker
    """
    if task not in TASKS:
        raise ValueError(f"walker task must be one of {TASKS}, got {task!r}")
    physics = dm_walker.Physics.from_xml_string(model_xml(scale), common.ASSETS)
    move = Move(move_speed=MOVE_SPEEDS[task], stand_height=stand_height(scale))
    return control.Environment(physics, move, time_limit=float("inf"), control_timestep=CONTROL_TIMESTEP)
