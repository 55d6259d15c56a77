"""DMC-GB2 (Almuzairee, Hansen & Christensen, RLC 2024; github.com/aalmuzairee/dmcgb2, MIT): twelve test
distributions of an agent trained on the undistracted task, six geometric and six photometric.

Facts taken from its code:

- Geometric modes turn the camera's frame, for the render only. ``rotate``: about the viewing axis by one of
  100 evenly spaced angles in [-180, 180) degrees (``easy``: [-90, 90)). ``shift``: about the camera's vertical
  and horizontal axes (a pan by ``a``, a tilt by ``b``: R = R_y(a) R_x(b)) along the border of a rectangle of
  100 points, 25 per side, from (min a, min b) through (max a, min b), (max a, max b), (min a, max b); the
  rectangle per domain is in :data:`SHIFT_LIMITS`, divided by 1.5 in ``easy``. ``rotate_shift`` applies the
  shift, then the rotation. Each list is shuffled once with the seed and walked one pose per episode.
- Photometric modes: ``color`` takes DMC-GB's colour sets (:mod:`sgfd_envs.benchmarks.dmcgb`) in order, from
  an index drawn with the seed, one per episode; ``video`` shows DMC-GB's clips (``easy``: its 10, ``hard``:
  its 100) on a box screen behind the robot (:data:`PROJECTORS`; it follows the torso of walker and cheetah),
  the next clip each episode from the same drawn index, one frame per agent step; ``video_hard`` also makes
  the floor invisible (grid alpha 0); ``color_video`` does both (the floor stays).
- ``distracting_cs``: its DCS test, DMC-GB's ``distracting_cs`` code at the same eight intensities
  (:func:`sgfd_envs.benchmarks.dmcgb.distracting_cs`), on these tasks at action repeat 2; its Pillow (10.2) resizes
  DAVIS's frames to the sky bicubically.
- Action repeat 2 for every task, 84x84 frames, 100 test episodes at the end of training.

The screen is a site with a cube texture whose faces all show the frame, as in DMC-GB2; MuJoCo draws it.
The frame is resized (bicubic, as DMC-GB2's Pillow) to DMC-GB2's 256 x 256, then averaged down to the finest mip
level the observation reads (128 x 128 at 84 px: :func:`projector_texture`); with ``render="fast"`` the resize is to
``min(256, 2 * image_size)`` by area.
"""

from __future__ import annotations

import importlib
import xml.etree.ElementTree as ET
from pathlib import Path
from typing import Any

import cv2
import mujoco
import numpy as np
from dm_control.mujoco import Physics
from dm_control.rl import control
from dm_control.utils import transformations

from sgfd_envs import domains
from sgfd_envs.benchmarks import facts
from sgfd_envs.benchmarks.dmcgb import SceneColours
from sgfd_envs.benchmarks.media import ClipBank, colour_set, dmcgb_clips
from sgfd_envs.benchmarks.scene import TextureSlot, VideoTexture, camera_frame_override, video_texture
from sgfd_envs.domains.suite_xml import find_child
from sgfd_envs.rendering import CameraRenderer

# The facts the id table reads (benchmarks/facts.py, import-light), under this module's names.
NAME, MODES, TASKS = facts.DMCGB2, facts.DMCGB2_MODES, facts.DMCGB2_TASKS
GEOMETRIC_MODES, PHOTOMETRIC_MODES = facts.GEOMETRIC_MODES, facts.PHOTOMETRIC_MODES
# How DMC-GB2's Pillow resizes a DAVIS frame or a clip frame (its default filter, bicubic), in OpenCV.
RESIZE = cv2.INTER_CUBIC
POSES = 100
ROTATION_LIMIT = {"easy": 90.0, "hard": 180.0}
# Degrees: (max a, min a, max b, min b) of the shift rectangle, hard; easy divides them by EASY_SHIFT_DIVISOR.
SHIFT_LIMITS = {
    "walker": (10.0, -10.0, 10.0, -10.0),
    "cheetah": (10.0, -10.0, 10.0, -10.0),
    "cartpole": (8.0, -8.0, 10.0, -10.0),
    "finger": (6.0, -6.0, 12.0, -6.0),
    "ball_in_cup": (6.0, -6.0, 12.0, -6.0),
}
EASY_SHIFT_DIVISOR = 1.5
# The video screen per domain: a box site (half-sizes, position, euler angles in degrees).
PROJECTORS = {
    "walker": ((1.86, 0.1, 1.86), (0.0, 1.96, -0.7), (-30.0, 0.0, 0.0)),
    "cheetah": ((1.86, 0.1, 1.86), (0.0, 1.6, -0.7), (0.0, 0.0, 0.0)),
    "cartpole": ((1.86, 0.1, 1.86), (0.0, 0.5, 1.0), (0.0, 0.0, 0.0)),
    "ball_in_cup": ((0.66, 0.1, 0.66), (0.0, 0.5, 0.05), (-27.0, 0.0, 0.0)),
    "finger": ((0.66, 0.1, 0.66), (0.0, 0.5, 0.05), (-27.0, 0.0, 0.0)),
}
# Walker and cheetah move: the screen's x and z follow the torso's subtree centre of mass, plus these offsets.
PROJECTOR_FOLLOWS = {"walker": (0.0, -1.07), "cheetah": (-0.05, 0.15)}
PROJECTOR_TEXTURE_SIDE = 256
# The screen's texture is minified at every pixel of an H px frame while its side is at least this many H, in every
# domain's view of its screen (at 84 px the 128 px texture gives the 256 px one's frame, the 64 px one does not).
PROJECTOR_TEXELS_PER_PIXEL = 1.5
_PROJECTOR = "video_screen"


def split_mode(mode: str) -> tuple[set[str], str]:
    """The parts of a mode (``rotate``, ``shift``, ``color``, ``video``) and its difficulty.

    :param mode: one of :data:`MODES` other than ``"train"``
    """
    if mode not in MODES[1:]:
        raise ValueError(f"mode must be one of {MODES[1:]}, got {mode!r}")
    *parts, difficulty = mode.split("_")
    return set(parts), difficulty


def rotation_angles(difficulty: str) -> np.ndarray:
    """The 100 roll angles (degrees) of ``rotate_<difficulty>``, in order before the shuffle."""
    limit = ROTATION_LIMIT[difficulty]
    return -limit + np.arange(POSES) * (2 * limit / POSES)


def shift_angles(domain: str, difficulty: str) -> np.ndarray:
    """The 100 (pan, tilt) pairs (degrees) of ``shift_<difficulty>`` on the rectangle's border, in order."""
    max_a, min_a, max_b, min_b = np.array(SHIFT_LIMITS[domain]) / (EASY_SHIFT_DIVISOR if difficulty == "easy" else 1)
    corners = np.array([[min_a, min_b], [max_a, min_b], [max_a, max_b], [min_a, max_b]])
    per_side = POSES // 4
    steps = np.arange(per_side)[:, np.newaxis] / per_side
    return np.concatenate([corners[i] + steps * (corners[(i + 1) % 4] - corners[i]) for i in range(4)])


def projector_texture(image_size: int, render: str = "benchmark") -> VideoTexture:
    """How a clip frame becomes the screen's texture: resized whole (bicubic) to DMC-GB2's 256 x 256 (with
    ``render="fast"`` to twice the observation's side, by area), then halved to the finest mip level an
    observation of ``image_size`` reads (128 at 84 px).

    :param image_size: observation height and width
    :param render: one of :data:`sgfd_envs.rendering.RENDER_MODES`
    """
    return video_texture(PROJECTOR_TEXTURE_SIDE, RESIZE, image_size, render, PROJECTOR_TEXELS_PER_PIXEL)


def projector_texture_side(image_size: int, render: str = "benchmark") -> int:
    """Side of the screen's texture (:func:`projector_texture`)."""
    return projector_texture(image_size, render).side


def load_with_projector(domain: str, task: str, texture_side: int) -> control.Environment:
    """dm_control's task whose model also holds DMC-GB2's video screen: a box site with its own cube texture.
    A site has no mass and never collides: the physics is dm_control's.

    :param domain: a domain of :data:`PROJECTORS`
    :param task: its task
    :param texture_side: side of the screen's texture in pixels
    """
    dm_env = domains.load_suite(domain, task)
    xml, assets = importlib.import_module(f"dm_control.suite.{domain}").get_model_and_assets()
    root = ET.fromstring(xml)
    asset = root.find("asset")
    if asset is None:
        asset = ET.SubElement(root, "asset")
    side = str(texture_side)
    ET.SubElement(
        asset, "texture", name=_PROJECTOR, type="skybox", builtin="flat", width=side, height=side, mark="none"
    )
    ET.SubElement(
        asset, "material", name=_PROJECTOR, texture=_PROJECTOR, texuniform="false",
        specular="0", shininess="0", reflectance="0", emission="0",
    )  # fmt: skip
    size, pos, euler = PROJECTORS[domain]
    ET.SubElement(
        find_child(root, "worldbody"), "site", name=_PROJECTOR, type="box", material=_PROJECTOR,
        size=" ".join(map(str, size)), pos=" ".join(map(str, pos)), euler=" ".join(map(str, euler)),
    )  # fmt: skip
    # As sgfd_envs.domains.cheetah does: MuJoCo deprecates <compiler settotalmass> (a warning at every
    # compile); rescaling the compiled model gives the same model arrays.
    compiler = root.find("compiler")
    total_mass = None if compiler is None else compiler.attrib.pop("settotalmass", None)
    physics = dm_env.physics
    physics.reload_from_xml_string(ET.tostring(root, encoding="unicode"), assets)
    if total_mass is not None:
        mujoco.mj_setTotalmass(physics.model.ptr, float(total_mass))
        mujoco.mj_setConst(physics.model.ptr, physics.data.ptr)
    return dm_env


class DMCGB2Distraction:
    """One DMC-GB2 test mode on one env's physics (see the module docstring).

    :param physics: the env's physics (for video modes, from :func:`load_with_projector`)
    :param domain: the dm_control domain
    :param mode: one of :data:`MODES` other than ``"train"``
    :param image_size: observation height and width
    :param data_dir: DMC-GB's (or DMC-GB2's ``envs/dmcgb``) data folder, or None for the procedural stand-ins
    :param render: ``"benchmark"`` or ``"fast"``: the screen texture's side and resize (module docstring)
    """

    # The env's parameters, then the mode's.
    def __init__(
        self, physics: Physics, domain: str,
        mode: str, image_size: int, data_dir: str | Path | None, render: str = "benchmark",
    ) -> None:  # fmt: skip
        parts, difficulty = split_mode(mode)
        self.mode = mode
        self._physics = physics
        self._domain = domain
        self._rotations = None
        if "rotate" in parts:
            self._rotations = [transformations.rotation_z_axis(np.radians(a)) for a in rotation_angles(difficulty)]
        self._shifts = None
        if "shift" in parts:
            self._shifts = [
                transformations.rotation_y_axis(np.radians(a)) @ transformations.rotation_x_axis(np.radians(b))
                for a, b in shift_angles(domain, difficulty)
            ]
        self._scene_colours = SceneColours(physics, colour_set(difficulty, data_dir)) if "color" in parts else None
        self._clips: ClipBank | None = None
        if "video" in parts:
            texture = projector_texture(image_size, render)
            self._clips = dmcgb_clips(
                f"video_{difficulty}", texture.resize_side, data_dir, texture.interpolation, texture.halvings
            )
            self._screen = TextureSlot(physics, _PROJECTOR)
            self._screen_side = texture.side
            self._screen_site = physics.model.name2id(_PROJECTOR, "site")
            if mode == "video_hard":
                physics.model.mat_rgba[physics.model.name2id("grid", "material"), 3] = 0.0
        self._order = np.arange(POSES)
        self._start = 0
        self._episodes_since_seed = 0
        self.camera_rotation = np.eye(3)
        self.pose_index: int | None = None
        self.colour_index: int | None = None
        self.clip_index: int | None = None
        self._shown_frame: tuple[int, int] | None = None

    def start_episode(self, rng: np.random.Generator, reseeded: bool) -> None:
        if reseeded:
            self._order = rng.permutation(POSES)
            self._start = int(rng.integers(POSES))
            self._episodes_since_seed = 0
        episode = self._episodes_since_seed
        self._episodes_since_seed += 1
        self.pose_index = int(self._order[episode % POSES])
        self.camera_rotation = np.eye(3)
        if self._shifts is not None:
            self.camera_rotation = self.camera_rotation @ self._shifts[self.pose_index]
        if self._rotations is not None:
            self.camera_rotation = self.camera_rotation @ self._rotations[self.pose_index]
        if self._scene_colours is not None:
            self.colour_index = (self._start + episode) % len(self._scene_colours)
            self._scene_colours.apply(self.colour_index)
        if self._clips is not None:
            self.clip_index = (self._start + episode + 1) % len(self._clips)

    def control_step(self) -> None:
        pass

    def get_state(self) -> dict[str, Any]:
        """The pose order and start drawn at seeding, the episode count since, and the episode's pose, colour
        entry and clip."""
        return {
            "order": self._order.copy(),
            "start": self._start,
            "episodes_since_seed": self._episodes_since_seed,
            "camera_rotation": self.camera_rotation.copy(),
            "pose_index": self.pose_index,
            "colour_index": self.colour_index,
            "clip_index": self.clip_index,
        }

    def set_state(self, state: dict[str, Any]) -> None:
        """Continue from ``get_state``'s state, on a distraction made with the same arguments."""
        self._order = np.array(state["order"])
        self._start, self._episodes_since_seed = state["start"], state["episodes_since_seed"]
        self.camera_rotation = np.array(state["camera_rotation"])
        self.pose_index, self.colour_index = state["pose_index"], state["colour_index"]
        self.clip_index = state["clip_index"]
        if self._scene_colours is not None and self.colour_index is not None:
            self._scene_colours.apply(self.colour_index)
        self._shown_frame = None  # the screen texture is written again at the next render

    def screen_position(self) -> np.ndarray | None:
        """Where the video screen is drawn now (None without a video): its compiled place, or for walker and
        cheetah moved with the torso's centre of mass."""
        if self._clips is None:
            return None
        data = self._physics.data
        position = data.site_xpos[self._screen_site].copy()
        follow = PROJECTOR_FOLLOWS.get(self._domain)
        if follow is not None:
            torso = data.subtree_com[self._physics.model.name2id("torso", "body")]
            position[0] = torso[0] + follow[0]
            position[2] = torso[2] + follow[1]
        return position

    def render(self, renderer: CameraRenderer, agent_step: int) -> np.ndarray:
        overrides = []
        if self._rotations is not None or self._shifts is not None:
            overrides += camera_frame_override(self._physics, renderer.camera_id, self.camera_rotation)
        if self._scene_colours is not None:
            self._scene_colours.upload(renderer)
        if self._clips is not None:
            assert self.clip_index is not None  # start_episode drew the episode's clip
            if self._shown_frame != (self.clip_index, agent_step):
                side = self._screen_side
                self._screen.write(self._clips.clip(self.clip_index).frame(agent_step), (side, side))
                self._shown_frame = (self.clip_index, agent_step)
            self._screen.upload_if_changed(renderer)
            overrides.append((self._physics.data.site_xpos, self._screen_site, self.screen_position()))
        return renderer.render(overrides)
