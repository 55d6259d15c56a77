"""DMC-GB, the DMControl Generalization Benchmark (Hansen & Wang, ICRA 2021;
github.com/nicklashansen/dmcontrol-generalization-benchmark, MIT): test modes of an agent trained on the
undistracted task.

Facts taken from its code:

- ``color_easy`` / ``color_hard``: at every reset one entry of a set of 100 is drawn at random (from a generator
  seeded once with the env's seed) and gives the robot's ``self`` material, the floor's checker colours
  (``grid`` rgb1 and rgb2; its edge marks keep their colour) and the sky's upper colour (``skybox`` rgb1).
- ``video_easy`` (10 clips) replaces the sky's pixels with a video frame, ``video_hard`` (100 clips) the sky's
  and the floor's, as DMC-GB does: the sky's texture (and the floor's) painted green ([.2, .8, .2], its marks
  too), the frame rendered as usual, and every pixel whose HSV colour lies in hue 100-185 degrees, saturation
  80-255 and value 70-255 (of 255) replaced by the video frame's pixel (:func:`green_screen_mask`). Each frame is
  the whole clip frame resized (bilinear) to the observation; the clip advances one frame per agent step from
  frame 0, and episode k after seeding shows clip (k + 1) mod n.
- ``distracting_cs`` (its code's reformatting of the Distracting Control Suite, :mod:`sgfd_envs.benchmarks.dcs`):
  background, camera and colour at one ``intensity`` s of :data:`DISTRACTING_CS_VIDEOS`, the background drawing
  from the first 2, 2, 4, 6, 8 of DAVIS's 60 training videos (all 60 from 0.3 on), always dynamic, every walk
  (camera, colours, video frame) moved at every second simulator step of the episode; DAVIS frames resized to the
  800 x 800 sky with Pillow's default filter of its pinned Pillow 6.2 (nearest). SVEA, SGQN and DMC-GB2 report
  this mode; DMC-GB2 tests on the same eight intensities (:mod:`sgfd_envs.benchmarks.dmcgb2`).
- Action repeat 4, 2 for finger (the code's default is 4 for every task; its maintainer states that finger-spin
  ran at 2, in the repository's issue 13); 1000 simulator steps per episode; 84x84 frames (agents stack 3).
- Its ``train.py`` counts ``env.step`` calls: ``train_steps=500k`` is 500k agent steps (2M simulator steps at
  repeat 4), and ``eval.py`` tests that checkpoint.
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from dm_control.mujoco import Physics

from sgfd_envs.benchmarks import facts
from sgfd_envs.benchmarks.dcs import DISTRACTIONS, DCSDistraction
from sgfd_envs.benchmarks.media import ClipBank, check_data_dir, colour_set, davis_folder, dmcgb_clips
from sgfd_envs.benchmarks.scene import DEFAULT_TEXTURE_CACHE_MB, TextureSlot, rgb_attribute, suite_texture_data
from sgfd_envs.dmc import Distraction
from sgfd_envs.rendering import CameraRenderer

# The facts the id table reads (benchmarks/facts.py, import-light), under this module's names.
NAME, MODES, TASKS, DISTRACTING_CS = facts.DMCGB, facts.DMCGB_MODES, facts.DMCGB_TASKS, facts.DISTRACTING_CS
DISTRACTING_CS_VIDEOS, INTENSITIES = facts.DISTRACTING_CS_VIDEOS, facts.INTENSITIES
DISTRACTING_CS_UPDATE_EVERY = 2
# DMC-GB's green screen: the colour of the sky (and floor) in its video modes, and the HSV box it keys out (hue in
# degrees, saturation and value out of 255).
GREEN_SCREEN_RGB = (0.2, 0.8, 0.2)
GREEN_SCREEN_HSV_LOW = (100.0, 80.0, 70.0)
GREEN_SCREEN_HSV_HIGH = (185.0, 255.0, 255.0)


def green_screen_mask(rgb: np.ndarray) -> np.ndarray:
    """Where DMC-GB's green screen keys a frame out: the pixels whose HSV colour (Python's ``colorsys``
    convention) lies in :data:`GREEN_SCREEN_HSV_LOW` .. :data:`GREEN_SCREEN_HSV_HIGH`. Each colour's verdict is
    worked out once per process (:func:`_green_screen_rule`) and looked up after.

    :param rgb: uint8 (H, W, 3) frame
    :return: bool (H, W)
    """
    red, green, blue = (rgb[..., channel].astype(np.int32) for channel in range(3))
    code = (red << 16) | (green << 8) | blue
    verdicts = _green_screen_verdicts()
    known = verdicts[code]
    if (known < 0).any():
        new = np.unique(code[known < 0])
        verdicts[new] = _green_screen_rule(np.stack([new >> 16, (new >> 8) & 255, new & 255], axis=-1))
        known = verdicts[code]
    return known == 1


@functools.lru_cache(maxsize=1)
def _green_screen_verdicts() -> np.ndarray:
    """Every 24-bit colour's verdict, indexed by ``r << 16 | g << 8 | b``: 1 keyed, 0 not, -1 not seen yet (16 MB)."""
    return np.full(2**24, -1, dtype=np.int8)


def _green_screen_rule(rgb: np.ndarray) -> np.ndarray:
    """DMC-GB's key of colours (..., 3) in 0..255: ``colorsys``'s HSV, in its floating-point steps, within the box."""
    channels = rgb.astype(np.float64) / 255.0
    red, green, blue = channels[..., 0], channels[..., 1], channels[..., 2]
    high, low = channels.max(axis=-1), channels.min(axis=-1)
    spread = high - low
    grey = spread == 0
    safe_spread = np.where(grey, 1.0, spread)
    red_c, green_c, blue_c = ((high - c) / safe_spread for c in (red, green, blue))
    hue = np.where(red == high, blue_c - green_c, np.where(green == high, 2.0 + red_c - blue_c, 4.0 + green_c - red_c))
    hue = np.where(grey, 0.0, (hue / 6.0) % 1.0) * 360.0
    saturation = np.where(grey, 0.0, spread / np.where(high == 0, 1.0, high)) * 255.0
    value = high * 255.0
    (hue_low, sat_low, value_low), (hue_high, sat_high, value_high) = GREEN_SCREEN_HSV_LOW, GREEN_SCREEN_HSV_HIGH
    return (
        (hue >= hue_low) & (hue <= hue_high)
        & (saturation >= sat_low) & (saturation <= sat_high)
        & (value >= value_low) & (value <= value_high)
    )  # fmt: skip


class GreenScreen:
    """DMC-GB's green screen on a dm_control scene: the skybox (and with ``floor`` the grid) painted
    :data:`GREEN_SCREEN_RGB`, marks included, as its XML edit paints them.

    :param physics: the env's physics
    :param floor: paint the floor too (``video_hard``)
    """

    def __init__(self, physics: Physics, floor: bool) -> None:
        green = rgb_attribute(GREEN_SCREEN_RGB)
        self._slots = [TextureSlot(physics, "skybox")]
        self._slots[0].write(suite_texture_data("skybox", rgb1=green, rgb2=green, markrgb=green))
        if floor:
            self._slots.append(TextureSlot(physics, "grid"))
            self._slots[1].write(suite_texture_data("grid", rgb1=green, rgb2=green, markrgb=green))

    def upload(self, renderer: CameraRenderer) -> None:
        """Send the painted textures to the GPU (once)."""
        for slot in self._slots:
            slot.upload_if_changed(renderer)


def check_intensity(split: str, intensity: float | None) -> float | None:
    """``intensity`` if it fits ``split``: one of :data:`INTENSITIES` for ``distracting_cs``, None otherwise."""
    if split == DISTRACTING_CS:
        if isinstance(intensity, bool) or intensity not in DISTRACTING_CS_VIDEOS:
            raise ValueError(f"intensity must be one of {INTENSITIES} with split='distracting_cs', got {intensity!r}")
        return float(intensity)
    if intensity is not None:
        raise ValueError(f"intensity is for split='distracting_cs' only, got intensity={intensity!r} with {split=}")
    return None


def distracting_cs(
    physics: Physics,
    domain: str,
    intensity: float,
    image_size: int,
    background_dir: str | Path | None,
    render: str = "benchmark",
    interpolation: int = cv2.INTER_NEAREST_EXACT,
    texture_cache_mb: int = DEFAULT_TEXTURE_CACHE_MB,
) -> DCSDistraction:
    """DMC-GB's ``distracting_cs`` at one intensity (see the module docstring).

    :param physics: the env's physics
    :param domain: the dm_control domain
    :param intensity: one of :data:`INTENSITIES`
    :param image_size: observation height and width
    :param background_dir: DAVIS's ``JPEGImages/480p`` folder, or None for the procedural stand-ins
    :param render: ``"benchmark"`` or ``"fast"`` (see :class:`~sgfd_envs.benchmarks.dcs.DCSDistraction`)
    :param interpolation: OpenCV's closest to the benchmark's resize of a DAVIS frame (DMC-GB's Pillow 6.2:
        nearest, as ``INTER_NEAREST_EXACT``)
    :param texture_cache_mb: GPU memory (MiB) the sky's frames of the episode's video may take (see
        :class:`~sgfd_envs.benchmarks.dcs.DCSDistraction`)
    """
    return DCSDistraction(
        physics, domain, intensity, DISTRACTING_CS_VIDEOS[intensity], True, DISTRACTIONS, "train", image_size,
        background_dir, update_every=DISTRACTING_CS_UPDATE_EVERY, render=render, interpolation=interpolation,
        texture_cache_mb=texture_cache_mb,
    )  # fmt: skip


def family_distraction(
    robot: str,
    split: str,
    intensity: float | None,
    data_dir: str | Path | None,
    background_dir: str | Path | None,
    image_size: int,
    render: str,
    make_mode: Callable[[Physics], Distraction],
    **distracting_cs_kwargs: Any,
) -> Callable[[Physics], Distraction]:
    """Check the data kwargs DMC-GB and DMC-GB2 share, and give their distraction's factory: DMC-GB's
    ``distracting_cs`` at ``intensity`` for that split, ``make_mode(physics)`` for the others.

    :param robot: the dm_control domain
    :param distracting_cs_kwargs: more kwargs of :func:`distracting_cs`
    """
    intensity = check_intensity(split, intensity)
    if data_dir is not None:
        check_data_dir(data_dir)
    if background_dir is not None:
        davis_folder(background_dir)

    def make_distraction(physics: Physics) -> Distraction:
        if split == DISTRACTING_CS:
            assert intensity is not None  # check_intensity requires one with this split
            return distracting_cs(
                physics, robot, intensity, image_size, background_dir, render, **distracting_cs_kwargs
            )
        return make_mode(physics)

    return make_distraction


class SceneColours:
    """Puts the entries of one of DMC-GB's colour sets on a dm_control scene at runtime, as DMC-GB's XML edit would:
    the ``self`` material's RGB, the grid texture rebuilt with new rgb1/rgb2, the skybox rebuilt with a new rgb1.

    :param physics: the env's physics
    :param colours: the colour set (entries with keys ``self_rgb``, ``grid_rgb1``, ``grid_rgb2``, ``skybox_rgb``)
    """

    def __init__(self, physics: Physics, colours: list[dict[str, np.ndarray]]) -> None:
        self._physics = physics
        self.colours = colours
        self._self_material = physics.model.name2id("self", "material")
        self._grid = TextureSlot(physics, "grid")
        self._sky = TextureSlot(physics, "skybox")
        self.current: dict[str, np.ndarray] | None = None

    def __len__(self) -> int:
        return len(self.colours)

    def apply(self, index: int) -> None:
        """Use the colours of entry ``index`` of the set."""
        entry = self.colours[index]
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
        self._scene_colours: SceneColours | None = None
        self._clips: ClipBank | None = None
        self._green_screen: GreenScreen | None = None
        if mode.startswith("color"):
            self._scene_colours = SceneColours(physics, colour_set(mode.removeprefix("color_"), data_dir))
        else:
            self._clips = dmcgb_clips(mode, image_size, data_dir)
            self._green_screen = GreenScreen(physics, floor=mode == "video_hard")
        self._episodes_since_seed = 0
        self.colour_index: int | None = None
        self.clip_index: int | None = None

    def start_episode(self, rng: np.random.Generator, reseeded: bool) -> None:
        if reseeded:
            self._episodes_since_seed = 0
        self._episodes_since_seed += 1
        if self._scene_colours is not None:
            self.colour_index = int(rng.integers(len(self._scene_colours)))
            self._scene_colours.apply(self.colour_index)
        else:
            assert self._clips is not None  # a video mode
            self.clip_index = self._episodes_since_seed % len(self._clips)

    def control_step(self) -> None:
        pass

    def get_state(self) -> dict[str, Any]:
        """The episode count since seeding and the episode's colour entry or clip."""
        return {
            "episodes_since_seed": self._episodes_since_seed,
            "colour_index": self.colour_index,
            "clip_index": self.clip_index,
        }

    def set_state(self, state: dict[str, Any]) -> None:
        """Continue from ``get_state``'s state, on a distraction made with the same arguments."""
        self._episodes_since_seed = state["episodes_since_seed"]
        self.colour_index, self.clip_index = state["colour_index"], state["clip_index"]
        if self._scene_colours is not None and self.colour_index is not None:
            self._scene_colours.apply(self.colour_index)

    def render(self, renderer: CameraRenderer, agent_step: int) -> np.ndarray:
        if self._scene_colours is not None:
            self._scene_colours.upload(renderer)
            return renderer.render()
        # a video mode, rendered after start_episode drew the episode's clip
        assert self._green_screen is not None and self._clips is not None and self.clip_index is not None
        self._green_screen.upload(renderer)
        rgb = renderer.render()
        keyed = green_screen_mask(rgb)[..., np.newaxis]
        return np.where(keyed, self._clips.clip(self.clip_index).frame(agent_step), rgb)
