"""Finger: dm_control's finger with a scalable distal link (spin and turn tasks)."""

from __future__ import annotations

from dm_control.rl import control
from dm_control.suite import common
from dm_control.suite import finger as dm_finger

from sgfd_envs.domains.suite_xml import find_named, get_floats, read_suite_model, set_floats, to_xml_string
from sgfd_envs.morphology import SETTINGS, Morphology

CONTROL_TIMESTEP = 0.02
# dm_control's easy target radius (0.07); "turn" is turn_easy, as in the pixel benchmarks.
_TURN_TARGET_RADIUS = 0.07
TASKS = ("spin", "turn")

_DISTAL_LENGTH = 0.16
# Narrower than the default 0.8..1.7: at 0.8 the whole finger falls 1 mm short of a spinner resting
# within 5 degrees of vertical, and such a start cannot be spun. At 0.85 it reaches at every angle.
MORPHOLOGY = Morphology(
    parameter="distal_length",
    default_length=_DISTAL_LENGTH,
    scales=tuple(round(0.85 + 0.075 * (setting - 1), 6) for setting in SETTINGS),
)


def model_xml(scale: float = 1.0) -> str:
    """The finger XML with its distal link ``scale`` times dm_control's length.

    The fingertip (the colliding capsule) and the two touch sensor sites move with the link's end,
    so the link's mass, inertia, reach and look all change together.

    :param scale: distal link length relative to dm_control's finger
    """
    root = read_suite_model("finger.xml")
    length = _DISTAL_LENGTH * scale
    shift = length - _DISTAL_LENGTH
    set_floats(find_named(root, "geom", "distal"), "fromto", [0, 0, 0, 0, 0, -length])
    fingertip = find_named(root, "geom", "fingertip")
    x0, y0, z0, x1, y1, z1 = get_floats(fingertip, "fromto")
    set_floats(fingertip, "fromto", [x0, y0, z0 - shift, x1, y1, z1 - shift])
    for site_name in ("touchtop", "touchbottom"):
        site = find_named(root, "site", site_name)
        x, y, z = get_floats(site, "pos")
        set_floats(site, "pos", [x, y, z - shift])
    return to_xml_string(root)


def load(task: str, scale: float = 1.0) -> control.Environment:
    """A dm_control environment of the finger with no time limit (the gymnasium env counts steps).

    :param task: ``"spin"`` or ``"turn"`` (dm_control's turn_easy)
    :param scale: distal link length relative to dm_control's finger
    """
    if task not in TASKS:
        raise ValueError(f"finger task must be one of {TASKS}, got {task!r}")
    physics = dm_finger.Physics.from_xml_string(model_xml(scale), common.ASSETS)
    return control.Environment(physics, task_of(task), time_limit=float("inf"), control_timestep=CONTROL_TIMESTEP)


def task_of(task: str) -> dm_finger.Spin | dm_finger.Turn:
    """dm_control's task object of ``"spin"`` or ``"turn"`` (turn_easy)."""
    return dm_finger.Spin() if task == "spin" else dm_finger.Turn(target_radius=_TURN_TARGET_RADIUS)
