"""The benchmarks' own ways of making a distracted frame, re-implemented from their descriptions: one place for
both ``bench/env_throughput.py`` (which times them) and ``tests/envs/test_benchmarks_pixels.py`` (which checks that our
ids make the same pixels). Each method edits a dm_control scene the way the benchmark's code does (XML for DMC-GB's
green screen, the texture bytes and a site for DMC-GB2's screen, the sky texture, the floor's alpha and the camera's
pose for the Distracting Control Suite) and renders with dm_control's ``physics.render``. Only dm_control, MuJoCo,
SciPy, Pillow and the standard library draw here, never sgfd_envs' renderer, compositing or distraction classes.

Also the tests' pixel comparisons: :func:`disagreement` and :func:`interior`."""

from __future__ import annotations

# First: importing sgfd_envs picks MuJoCo's headless OpenGL backend, which must precede dm_control.
import sgfd_envs  # noqa: F401

# isort: split

import colorsys
import importlib
import xml.etree.ElementTree as ET
from collections.abc import Callable

import cv2
import mujoco
import numpy as np
from dm_control import mujoco as dm_mujoco
from dm_control.suite import common
from PIL import Image
from scipy.spatial.transform import Rotation

from sgfd_envs.dmc import TASK_MODEL_FIELDS

SIZE = 84
GREEN = ".2 .8 .2"
Model = tuple[str, dict[str, bytes]]


def disagreement(ours: np.ndarray, theirs: np.ndarray, levels: int) -> float:
    """Share of pixels whose colour differs by more than ``levels`` (of 255) in some channel."""
    return float((np.abs(ours.astype(int) - theirs.astype(int)).max(axis=-1) > levels).mean())


def interior(mask: np.ndarray) -> np.ndarray:
    """The pixels of ``mask`` whose 8 neighbours are in it too: away from an edge, where multisampling blends."""
    kernel = np.ones((3, 3), np.uint8)
    eroded = cv2.erode(mask.astype(np.uint8), kernel, borderType=cv2.BORDER_CONSTANT, borderValue=0)
    return eroded.astype(bool)


def copy_state(physics, source) -> None:
    """``source``'s simulator state and per-episode model fields on ``physics`` (the task's, and the site colours a
    task may hide, as finger-spin its target), positions recomputed."""
    for name in (*TASK_MODEL_FIELDS, "site_rgba"):
        getattr(physics.model, name)[:] = getattr(source.model, name)
    physics.set_state(source.get_state())
    physics.forward()


def suite_model(
    domain: str,
    assets_edit: Callable[[dict], None] | None = None,
    xml_edit: Callable[[ET.Element], None] | None = None,
) -> Model:
    """dm_control's XML and assets of ``domain``, optionally edited (for ``physics.reload_from_xml_string``)."""
    xml, assets = importlib.import_module(f"dm_control.suite.{domain}").get_model_and_assets()
    assets = dict(assets)
    if assets_edit is not None:
        assets_edit(assets)
    root = ET.fromstring(xml)
    if xml_edit is not None:
        xml_edit(root)
    return ET.tostring(root, encoding="unicode"), assets


def suite_physics(model: Model):
    """A physics compiled from :func:`suite_model`'s XML and assets."""
    return dm_mujoco.Physics.from_xml_string(*model)


def upload_texture(physics, name: str) -> None:
    """Send texture ``name``'s bytes, as the model holds them now, to the GPU (the benchmarks do so after editing
    them; a physics that has not rendered yet uploads every texture at its first render anyway)."""
    texture = physics.model.name2id(name, "texture")
    with physics.contexts.gl.make_current() as ctx:
        ctx.call(mujoco.mjr_uploadTexture, physics.model.ptr, physics.contexts.mujoco.ptr, texture)


def write_texture(physics, name: str, image: np.ndarray) -> None:
    """``image`` (square, RGB) as texture ``name``'s bytes, and sent to the GPU."""
    texture = physics.model.name2id(name, "texture")
    physics.model.tex_height[texture] = physics.model.tex_width[texture] = image.shape[0]
    address = physics.model.tex_adr[texture]
    physics.model.tex_data[address : address + image.size] = image.reshape(-1)
    upload_texture(physics, name)


def _set_texture(assets: dict, asset: str, name: str, **attributes: str) -> None:
    root = ET.fromstring(assets[asset])
    texture = next(t for t in root.iter("texture") if t.get("name") == name)
    texture.attrib.update(attributes)
    assets[asset] = ET.tostring(root)


# --- DMC-GB ---------------------------------------------------------------------------------------------------


def dmcgb_green_model(domain: str, mode: str) -> Model:
    """DMC-GB's video modes' scene: the sky's texture (and for ``video_hard`` the floor's) rebuilt green."""

    def paint(assets: dict) -> None:
        assets.update({**common.ASSETS, **assets})
        _set_texture(assets, "./common/skybox.xml", "skybox", rgb1=GREEN, rgb2=GREEN, markrgb=GREEN)
        if mode == "video_hard":
            _set_texture(assets, "./common/materials.xml", "grid", rgb1=GREEN, rgb2=GREEN, markrgb=GREEN)

    return suite_model(domain, paint)


def green_screen(rendered: np.ndarray, frame: np.ndarray) -> np.ndarray:
    """DMC-GB's compositing, per pixel in Python: where the render's HSV (``colorsys``) has hue 100-185 degrees and
    saturation and value from 80 and 70 of 255, the video frame's pixel."""
    out = rendered.copy()
    for row in range(rendered.shape[0]):
        for col in range(rendered.shape[1]):
            red, green, blue = (int(c) / 255.0 for c in rendered[row, col])
            hue, saturation, value = colorsys.rgb_to_hsv(red, green, blue)
            if 100 <= hue * 360 <= 185 and 80 <= saturation * 255 <= 255 and 70 <= value * 255 <= 255:
                out[row, col] = frame[row, col]
    return out


def dmcgb_green_screen(domain: str, mode: str, source_physics, frame: np.ndarray) -> np.ndarray:
    """DMC-GB's video modes on ``source_physics``' state: the green scene, the usual render, :func:`green_screen`."""
    physics = suite_physics(dmcgb_green_model(domain, mode))
    copy_state(physics, source_physics)
    out = green_screen(physics.render(SIZE, SIZE, camera_id=0), frame)
    physics.free()
    return out


# --- DMC-GB2 --------------------------------------------------------------------------------------------------

# DMC-GB2's screen per domain: half-sizes, position, euler angles (degrees); and the torso offsets it follows.
SCREENS = {
    "walker": ("1.86 .1 1.86", "0 1.96 -.7", "-30 0 0"),
    "cheetah": ("1.86 .1 1.86", "0 1.6 -.7", "0 0 0"),
    "cartpole": ("1.86 .1 1.86", "0 .5 1", "0 0 0"),
    "ball_in_cup": (".66 .1 .66", "0 .5 .05", "-27 0 0"),
    "finger": (".66 .1 .66", "0 .5 .05", "-27 0 0"),
}
FOLLOW = {"walker": (0.0, -1.07), "cheetah": (-0.05, 0.15)}
SCREEN_SIDE = 256


def dmcgb2_screen_model(domain: str) -> Model:
    """DMC-GB2's video modes' scene: a box site behind the robot with its own 256 x 256 cube texture."""

    def add_screen(root: ET.Element) -> None:
        asset = root.find("asset")
        if asset is None:
            asset = ET.SubElement(root, "asset")
        side = str(SCREEN_SIDE)
        ET.SubElement(asset, "texture", name="screen", type="skybox", builtin="flat", width=side, height=side)
        ET.SubElement(
            asset, "material", name="screen", texture="screen", texuniform="false", specular="0", shininess="0",
            reflectance="0", emission="0",
        )  # fmt: skip
        size, pos, euler = SCREENS[domain]
        worldbody = root.find("worldbody")
        assert worldbody is not None, f"dm_control's {domain} model has no worldbody"
        ET.SubElement(worldbody, "site", name="screen", type="box", material="screen", size=size,
                      pos=pos, euler=euler)  # fmt: skip

    return suite_model(domain, xml_edit=add_screen)


def dmcgb2_prepare(physics, mode: str) -> None:
    """The floor invisible in ``video_hard``."""
    if mode == "video_hard":
        physics.named.model.mat_rgba["grid", "a"] = 0.0


def dmcgb2_resize(frame: np.ndarray) -> np.ndarray:
    """A clip frame resized to the screen's texture by Pillow's bicubic filter (done when a clip is loaded)."""
    return np.asarray(Image.fromarray(frame).resize((SCREEN_SIDE, SCREEN_SIDE), Image.Resampling.BICUBIC))


def dmcgb2_show(physics, domain: str, resized: np.ndarray) -> None:
    """DMC-GB2's work per agent step: the resized frame into the screen's texture bytes and to the GPU, the
    screen moved with the torso for walker and cheetah."""
    write_texture(physics, "screen", resized)
    if domain in FOLLOW:
        torso = physics.named.data.subtree_com["torso"]
        site = physics.model.name2id("screen", "site")
        physics.data.site_xpos[site, 0] = torso[0] + FOLLOW[domain][0]
        physics.data.site_xpos[site, 2] = torso[2] + FOLLOW[domain][1]


def dmcgb2_screen(domain: str, mode: str, source_physics, frame: np.ndarray) -> np.ndarray:
    """DMC-GB2's video modes on ``source_physics``' state: the screen scene showing ``frame``; dm_control's render."""
    physics = suite_physics(dmcgb2_screen_model(domain))
    copy_state(physics, source_physics)
    dmcgb2_prepare(physics, mode)
    dmcgb2_show(physics, domain, dmcgb2_resize(frame))
    rendered = physics.render(SIZE, SIZE, camera_id=0)
    physics.free()
    return rendered


# --- the Distracting Control Suite ----------------------------------------------------------------------------

SKY_SIDE = 800


def dcs_ground_alpha(domain: str) -> float:
    """The floor's alpha under DCS's background: none for reacher, opaque for walker and cheetah, 0.3 otherwise."""
    if domain == "reacher":
        return 0.0
    return 1.0 if domain in ("walker", "cheetah") else 0.3


def dcs_prepare(physics, domain: str) -> None:
    """The floor's alpha set for the episode."""
    physics.named.model.mat_rgba["grid", "a"] = dcs_ground_alpha(domain)


def dcs_look_at_point(physics, camera_id: int = 0) -> np.ndarray:
    """The point the (unmoved) camera looks at: along its viewing axis, as far as the robot's centre of mass."""
    position = physics.data.cam_xpos[camera_id]
    distance = np.sqrt(np.sum((position - physics.data.subtree_com[1]) ** 2))
    return position + physics.data.cam_xmat[camera_id].reshape(3, 3) @ np.array([0.0, 0.0, -distance])


def dcs_camera_pose(
    physics, spherical: np.ndarray, roll: float, start_target: np.ndarray, upper_quadrant: bool
) -> tuple[np.ndarray, np.ndarray]:
    """DCS's camera pose from its drawn (radius, azimuth, polar angle) and roll: the point on the sphere (around
    the robot's centre of mass for a tracking camera), turned to look at the start's look-at point (fixed camera)
    or the unmoved camera's one now (tracking camera), then rolled about the viewing axis. ``upper_quadrant``:
    yaw then pitch, a level horizon; else the shortest rotation from looking down onto the target (reacher)."""
    radius, azimuth, polar = spherical
    position = radius * np.array([np.sin(polar) * np.cos(azimuth), np.sin(polar) * np.sin(azimuth), np.cos(polar)])
    target = start_target
    if int(physics.model.cam_mode[0]) == int(mujoco.mjtCamLight.mjCAMLIGHT_TRACKCOM):
        position = position + physics.data.subtree_com[1]
        target = dcs_look_at_point(physics)
    direction = (target - position) / np.linalg.norm(target - position)
    if upper_quadrant:
        yaw = np.arctan2(direction[0], direction[1])
        pitch = np.arctan2(direction[2], np.linalg.norm(direction[:2])) + np.pi / 2
        # Intrinsic z-x-z: turn by -yaw about the world's z, pitch about the turned x, roll about the viewing axis.
        orientation = Rotation.from_euler("ZXZ", [-yaw, pitch, roll]).as_matrix()
    else:
        down = np.array([0.0, 0.0, -1.0])
        axis = np.cross(down, direction)
        angle = np.arctan2(np.linalg.norm(axis), direction @ down)
        turn = Rotation.from_rotvec(axis / np.linalg.norm(axis) * angle)
        orientation = (turn * Rotation.from_euler("z", roll)).as_matrix()
    return position, orientation


def dcs_resize(frame: np.ndarray, resample: int) -> np.ndarray:
    """A video frame resized (``resample``, Pillow) to the 800 x 800 sky texture (done when a video is loaded)."""
    return np.asarray(Image.fromarray(frame).resize((SKY_SIDE, SKY_SIDE), resample))


def dcs_show_sky(physics, resized: np.ndarray) -> None:
    """DCS's work per simulator step: the resized frame into the skybox texture's bytes (every face shows it) and
    to the GPU."""
    write_texture(physics, "skybox", resized)


def dcs_set_camera(physics, pose: tuple[np.ndarray, np.ndarray]) -> None:
    """Camera 0 at ``pose`` (position, 3x3 orientation) in the data the next render reads."""
    position, orientation = pose
    physics.data.cam_xpos[0] = position
    physics.data.cam_xmat[0] = orientation.reshape(-1)


def dcs_sky(
    domain: str,
    source_physics,
    frame: np.ndarray,
    colours: np.ndarray,
    camera: tuple[np.ndarray, float, np.ndarray],
    resample: int,
) -> np.ndarray:
    """The Distracting Control Suite on ``source_physics``' state: the floor's alpha, every material's colour, the
    frame on the sky and the camera at :func:`dcs_camera_pose` of ``camera`` (spherical coordinates, roll, the
    start's look-at point); dm_control's render."""
    physics = suite_physics(suite_model(domain))
    copy_state(physics, source_physics)
    dcs_prepare(physics, domain)
    physics.model.mat_rgba[:, :3] = colours
    dcs_show_sky(physics, dcs_resize(frame, resample))
    spherical, roll, start_target = camera
    dcs_set_camera(physics, dcs_camera_pose(physics, spherical, roll, start_target, domain != "reacher"))
    rendered = physics.render(SIZE, SIZE, camera_id=0)
    physics.free()
    return rendered
