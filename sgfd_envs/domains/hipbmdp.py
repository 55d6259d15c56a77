"""HiP-BMDP's robot files, which the SGFD authors' code rendered for both of the paper's tables, built from
dm_control's own model files.

mtenv's ``local_dm_control_suite/`` (facebookresearch/mtenv; the SGFD repository holds the same files) is a copy
of dm_control's suite whose robot files differ from dm_control's in their included assets and one number each:

- ``walker_len_N``: the left foot capsule's half-length 0.07 + 0.01 N m (file 3 is dm_control's walker);
- ``cheetah_torso_length_N``: the torso capsule from -(0.4 + 0.1 N) to 0.4 + 0.1 N m along x (file 1 is
  dm_control's cheetah; the head and the thighs stay where they are);
- ``finger_size_N``: the ``finger`` default class's site size x = 0.025 N (file 1 is dm_control's finger); its
  sites are the touch sensors', in group 3, which no camera draws.

The walker and cheetah files include ``materials_white_floor.xml`` (a grey floor checker: rgb1 .1 .1 .1, rgb2
.2 .2 .2, edge marks .1 .1 .1), the finger files the local ``materials.xml`` (a strong blue checker: .1 .1 .4,
.2 .2 .8, edge marks .1 .1 .4, and the ``decoration`` material orange .7 .5 .3 where dm_control's is blue
.3 .5 .7), and all of them the local ``skybox.xml``, whose random marks are black (dm_control's: white). Every
other line of these files and of the tasks' code equals dm_control's (dm_control 1.0.50), so each file is built
here as dm_control's file with these edits, and its task is dm_control's.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from collections.abc import Callable

from dm_control.rl import control
from dm_control.suite import common
from dm_control.suite import finger as dm_finger
from dm_control.suite import walker as dm_walker

from sgfd_envs.domains import cheetah, finger, walker
from sgfd_envs.domains.suite_xml import find_named, get_floats, read_suite_model, set_floats, to_xml_string
from sgfd_envs.morphology import HIPBMDP_FILES, check_setting

_MATERIALS = "./common/materials.xml"
_WHITE_FLOOR = "./common/materials_white_floor.xml"
_SKYBOX = "./common/skybox.xml"
# The floor checker of each local materials file: (rgb1, rgb2, markrgb).
_FLOOR_COLOURS = {_MATERIALS: (".1 .1 .4", ".2 .2 .8", ".1 .1 .4"), _WHITE_FLOOR: (".1 .1 .1", ".2 .2 .2", ".1 .1 .1")}
# The local materials.xml's decoration (the finger's hub and the spinner's axle): dm_control's is ".3 .5 .7 1".
_ORANGE_DECORATION = ".7 .5 .3 1"
# Which materials file each robot's files include.
_MATERIALS_OF = {"walker": _WHITE_FLOOR, "cheetah": _WHITE_FLOOR, "finger": _MATERIALS}
TASKS = {"walker": walker.TASKS, "cheetah": cheetah.TASKS, "finger": finger.TASKS}


def _asset(name: str, edit: Callable[[ET.Element], None]) -> bytes:
    """dm_control's common asset ``name`` with ``edit`` applied to its tree."""
    root = ET.fromstring(common.ASSETS[name])
    edit(root)
    return ET.tostring(root)


def _local_materials(file_name: str) -> Callable[[ET.Element], None]:
    def edit(root: ET.Element) -> None:
        rgb1, rgb2, mark = _FLOOR_COLOURS[file_name]
        grid = find_named(root, "texture", "grid")
        grid.set("rgb1", rgb1)
        grid.set("rgb2", rgb2)
        grid.set("markrgb", mark)
        if file_name == _MATERIALS:
            find_named(root, "material", "decoration").set("rgba", _ORANGE_DECORATION)

    return edit


def _black_marks(root: ET.Element) -> None:
    find_named(root, "texture", "skybox").set("markrgb", "0 0 0")


def local_assets() -> dict[str, bytes]:
    """The files the local robot files include: dm_control's ``visual.xml``, and the local ``materials.xml``,
    ``materials_white_floor.xml`` and ``skybox.xml``."""
    return {
        "./common/visual.xml": common.ASSETS["./common/visual.xml"],
        _SKYBOX: _asset(_SKYBOX, _black_marks),
        _MATERIALS: _asset(_MATERIALS, _local_materials(_MATERIALS)),
        _WHITE_FLOOR: _asset(_MATERIALS, _local_materials(_WHITE_FLOOR)),
    }


def _edit_file(robot: str, root: ET.Element, setting: int) -> None:
    """The one number file ``setting`` of ``robot`` changes."""
    value = HIPBMDP_FILES[robot].value(setting)
    if robot == "walker":
        foot = find_named(root, "geom", "left_foot")
        set_floats(foot, "size", [get_floats(foot, "size")[0], value])
    elif robot == "cheetah":
        half = value / 2
        set_floats(find_named(root, "geom", "torso"), "fromto", [-half, 0, 0, half, 0, 0])
    else:
        site = root.find(".//default[@class='finger']/site")
        if site is None:
            raise KeyError("expected a <site> in the finger model's default class 'finger', found none")
        set_floats(site, "size", [value, *get_floats(site, "size")[1:]])


def robot_tree(robot: str, setting: int) -> ET.Element:
    """HiP-BMDP's file ``setting`` of ``robot`` (``walker_len_N``, ``cheetah_torso_length_N``, ``finger_size_N``)
    as a model tree whose includes name :func:`local_assets`' files.

    :param robot: ``"walker"``, ``"cheetah"`` or ``"finger"``
    :param setting: the file's number N, 1..10
    """
    if robot not in HIPBMDP_FILES:
        raise ValueError(f"robot must be one of {tuple(HIPBMDP_FILES)}, got {robot!r}")
    root = read_suite_model(f"{robot}.xml")
    include = root.find(f"include[@file='{_MATERIALS}']")
    if include is None:
        raise KeyError(f"expected <include file={_MATERIALS!r}> in dm_control's {robot}.xml")
    include.set("file", _MATERIALS_OF[robot])
    _edit_file(robot, root, check_setting(setting))
    return root


def model_xml(robot: str, setting: int) -> str:
    """:func:`robot_tree` as the XML text of a model file."""
    return to_xml_string(robot_tree(robot, setting))


def load(robot: str, task: str, setting: int) -> control.Environment:
    """dm_control's task on HiP-BMDP's robot file ``setting``, with no time limit (the gymnasium env counts steps).

    :param robot: ``"walker"``, ``"cheetah"`` or ``"finger"``
    :param task: a task of that robot (``"walk"``, ``"run"``, ``"spin"``, ``"turn"``: dm_control's turn_easy)
    :param setting: the file's number N, 1..10
    """
    if robot in TASKS and task not in TASKS[robot]:
        raise ValueError(f"{robot} task must be one of {TASKS[robot]}, got {task!r}")
    root, assets = robot_tree(robot, setting), local_assets()
    if robot == "cheetah":
        return cheetah.environment(cheetah.compile_model(root, assets))
    if robot == "walker":
        physics = dm_walker.Physics.from_xml_string(to_xml_string(root), assets)
        move = dm_walker.PlanarWalker(move_speed=walker.MOVE_SPEEDS[task])
        return control.Environment(physics, move, time_limit=float("inf"), control_timestep=walker.CONTROL_TIMESTEP)
    physics = dm_finger.Physics.from_xml_string(to_xml_string(root), assets)
    spin_or_turn = finger.task_of(task)
    return control.Environment(physics, spin_or_turn, time_limit=float("inf"), control_timestep=finger.CONTROL_TIMESTEP)
