"""The benchmarks' own ways of making a distracted frame, re-implemented from their descriptions for the pixel tests:
each builds its own dm_control physics, puts the env's state on it, edits the scene the way the benchmark's code
does (XML for DMC-GB's green screen, the texture bytes and a site for DMC-GB2's screen, the sky texture, the floor's
alpha and the camera's pose for the Distracting Control Suite) and renders with dm_control's ``physics.render``.
Only dm_control, Pillow and the standard library draw here, never sgfd_envs' renderer or compositing."""

from __future__ import annotations

import colorsys
import importlib
import xml.etree.ElementTree as ET

import numpy as np
from dm_control import mujoco as dm_mujoco
from dm_control.suite import common
from PIL import Image

from sgfd_envs.dmc import TASK_MODEL_FIELDS

SIZE = 84
GREEN = ".2 .8 .2"


def disagreement(ours: np.ndarray, theirs: np.ndarray, levels: int) -> float:
    """Share of pixels whose colour differs by more than ``levels`` (of 255) in some channel."""
    return float((np.abs(ours.astype(int) - theirs.astype(int)).max(axis=-1) > levels).mean())


def copy_state(physics, source) -> None:
    """``source``'s simulator state and per-episode model fields on ``physics`` (the task's, and the site colours a
    task may hide, as finger-spin its target), positions recomputed."""
    for name in (*TASK_MODEL_FIELDS, "site_rgba"):
        getattr(physics.model, name)[:] = getattr(source.model, name)
    physics.set_state(source.get_state())
    physics.forward()


def suite_physics(domain: str, assets_edit=None, xml_edit=None):
    """dm_control's model of ``domain``, its shared assets and its XML optionally edited, compiled anew."""
    xml, assets = importlib.import_module(f"dm_control.suite.{domain}").get_model_and_assets()
    assets = dict(assets)
    if assets_edit is not None:
        assets_edit(assets)
    root = ET.fromstring(xml)
    if xml_edit is not None:
        xml_edit(root)
    return dm_mujoco.Physics.from_xml_string(ET.tostring(root, encoding="unicode"), assets)


def _set_texture(assets: dict, asset: str, name: str, **attributes: str) -> None:
    root = ET.fromstring(assets[asset])
    texture = next(t for t in root.iter("texture") if t.get("name") == name)
    texture.attrib.update(attributes)
    assets[asset] = ET.tostring(root)


# --- DMC-GB ---------------------------------------------------------------------------------------------------


def dmcgb_green_screen(domain: str, mode: str, source_physics, frame: np.ndarray) -> np.ndarray:
    """DMC-GB's video modes: the sky's texture (and for ``video_hard`` the floor's) rebuilt green from the XML, the
    usual render, then per pixel: HSV (``colorsys``) hue 100-185 degrees, saturation and value from 80 and 70 of 255
    take the video frame's pixel."""

    def paint(assets: dict) -> None:
        shared = {**common.ASSETS, **assets}
        assets.update(shared)
        _set_texture(assets, "./common/skybox.xml", "skybox", rgb1=GREEN, rgb2=GREEN, markrgb=GREEN)
        if mode == "video_hard":
            _set_texture(assets, "./common/materials.xml", "grid", rgb1=GREEN, rgb2=GREEN, markrgb=GREEN)

    physics = suite_physics(domain, paint)
    copy_state(physics, source_physics)
    rendered = physics.render(SIZE, SIZE, camera_id=0)
    out = rendered.copy()
    for row in range(SIZE):
        for col in range(SIZE):
            red, green, blue = (int(c) / 255.0 for c in rendered[row, col])
            hue, saturation, value = colorsys.rgb_to_hsv(red, green, blue)
            if 100 <= hue * 360 <= 185 and 80 <= saturation * 255 <= 255 and 70 <= value * 255 <= 255:
                out[row, col] = frame[row, col]
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


def dmcgb2_screen(domain: str, mode: str, source_physics, frame: np.ndarray, colours=None) -> np.ndarray:
    """DMC-GB2's video modes: a box site with a 256 x 256 cube texture behind the robot, the clip frame resized
    to it by Pillow's default filter (bicubic) and written into the texture's bytes, the site moved with the
    torso for walker and cheetah, the floor invisible in ``video_hard``; dm_control's render."""

    def add_screen(root: ET.Element) -> None:
        asset = root.find("asset")
        if asset is None:
            asset = ET.SubElement(root, "asset")
        ET.SubElement(asset, "texture", name="screen", type="skybox", builtin="flat", width="256", height="256")
        ET.SubElement(
            asset, "material", name="screen", texture="screen", texuniform="false", specular="0", shininess="0",
            reflectance="0", emission="0",
        )  # fmt: skip
        size, pos, euler = SCREENS[domain]
        ET.SubElement(root.find("worldbody"), "site", name="screen", type="box", material="screen", size=size,
                      pos=pos, euler=euler)  # fmt: skip

    physics = suite_physics(domain, xml_edit=add_screen)
    copy_state(physics, source_physics)
    if colours is not None:
        physics.model.mat_rgba[: len(colours), :3] = colours
    if mode == "video_hard":
        physics.named.model.mat_rgba["grid", "a"] = 0.0
    texture = physics.model.name2id("screen", "texture")
    physics.model.tex_height[texture] = physics.model.tex_width[texture] = 256
    address = physics.model.tex_adr[texture]
    resized = np.asarray(Image.fromarray(frame).resize((256, 256), Image.BICUBIC))
    physics.model.tex_data[address : address + resized.size] = resized.reshape(-1)
    if domain in FOLLOW:
        torso = physics.named.data.subtree_com["torso"]
        site = physics.model.name2id("screen", "site")
        physics.data.site_xpos[site, 0] = torso[0] + FOLLOW[domain][0]
        physics.data.site_xpos[site, 2] = torso[2] + FOLLOW[domain][1]
    rendered = physics.render(SIZE, SIZE, camera_id=0)
    physics.free()
    return rendered


# --- the Distracting Control Suite ----------------------------------------------------------------------------


def dcs_sky(
    domain: str, source_physics, frame: np.ndarray, ground_alpha: float, camera, colours, resample: int
) -> np.ndarray:
    """The Distracting Control Suite's background: the frame resized (``resample``, Pillow) to an 800 x 800 image
    written into the skybox texture, which then shows it on every face; the floor's alpha set; every material's
    colour and the camera's pose written into the model and data; dm_control's render."""
    physics = suite_physics(domain)
    copy_state(physics, source_physics)
    physics.model.mat_rgba[:, :3] = colours
    physics.named.model.mat_rgba["grid", "a"] = ground_alpha
    sky = physics.model.name2id("skybox", "texture")
    physics.model.tex_height[sky] = physics.model.tex_width[sky] = 800
    address = physics.model.tex_adr[sky]
    resized = np.asarray(Image.fromarray(frame).resize((800, 800), resample))
    physics.model.tex_data[address : address + resized.size] = resized.reshape(-1)
    if camera is not None:
        position, orientation = camera
        physics.data.cam_xpos[0] = position
        physics.data.cam_xmat[0] = orientation.reshape(-1)
    rendered = physics.render(SIZE, SIZE, camera_id=0)
    physics.free()
    return rendered


def interior(mask: np.ndarray) -> np.ndarray:
    """The pixels of ``mask`` whose 8 neighbours are in it too: away from an edge, where multisampling blends."""
    padded = np.pad(mask, 1, constant_values=False)
    height, width = mask.shape
    inside = np.ones_like(mask)
    for row in range(3):
        for col in range(3):
            inside &= padded[row : row + height, col : col + width]
    return inside
