"""The Distracting Control Suite (Stone, Ramirez, Konolige & Jonschkowski, 2021;
github.com/google-research/google-research/tree/master/distracting_control, Apache-2.0): background, camera
and colour distractions at a difficulty scale s (easy 0.1, medium 0.2, hard 0.3), each static or dynamic.

Facts taken from its code (``suite_utils.py``, ``background.py``, ``camera.py``, ``color.py``):

- Background: the skybox texture shows a DAVIS 2017 video (one square image on every face); easy uses the first
  4 videos of the list, medium 8, hard all (60 ``train``, 30 ``validation``). Each episode draws a video, a
  start frame and a direction; static shows one random frame, dynamic moves one frame per simulator step and
  turns back at either end. The floor's alpha becomes 0 for reacher, stays 1 for walker and cheetah and is 0.3
  for the others.
- Camera: each episode draws a position on a sphere around the start (radius, azimuth and elevation within
  +-pi/2 s of the start, radius between (1 - 0.5 s) and (1 + 1.5 s) times the start's; above the ground and on
  the start's side unless the domain is reacher) and a roll within +-pi/2 s, then looks at the robot. Dynamic:
  a velocity of norm up to 0.4 s (scaled by radius / 4) random-walks with std 0.1 s per simulator step, the roll
  velocity (up to pi/50 s) with std pi/300 s.
- Colour: every material's RGB is drawn uniformly within +-s of dm_control's (clipped to [0, 1]) each episode;
  dynamic adds Gaussian steps of std 0.03 s per simulator step, clipped to that range.

The distractions draw from generators seeded with the env's seed (DCS leaves them unseeded). Each DAVIS frame is
resized whole to DCS's 800 x 800 sky texture (bilinear, as DCS's ``tf.image.resize``), then averaged down to the
finest mip level the observation reads (400 x 400 at 84 px: :func:`sky_texture`); frames are taken in file-name
order. Each frame is sent to the GPU at its first view in the episode's video, into a texture of its own, and drawn
at later views by switching the sky's texture by name (DCS sends the sky at every simulator step); the video's
frames stay on the GPU until the next video's first frame, up to ``texture_cache_mb``
(:class:`~sgfd_envs.benchmarks.scene.FrameTextures`). The walks move at every simulator step and touch the model
only for a render (colours, camera pose, sky). With ``render="fast"`` the resize is to ``min(800, 2 * image_size)``
by area.

DMC-GB's ``distracting_cs`` mode (and DMC-GB2's DCS test) is this suite at another scale with other video counts,
always dynamic, its walks moved every second simulator step (:data:`sgfd_envs.benchmarks.dmcgb.DISTRACTING_CS_VIDEOS`);
:class:`DCSDistraction` takes those as arguments.
"""

from __future__ import annotations

import copy
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import cv2
import mujoco
import numpy as np
from dm_control.mujoco import Physics
from dm_control.utils import transformations

from sgfd_envs.benchmarks import facts
from sgfd_envs.benchmarks.media import ClipBank, davis_clips
from sgfd_envs.benchmarks.scene import (
    DEFAULT_TEXTURE_CACHE_MB,
    FrameTextures,
    TextureSlot,
    VideoTexture,
    check_texture_cache_mb,
    video_texture,
)
from sgfd_envs.rendering import CameraRenderer

# The facts the id table reads (benchmarks/facts.py, import-light), under this module's names.
NAME, SPLITS, TASKS = facts.DCS, facts.DCS_SPLITS, facts.DCS_TASKS
DIFFICULTY_SCALE, DIFFICULTY_VIDEOS, DIFFICULTIES = facts.DIFFICULTY_SCALE, facts.DIFFICULTY_VIDEOS, facts.DIFFICULTIES
DISTRACTIONS, VIDEO_SPLITS, check_distractions = facts.DISTRACTIONS, facts.VIDEO_SPLITS, facts.check_distractions
# The DAVIS 2017 video names of DCS's train and validation lists, in its order (the easy and medium
# difficulties take the first 4 and 8).
DAVIS_VIDEOS = {
    "train": (
        "bear", "bmx-bumps", "boat", "boxing-fisheye", "breakdance-flare", "bus", "car-turn", "cat-girl",
        "classic-car", "color-run", "crossing", "dance-jump", "dancing", "disc-jockey", "dog-agility", "dog-gooses",
        "dogs-scale", "drift-turn", "drone", "elephant", "flamingo", "hike", "hockey", "horsejump-low",
        "kid-football", "kite-walk", "koala", "lady-running", "lindy-hop", "longboard", "lucia", "mallard-fly",
        "mallard-water", "miami-surf", "motocross-bumps", "motorbike", "night-race", "paragliding", "planes-water",
        "rallye", "rhino", "rollerblade", "schoolgirls", "scooter-board", "scooter-gray", "sheep", "skate-park",
        "snowboard", "soccerball", "stroller", "stunt", "surf", "swing", "tennis", "tractor-sand", "train",
        "tuk-tuk", "upside-down", "varanus-cage", "walking",
    ),
    "validation": (
        "bike-packing", "blackswan", "bmx-trees", "breakdance", "camel", "car-roundabout", "car-shadow", "cows",
        "dance-twirl", "dog", "dogs-jump", "drift-chicane", "drift-straight", "goat", "gold-fish", "horsejump-high",
        "india", "judo", "kite-surf", "lab-coat", "libby", "loading", "mbike-trick", "motocross-jump",
        "paragliding-launch", "parkour", "pigs", "scooter-black", "shooting", "soapbox",
    ),
}  # fmt: skip
GROUND_ALPHA = {"reacher": 0.0, "walker": 1.0, "cheetah": 1.0}
DEFAULT_GROUND_ALPHA = 0.3
SKY_TEXTURE_SIDE = 800
# How DCS resizes a DAVIS frame to the sky texture (tf.image.resize, bilinear), in OpenCV.
RESIZE = cv2.INTER_LINEAR
# A sky texture of side S is minified at every pixel of an H px frame while S >= 3.24 H at dm_control's 45-degree
# field of view (a pixel at the frame's corner spans the least angle, a texel at a face's centre the most); 4 H
# leaves a margin. Halved that far, the texture gives the frame the 800 px sky's mip levels (see VideoTexture).
SKY_TEXELS_PER_PIXEL = 4.0
# Most environments start their camera 4 m away; the camera's velocities scale with start radius / 4.
_REFERENCE_RADIUS = 4.0


def sky_texture(image_size: int, render: str = "benchmark", interpolation: int = RESIZE) -> VideoTexture:
    """How a video frame becomes the sky texture: resized whole to DCS's 800 x 800 with ``interpolation`` (with
    ``render="fast"`` to twice the observation's side, by area), then halved to the finest mip level an
    observation of ``image_size`` reads (400 at 84 px).

    :param image_size: observation height and width
    :param render: one of :data:`sgfd_envs.rendering.RENDER_MODES`
    :param interpolation: OpenCV's closest to the benchmark's resize of a DAVIS frame
    """
    return video_texture(SKY_TEXTURE_SIDE, interpolation, image_size, render, SKY_TEXELS_PER_PIXEL)


def sky_texture_side(image_size: int, render: str = "benchmark") -> int:
    """Side of the sky texture the video is written to (:func:`sky_texture`)."""
    return sky_texture(image_size, render).side


# --- camera ----------------------------------------------------------------------------------------------


def to_spherical(point: np.ndarray) -> np.ndarray:
    """(radius, azimuth, polar angle from +z) of a point."""
    radius = float(np.linalg.norm(point))
    return np.array([radius, np.arctan2(point[1], point[0]), np.arctan2(np.linalg.norm(point[:2]), point[2])])


def to_cartesian(spherical: np.ndarray) -> np.ndarray:
    """The point of (radius, azimuth, polar angle)."""
    radius, azimuth, polar = spherical
    return radius * np.array([np.sin(polar) * np.cos(azimuth), np.sin(polar) * np.sin(azimuth), np.cos(polar)])


def look_at_without_roll(target: np.ndarray, position: np.ndarray) -> np.ndarray:
    """Camera orientation at ``position`` looking at ``target`` with a level horizon (yaw, then pitch)."""
    direction = (target - position) / np.linalg.norm(target - position)
    yaw = np.arctan2(direction[0], direction[1])
    # A camera with identity orientation looks down (-z); pitching it by 90 degrees makes it look level.
    pitch = np.arctan2(direction[2], np.linalg.norm(direction[:2])) + np.pi / 2
    return transformations.rotation_z_axis(-yaw) @ transformations.rotation_x_axis(pitch)


def look_at_shortest_arc(target: np.ndarray, position: np.ndarray) -> np.ndarray:
    """Camera orientation at ``position`` looking at ``target``: the shortest rotation taking the camera's
    viewing direction (-z) onto the target's (some roll; no flip at the poles, which matters for reacher)."""
    direction = (target - position) / np.linalg.norm(target - position)
    down = np.array([0.0, 0.0, -1.0])
    axis = np.cross(down, direction)
    sin_angle = float(np.linalg.norm(axis))
    cos_angle = float(direction @ down)
    axis = axis / (sin_angle + 1e-4)
    cross = np.array([[0.0, -axis[2], axis[1]], [axis[2], 0.0, -axis[0]], [-axis[1], axis[0], 0.0]])
    return cos_angle * np.eye(3) + sin_angle * cross + (1 - cos_angle) * np.outer(axis, axis)


class CameraWalk:
    """DCS's camera distraction of camera ``camera_id``: a pose on a sphere around its start, random each episode,
    random-walking in dynamic mode; rendered through overrides, so the simulation never sees it.

    :param physics: the env's physics
    :param camera_id: the rendered camera (fixed, or tracking the robot's centre of mass)
    :param scale: difficulty scale s
    :param dynamic: whether the pose moves during the episode
    :param upper_quadrant: keep the camera above the ground and on the start's side (all domains but reacher)
    """

    def __init__(self, physics: Physics, camera_id: int, scale: float, dynamic: bool, upper_quadrant: bool) -> None:
        mode = int(physics.model.cam_mode[camera_id])
        fixed, tracking = int(mujoco.mjtCamLight.mjCAMLIGHT_FIXED), int(mujoco.mjtCamLight.mjCAMLIGHT_TRACKCOM)
        if mode not in (fixed, tracking):
            raise ValueError(
                f"the camera distraction needs a fixed or trackcom camera, camera {camera_id} has mode {mode}"
            )
        self._physics = physics
        self._camera_id = camera_id
        self._tracking = mode == tracking
        self.angle_delta = np.pi / 2 * scale
        self.roll_delta = np.pi / 2 * scale
        self.max_velocity = 0.4 * scale if dynamic else 0.0
        self.velocity_std = 0.1 * scale if dynamic else 0.0
        self.max_roll_velocity = np.pi / 50 * scale if dynamic else 0.0
        self.roll_velocity_std = np.pi / 300 * scale if dynamic else 0.0
        self.zoom_in = 0.5 * scale
        self.zoom_out = 1.5 * scale
        self.upper_quadrant = upper_quadrant

    def _look_at_point(self) -> np.ndarray:
        """A point straight ahead of the (unmoved) camera, as far as the robot's centre of mass."""
        data = self._physics.data
        position = data.cam_xpos[self._camera_id]
        distance = np.linalg.norm(position - data.subtree_com[1])
        return position + data.cam_xmat[self._camera_id].reshape(3, 3) @ np.array([0.0, 0.0, -distance])

    def start(self, rng: np.random.Generator) -> None:
        """Set the ranges from the camera's pose at the episode's start and draw a pose and velocities."""
        data = self._physics.data
        self._initial_target = self._look_at_point()
        start = data.cam_xpos[self._camera_id].copy()
        if self._tracking:
            start -= data.subtree_com[1]
        radius, azimuth, polar = to_spherical(start)
        self.velocity_scale = radius / _REFERENCE_RADIUS
        low = np.array([max(radius * (1 - self.zoom_in), 0.0), azimuth - self.angle_delta, polar - self.angle_delta])
        high = np.array([radius * (1 + self.zoom_out), azimuth + self.angle_delta, polar + self.angle_delta])
        if self.upper_quadrant:
            low[1], high[1] = max(low[1], -np.pi), min(high[1], 0.0)
            low[2], high[2] = max(low[2], 0.0), min(high[2], np.pi / 2)
        self.low, self.high = low, high
        azimuth, polar = rng.uniform(low[1], high[1]), rng.uniform(low[2], high[2])
        self.spherical = np.array([rng.uniform(low[0], high[0]), azimuth, polar])
        self.roll = rng.uniform(-self.roll_delta, self.roll_delta)
        direction = rng.standard_normal(3)
        self.velocity = direction / np.linalg.norm(direction) * rng.uniform(0.0, self.max_velocity)
        self.roll_velocity = rng.uniform(-self.max_roll_velocity, self.max_roll_velocity)
        self.advance(rng)

    def advance(self, rng: np.random.Generator) -> None:
        """One simulator step of the random walk (a static camera stays put: its velocities are 0)."""
        limit = self.max_velocity * self.velocity_scale
        self.velocity = self.velocity + rng.standard_normal(3) * self.velocity_std * self.velocity_scale
        self.roll_velocity += rng.standard_normal() * self.roll_velocity_std
        speed = np.linalg.norm(self.velocity)
        if speed > limit:
            self.velocity = self.velocity * (limit / speed)
        self.roll_velocity = float(np.clip(self.roll_velocity, -self.max_roll_velocity, self.max_roll_velocity))
        position = to_cartesian(self.spherical)
        moved = np.clip(to_spherical(position + self.velocity), self.low, self.high)
        self.velocity = to_cartesian(moved) - position
        self.spherical = moved
        roll = float(np.clip(self.roll + self.roll_velocity, -self.roll_delta, self.roll_delta))
        self.roll_velocity = roll - self.roll
        self.roll = roll

    # What start() draws and advance() moves: the episode's ranges, start target and pose, and its velocities.
    _STATE = ("_initial_target", "velocity_scale", "low", "high", "spherical", "roll", "velocity", "roll_velocity")

    def get_state(self) -> dict[str, Any]:
        """The episode's ranges and start target, the pose and its velocities (empty before the first episode)."""
        return {name: copy.deepcopy(getattr(self, name)) for name in self._STATE if hasattr(self, name)}

    def set_state(self, state: dict[str, Any]) -> None:
        """Continue from ``get_state``'s state."""
        for name, value in state.items():
            setattr(self, name, copy.deepcopy(value))

    def pose(self) -> tuple[np.ndarray, np.ndarray]:
        """The camera's world position and orientation (3x3) now."""
        position = to_cartesian(self.spherical)
        if self._tracking:
            position = position + self._physics.data.subtree_com[1]
            target = self._look_at_point()
        else:
            target = self._initial_target
        look_at = look_at_without_roll if self.upper_quadrant else look_at_shortest_arc
        return position, look_at(target, position) @ transformations.rotation_z_axis(self.roll)

    def overrides(self) -> list:
        """Renderer overrides that put the camera at :meth:`pose` for one render."""
        position, orientation = self.pose()
        data = self._physics.data
        return [(data.cam_xpos, self._camera_id, position), (data.cam_xmat, self._camera_id, orientation.reshape(-1))]


# --- colour ----------------------------------------------------------------------------------------------


class ColourWalk:
    """DCS's colour distraction: every material's RGB within +-scale of dm_control's. The walk moves its colours;
    :meth:`show` puts them on the model, at a render only (a simulator step no frame shows sets none).

    :param physics: the env's physics
    :param scale: difficulty scale s
    :param dynamic: whether the colours random-walk during the episode
    """

    def __init__(self, physics: Physics, scale: float, dynamic: bool) -> None:
        self._model = physics.model
        self.max_delta = scale
        self.step_std = 0.03 * scale if dynamic else 0.0
        self.original = self._model.mat_rgba[:, :3].copy()
        self.low = np.clip(self.original - scale, 0.0, 1.0)
        self.high = np.clip(self.original + scale, 0.0, 1.0)
        self.current = self.original.copy()

    def start(self, rng: np.random.Generator) -> None:
        self.current = self.low + rng.random(self.low.shape) * (self.high - self.low)

    def advance(self, rng: np.random.Generator) -> None:
        if self.step_std:
            step = rng.standard_normal(self.current.shape) * self.step_std
            self.current = np.clip(self.current + step, self.low, self.high)

    def show(self) -> None:
        """Put the walk's colours on the model's materials, for the next render."""
        self._model.mat_rgba[:, :3] = self.current

    def get_state(self) -> dict[str, np.ndarray]:
        return {"current": self.current.copy()}

    def set_state(self, state: dict[str, np.ndarray]) -> None:
        self.current = np.array(state["current"])


# --- background ------------------------------------------------------------------------------------------


class SkyVideo:
    """DCS's background distraction: a DAVIS video on the skybox texture, the floor made (semi-)transparent.

    :param physics: the env's physics
    :param clips: the videos of the difficulty
    :param dynamic: whether the frame moves during the episode
    :param ground_alpha: the floor's alpha
    :param texture_side: side of the square sky texture
    :param cache_bytes: GPU memory the episode's video frames may take, each sent once
        (:class:`~sgfd_envs.benchmarks.scene.FrameTextures`)
    """

    def __init__(
        self,
        physics: Physics,
        clips: ClipBank,
        dynamic: bool,
        ground_alpha: float,
        texture_side: int,
        cache_bytes: int = DEFAULT_TEXTURE_CACHE_MB << 20,
    ) -> None:
        self._physics = physics
        self._clips = clips
        self.dynamic = dynamic
        self.ground_alpha = ground_alpha
        self.texture_side = texture_side
        self._sky = TextureSlot(physics, "skybox")
        self.textures = FrameTextures(self._sky, texture_side, cache_bytes)
        self._grid = physics.model.name2id("grid", "material")
        self.video_index = 0
        self.frames: list[int] = [0]
        self.position = 0
        self.direction = 1

    def start(self, rng: np.random.Generator) -> None:
        self._physics.model.mat_rgba[self._grid, 3] = self.ground_alpha
        self.video_index = int(rng.integers(len(self._clips)))
        n_frames = self._clips.clip(self.video_index).n_frames
        self.frames = list(range(n_frames)) if self.dynamic else [int(rng.integers(n_frames))]
        self.position = int(rng.integers(len(self.frames)))
        self.direction = int(rng.choice([-1, 1]))

    def advance(self) -> None:
        if not self.dynamic:
            return
        self.position += self.direction
        if self.position <= 0:
            self.position, self.direction = 0, abs(self.direction)
        if self.position >= len(self.frames):
            self.position, self.direction = len(self.frames) - 1, -abs(self.direction)

    def get_state(self) -> dict[str, Any]:
        """The episode's video and frames, and where in them the sky is."""
        return {
            "video_index": self.video_index,
            "frames": list(self.frames),
            "position": self.position,
            "direction": self.direction,
        }

    def set_state(self, state: dict[str, Any]) -> None:
        self._physics.model.mat_rgba[self._grid, 3] = self.ground_alpha
        self.video_index, self.frames = state["video_index"], list(state["frames"])
        self.position, self.direction = state["position"], state["direction"]

    @property
    def frame_index(self) -> int:
        """The index, in its video, of the frame the sky shows."""
        return self.frames[self.position]

    def overrides(self, renderer: CameraRenderer) -> list:
        """Renderer overrides that show the sky's frame, sent to the GPU at its first view in the video."""
        clip, index = self._clips.clip(self.video_index), self.frame_index
        return self.textures.overrides(renderer, self.video_index, index, lambda: clip.frame(index))


class DCSDistraction:
    """The Distracting Control Suite at one scale on one env's physics (see the module docstring).

    :param physics: the env's physics
    :param domain: the dm_control domain
    :param scale: the difficulty scale s (DCS: easy 0.1, medium 0.2, hard 0.3; DMC-GB: its intensity)
    :param n_videos: how many videos of the list the background draws from (None: all)
    :param dynamic: whether the distractions move during an episode
    :param distractions: which of :data:`DISTRACTIONS` apply
    :param background_videos: ``"train"`` or ``"validation"``: DCS's DAVIS list
    :param image_size: observation height and width
    :param background_dir: DAVIS's ``JPEGImages/480p`` folder, or None for the procedural stand-ins
    :param camera_id: the rendered camera
    :param update_every: the walks move at every ``update_every``-th simulator step of an episode (DCS: 1,
        DMC-GB's ``distracting_cs``: 2)
    :param render: ``"benchmark"`` (frames resized to DCS's 800 x 800 with ``interpolation``) or ``"fast"`` (see
        :func:`sky_texture`)
    :param interpolation: OpenCV interpolation closest to the benchmark's resize of a DAVIS frame
    :param texture_cache_mb: GPU memory (MiB) the sky's frames of the episode's video may take, each sent to the
        GPU once; frames past it are sent at every view (0: every new frame is sent; see
        :class:`~sgfd_envs.benchmarks.scene.FrameTextures`)
    """

    def __init__(
        self,
        physics: Physics,
        domain: str,
        scale: float,
        n_videos: int | None,
        dynamic: bool,
        distractions: Sequence[str],
        background_videos: str,
        image_size: int,
        background_dir: str | Path | None,
        *,
        camera_id: int = 0,
        update_every: int = 1,
        render: str = "benchmark",
        interpolation: int = RESIZE,
        texture_cache_mb: int = DEFAULT_TEXTURE_CACHE_MB,
    ) -> None:
        if background_videos not in VIDEO_SPLITS:
            raise ValueError(f"background_videos must be one of {VIDEO_SPLITS}, got {background_videos!r}")
        if not isinstance(dynamic, bool):
            raise ValueError(f"dynamic must be True or False, got {dynamic!r}")
        distractions = check_distractions(distractions)
        check_texture_cache_mb(texture_cache_mb)
        self.scale = scale
        self.update_every = update_every
        self.background: SkyVideo | None = None
        self.camera: CameraWalk | None = None
        self.colour: ColourWalk | None = None
        if "background" in distractions:
            videos = DAVIS_VIDEOS[background_videos][:n_videos]
            texture = sky_texture(image_size, render, interpolation)
            clips = davis_clips(
                videos, background_videos, texture.resize_side, background_dir, texture.interpolation,
                texture.halvings,
            )  # fmt: skip
            alpha = GROUND_ALPHA.get(domain, DEFAULT_GROUND_ALPHA)
            self.background = SkyVideo(physics, clips, dynamic, alpha, texture.side, texture_cache_mb << 20)
        if "camera" in distractions:
            self.camera = CameraWalk(physics, camera_id, scale, dynamic, upper_quadrant=domain != "reacher")
        if "colour" in distractions:
            self.colour = ColourWalk(physics, scale, dynamic)
        self._rngs: list[np.random.Generator] = []
        self._steps = 0

    def start_episode(self, rng: np.random.Generator, reseeded: bool) -> None:
        if reseeded or not self._rngs:
            # One stream per distraction, as DCS's wrappers each hold their own.
            self._rngs = rng.spawn(3)
        background_rng, camera_rng, colour_rng = self._rngs
        self._steps = 0
        if self.background is not None:
            self.background.start(background_rng)
        if self.camera is not None:
            self.camera.start(camera_rng)
        if self.colour is not None:
            self.colour.start(colour_rng)

    def control_step(self) -> None:
        self._steps += 1
        if self._steps % self.update_every:
            return
        _, camera_rng, colour_rng = self._rngs
        if self.background is not None:
            self.background.advance()
        if self.camera is not None:
            self.camera.advance(camera_rng)
        if self.colour is not None:
            self.colour.advance(colour_rng)

    def get_state(self) -> dict[str, Any]:
        """Each distraction's generator and state."""
        parts = {name: part.get_state() for name, part in self._parts().items() if part is not None}
        return {"random": [rng.bit_generator.state for rng in self._rngs], "steps": self._steps, **parts}

    def set_state(self, state: dict[str, Any]) -> None:
        """Continue from ``get_state``'s state, on a distraction made with the same arguments."""
        self._rngs = [np.random.default_rng() for _ in state["random"]]
        for rng, rng_state in zip(self._rngs, state["random"], strict=True):
            rng.bit_generator.state = rng_state
        self._steps = state.get("steps", 0)
        for name, part in self._parts().items():
            if part is not None:
                part.set_state(state[name])

    def _parts(self) -> dict[str, SkyVideo | CameraWalk | ColourWalk | None]:
        return {"background": self.background, "camera": self.camera, "colour": self.colour}

    def render(self, renderer: CameraRenderer, agent_step: int) -> np.ndarray:
        overrides = self.background.overrides(renderer) if self.background is not None else []
        if self.colour is not None:
            self.colour.show()
        if self.camera is not None:
            overrides += self.camera.overrides()
        return renderer.render(overrides)
