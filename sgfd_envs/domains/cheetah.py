"""Half-cheetah: dm_control's cheetah with a scalable torso length (run task)."""

from __future__ import annotations

import xml.etree.ElementTree as ET

import mujoco
from dm_control.rl import control
from dm_control.suite import cheetah as dm_cheetah
from dm_control.suite import common

from sgfd_envs.domains.suite_xml import find_child, find_named, get_floats, read_suite_model, set_floats, to_xml_string
from sgfd_envs.morphology import Morphology

# dm_control's cheetah has no control_timestep: one agent action per 0.01 s physics step.
CONTROL_TIMESTEP = 0.01
TASKS = ("run",)

_TORSO_HALF_LENGTH = 0.5
MORPHOLOGY = Morphology(parameter="torso_length", default_length=2 * _TORSO_HALF_LENGTH)


def _scaled_model(scale: float) -> ET.Element:
    root = read_suite_model("cheetah.xml")
    half_length = _TORSO_HALF_LENGTH * scale
    set_floats(find_named(root, "geom", "torso"), "fromto", [-half_length, 0, 0, half_length, 0, 0])
    head = find_named(root, "geom", "head")
    x, y, z = get_floats(head, "pos")
    set_floats(head, "pos", [x - _TORSO_HALF_LENGTH + half_length, y, z])
    for thigh_name, side in (("bthigh", -1.0), ("fthigh", 1.0)):
        thigh = find_named(root, "body", thigh_name)
        _, y, z = get_floats(thigh, "pos")
        set_floats(thigh, "pos", [side * half_length, y, z])
    return root


def model_xml(scale: float = 1.0) -> str:
    """The cheetah XML with its torso ``scale`` times dm_control's length.

    Thighs and head move with the torso's ends. dm_control rescales the whole body to 14 kg
    (``settotalmass``), so a longer torso takes mass and inertia from the legs.

    :param scale: torso length relative to dm_control's cheetah
    """
    return to_xml_string(_scaled_model(scale))


def load(task: str, scale: float = 1.0) -> control.Environment:
    """A dm_control environment of the cheetah with no time limit (the gymnasium env counts steps).

    :param task: ``"run"``
    :param scale: torso length relative to dm_control's cheetah
    """
    if task not in TASKS:
        raise ValueError(f"cheetah task must be one of {TASKS}, got {task!r}")
    return environment(compile_model(_scaled_model(scale), common.ASSETS))


def compile_model(root: ET.Element, assets: dict[str, bytes]) -> dm_cheetah.Physics:
    """A cheetah model tree compiled as MuJoCo compiles it with its ``<compiler settotalmass>``.

    MuJoCo deprecates ``settotalmass`` and logs a warning at every compile; rescaling the compiled model instead
    gives the same model arrays (tested against dm_control's cheetah).

    :param root: the model tree (its ``settotalmass`` is taken out of it)
    :param assets: the files its includes name
    """
    total_mass = float(find_child(root, "compiler").attrib.pop("settotalmass"))
    physics = dm_cheetah.Physics.from_xml_string(to_xml_string(root), assets)
    mujoco.mj_setTotalmass(physics.model.ptr, total_mass)
    mujoco.mj_setConst(physics.model.ptr, physics.data.ptr)
    return physics


def environment(physics: dm_cheetah.Physics) -> control.Environment:
    """dm_control's run task on ``physics``, with no time limit (the gymnasium env counts steps)."""
    return control.Environment(
        physics, dm_cheetah.Cheetah(), time_limit=float("inf"), control_timestep=CONTROL_TIMESTEP
    )
