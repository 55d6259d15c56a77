"""DMC-GB, the DMControl Generalization Benchmark (Hansen & Wang, ICRA 2021;
github.com/nicklashansen/dmcontrol-generalization-benchmark, MIT): test modes of an agent trained on the
undistracted task.

Facts taken from its code:

- ``color_easy`` / ``color_hard``: at every reset one entry of a set of 100 is drawn at random (from a generator
  seeded once with the env's seed) and gives the robot's ``self`` material, the floor's checker colours
  (``grid`` rgb1 and rgb2; its edge marks keep their colour) and the sky's upper colour (``skybox`` rgb1).
- ``video_easy`` (10 clips) replaces the sky's pixels with a video frame, ``video_hard`` (100 clips) the sky's
  and the floor's: DMC-GB paints them green and chroma-keys them in HSV, here the render pass's depth says
  exactly which pixels they are. Each frame is the whole clip frame resized (bilinear) to the observation;
  the clip advances one frame per agent step from frame 0, and episode k after seeding shows clip (k + 1) mod n.
- Action repeat 4, 2 for finger; 1000 simulator steps per episode; 84x84 frames (the paper's agents stack 3).
"""

from __future__ import annotations

from pathlib import Path

import mujoco
import numpy as np
from dm_control.mujoco import Physics

from sgfd_envs.backgrounds import composite
from sgfd_envs.benchmarks.media import ClipBank, colour_set, dmcgb_clips
from sgfd_envs.benchmarks.scene import TextureSlot, object_id, rgb_attribute, suite_texture_data
from sgfd_envs.dmc import CameraRenderer

NAME = "DMCGB"
MODES = ("train", "color_easy", "color_hard", "video_easy", "video_hard")
# (domain, task) -> action repeat, DMC-GB's defaults.
TASKS: dict[tuple[str, str], int] = {
    ("walker", "walk"): 4,
    ("walker", "stand"): 4,
    ("cartpole", "swingup"): 4,
    ("ball_in_cup", "catch"): 4,
    ("finger", "spin"): 2,
}


class SceneColours:
    """Puts one of DMC-GB's colour entries on a dm_control scene at runtime, as DMC-GB's XML edit would: the
    ``self`` material's RGB, the grid texture rebuilt with new rgb1/rgb2, the skybox rebuilt with a new rgb1.

    :param physics: the env's physics
    """

    def __init__(self, physics: Physics) -> None:
        self._physics = physics
        self._self_material = object_id(physics, mujoco.mjtObj.mjOBJ_MATERIAL, "self")
        self._grid = TextureSlot(physics, "grid")
        self._sky = TextureSlot(physics, "skybox")
        self.current: dict[str, np.ndarray] | None = None

    def apply(self, entry: dict[str, np.ndarray]) -> None:
        """Use ``entry``'s colours (keys ``self_rgb``, ``grid_rgb1``, ``grid_rgb2``, ``skybox_rgb``)."""
        self._physics.model.mat_rgba[self._self_material, :3] = entry["self_rgb"]
        self._grid.write(
            suite_texture_data("grid", rgb1=rgb_attribute(entry["grid_rgb1"]), rgb2=rgb_attribute(entry["grid_rgb2"]))
        )
        self._sky.write(suite_texture_data("skybox", rgb1=rgb_attribute(entry["skybox_rgb"])))
        self.current = entry

    def upload(self, renderer: CameraRenderer) -> None:
        """Send the rebuilt textures to the GPU (once per change)."""
        self._grid.upload_if_changed(renderer)
        self._sky.upload_if_changed(renderer)


class DMCGBDistraction:
    """One DMC-GB test mode on one env's physics (see the module docstring).

    :param physics: the env's physics
    :param mode: one of :data:`MODES` other than ``"train"``
    :param image_size: observation height and width
    :param data_dir: DMC-GB's ``src/env/data`` folder, or None for the procedural stand-ins
    """

    def __init__(self, physics: Physics, mode: str, image_size: int, data_dir: str | Path | None) -> None:
        if mode not in MODES[1:]:
            raise ValueError(f"mode must be one of {MODES[1:]}, got {mode!r}")
        self.mode = mode
        self.hide = {"video_easy": "sky", "video_hard": "backdrop"}.get(mode, "nothing")
        self._colours: list[dict[str, np.ndarray]] | None = None
        self._scene_colours: SceneColours | None = None
        self._clips: ClipBank | None = None
        if mode.startswith("color"):
            self._colours = colour_set(mode.removeprefix("color_"), data_dir)
            self._scene_colours = SceneColours(physics)
        else:
            self._clips = dmcgb_clips(mode, image_size, data_dir)
        self._episodes_since_seed = 0
        self.colour_index: int | None = None
        self.clip_index: int | None = None

    def start_episode(self, rng: np.random.Generator, reseeded: bool) -> None:
        if reseeded:
            self._episodes_since_seed = 0
        self._episodes_since_seed += 1
        if self._colours is not None:
            self.colour_index = int(rng.integers(len(self._colours)))
            self._scene_colours.apply(self._colours[self.colour_index])
        else:
            self.clip_index = self._episodes_since_seed % len(self._clips)

    def control_step(self) -> None:
        pass

    def get_state(self) -> dict[str, int | None]:
        """The episode count since seeding and the episode's colour entry or clip."""
        return {
            "episodes_since_seed": self._episodes_since_seed,
            "colour_index": self.colour_index,
            "clip_index": self.clip_index,
        }

    def set_state(self, state: dict[str, int | None]) -> None:
        """Continue from ``get_state``'s state, on a distraction made with the same arguments."""
        self._episodes_since_seed = state["episodes_since_seed"]
        self.colour_index, self.clip_index = state["colour_index"], state["clip_index"]
        if self.colour_index is not None:
            self._scene_colours.apply(self._colours[self.colour_index])

    def render(self, renderer: CameraRenderer, agent_step: int) -> np.ndarray:
        if self._scene_colours is not None:
            self._scene_colours.upload(renderer)
            return renderer.render()[0]
        rgb, background = renderer.render()
        return composite(rgb, background, self._clips.clip(self.clip_index).frame(agent_step))
