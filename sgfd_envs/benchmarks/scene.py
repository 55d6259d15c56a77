"""What the benchmarks change in a dm_control scene, without touching its physics: material colours, textures
rebuilt or replaced and sent to the GPU, rotations of a camera's frame.

Every edit here writes visual fields of the model (``mat_rgba``, ``tex_data``, ``tex_width``/``tex_height``) or a
pose the renderer uses for one render; none of them enters MuJoCo's dynamics.
"""

from __future__ import annotations

import functools
import xml.etree.ElementTree as ET
from collections.abc import Callable, Hashable, Sequence
from dataclasses import dataclass

import cv2
import mujoco
import numpy as np
from dm_control.mujoco import Physics
from dm_control.suite import common

from sgfd_envs.rendering import CameraRenderer, check_render

# dm_control's shared assets: the skybox texture is in skybox.xml, the floor's grid texture in materials.xml.
_ASSET_OF_TEXTURE = {"skybox": "./common/skybox.xml", "grid": "./common/materials.xml"}


def suite_texture_attributes(name: str) -> dict[str, str]:
    """The XML attributes of one of dm_control's shared textures (``"skybox"`` or ``"grid"``).

    :param name: the texture's name
    """
    if name not in _ASSET_OF_TEXTURE:
        raise ValueError(f"name must be one of {tuple(_ASSET_OF_TEXTURE)}, got {name!r}")
    root = ET.fromstring(common.ASSETS[_ASSET_OF_TEXTURE[name]])
    element = next(e for e in root.iter("texture") if e.get("name") == name)
    return dict(element.attrib)


def rgb_attribute(rgb: Sequence[float] | np.ndarray) -> str:
    """An MJCF colour attribute from three floats in [0, 1]."""
    return " ".join(f"{float(c):.17g}" for c in rgb)


# A few entries: envs of one process that draw the same colours share the bytes (a skybox is 11.5 MB).
@functools.lru_cache(maxsize=4)
def _compiled_texture(items: tuple[tuple[str, str], ...]) -> np.ndarray:
    attributes = dict(items)
    element = ET.Element("texture", attributes)
    xml = f"<mujoco><asset>{ET.tostring(element, encoding='unicode')}</asset></mujoco>"
    data = mujoco.MjModel.from_xml_string(xml).tex_data.copy()
    data.flags.writeable = False
    return data


def suite_texture_data(name: str, **changes: str) -> np.ndarray:
    """The bytes MuJoCo builds for one of dm_control's shared builtin textures with some attributes changed
    (e.g. ``rgb1``), exactly as compiling the changed XML would give them.

    :param name: ``"skybox"`` or ``"grid"``
    :param changes: attribute values replacing dm_control's, as MJCF strings
    :return: read-only uint8 array of the texture's ``tex_data``
    """
    attributes = suite_texture_attributes(name)
    unknown = set(changes) - {"rgb1", "rgb2", "markrgb"}
    if unknown:
        raise ValueError(f"only rgb1, rgb2 and markrgb of a texture can change, got {sorted(unknown)}")
    attributes.update(changes)
    return _compiled_texture(tuple(sorted(attributes.items())))


@dataclass(frozen=True)
class VideoTexture:
    """How a video frame becomes the square texture a benchmark shows it on: resized whole to ``resize_side`` with
    ``interpolation``, then averaged over 2x2 blocks ``halvings`` times. The averaging makes the texture's mip
    level 0 the finest level a frame of the observation's size reads: MuJoCo draws textures mipmapped, so the finer
    levels are never read, and neither made nor sent to the GPU (an 800 px sky seen at 84 px is read at level 1
    and coarser).

    :param resize_side: side the frame is resized to
    :param interpolation: OpenCV interpolation of that resize
    :param halvings: 2x2 averagings after it
    """

    resize_side: int
    interpolation: int
    halvings: int = 0

    @property
    def side(self) -> int:
        """The texture's side."""
        return self.resize_side >> self.halvings


def video_texture(
    benchmark_side: int, benchmark_resize: int, image_size: int, render: str, texels_per_pixel: float
) -> VideoTexture:
    """The texture a benchmark's video frames go into: resized as the benchmark resizes them to its side with
    ``render="benchmark"``, with ``"fast"`` to twice the observation's side (at most the benchmark's) by pixel
    area; then halved while the halved texture is still minified at every pixel of a frame (its side at least
    ``texels_per_pixel`` observation sides): such a frame blends the same two mip levels as from the full texture.

    :param benchmark_side: the benchmark's texture side
    :param benchmark_resize: OpenCV's interpolation closest to the benchmark's resize
    :param image_size: the observation's height and width
    :param render: one of :data:`sgfd_envs.rendering.RENDER_MODES`
    :param texels_per_pixel: the least side, in observation sides, at which every pixel of a frame minifies the
        texture (a property of where it is drawn and of the camera's field of view)
    """
    if check_render(render) == "benchmark":
        side, interpolation = benchmark_side, benchmark_resize
    else:
        side, interpolation = min(benchmark_side, 2 * image_size), cv2.INTER_AREA
    halvings = 0
    while side % 2 ** (halvings + 1) == 0 and side >> (halvings + 1) >= texels_per_pixel * image_size:
        halvings += 1
    return VideoTexture(side, interpolation, halvings)


class TextureSlot:
    """One texture of a model whose content the benchmark replaces, sent to the GPU before the next render
    that needs it (never more than once per change).

    :param physics: the env's physics
    :param name: the texture's name in the model
    """

    def __init__(self, physics: Physics, name: str) -> None:
        self._model = physics.model
        self.texture_id = physics.model.name2id(name, "texture")
        self._address = int(self._model.tex_adr[self.texture_id])
        height, width = int(self._model.tex_height[self.texture_id]), int(self._model.tex_width[self.texture_id])
        self.original_shape = (height, width)
        self._capacity = height * width * int(self._model.tex_nchannel[self.texture_id])
        self._stale = False
        # What the bytes show, as the last write named it (None: unnamed, or the model's own).
        self.holds: Hashable | None = None

    def write(self, data: np.ndarray, shape: tuple[int, int] | None = None, holds: Hashable | None = None) -> None:
        """Replace the texture's bytes (and, for a cube texture, its size: a square ``shape`` makes MuJoCo
        draw the same image on all six faces).

        :param data: uint8 bytes, height x width x 3 of ``shape``
        :param shape: (height, width); default the texture's own
        :param holds: a name for what the bytes show (e.g. a clip's frame), kept as :attr:`holds`
        """
        height, width = shape or self.original_shape
        flat = np.asarray(data, dtype=np.uint8).reshape(-1)
        if flat.size != height * width * 3 or flat.size > self._capacity:
            raise ValueError(
                f"texture data must be {height}x{width}x3 bytes and fit the texture's {self._capacity}, got {flat.size}"
            )
        self._model.tex_height[self.texture_id] = height
        self._model.tex_width[self.texture_id] = width
        self._model.tex_data[self._address : self._address + flat.size] = flat
        self._stale = True
        self.holds = holds

    def upload_if_changed(self, renderer: CameraRenderer) -> None:
        """Send the texture to the GPU if it changed since the last upload."""
        if self._stale:
            renderer.upload_texture(self.texture_id)
            self._stale = False


# GPU memory the frames of one clip may take per env by default, in MiB: every frame of the longest DAVIS clip (104)
# as DCS's 400 px sky of an 84 px frame (5.1 MB each, :func:`cube_texture_bytes`) fits.
DEFAULT_TEXTURE_CACHE_MB = 512


def check_texture_cache_mb(texture_cache_mb: int) -> int:
    """``texture_cache_mb`` if it is a non-negative int, else a ValueError naming it."""
    if isinstance(texture_cache_mb, bool) or not isinstance(texture_cache_mb, int) or texture_cache_mb < 0:
        raise ValueError(f"texture_cache_mb must be a non-negative int (MiB; 0: no cache), got {texture_cache_mb!r}")
    return texture_cache_mb


def cube_texture_bytes(side: int) -> int:
    """GPU memory of a cube texture of square ``side`` as MuJoCo sends it: six faces of side x side texels, 4 bytes
    each (OpenGL drivers keep RGB texels as RGBA), and its mip levels (a third more)."""
    return 6 * side * side * 4 * 4 // 3


class FrameTextures:
    """The frames of a clip shown on a model's cube texture (DCS's sky), each sent to the GPU once, into an OpenGL
    texture of its own, at its first view, and drawn at every later view by naming that texture in the rendering
    context for the render (which sends nothing). The frames' pixels are the upload path's: MuJoCo's own upload
    fills each texture.

    It holds one clip's frames at a time (those of the previous clip are freed at the next clip's first view), up
    to ``max_bytes`` of GPU memory (:func:`cube_texture_bytes` per frame). A frame past that is written into the
    model's texture and sent at each view, as without the cache.

    :param slot: the model texture the frames are shown on
    :param side: the frames' square side
    :param max_bytes: GPU memory the cached frames may take (0: none, every view of a new frame sends it)
    """

    def __init__(self, slot: TextureSlot, side: int, max_bytes: int) -> None:
        self._slot = slot
        self._side = side
        self.capacity = max_bytes // cube_texture_bytes(side)
        self._clip: Hashable | None = None
        self._renderer: CameraRenderer | None = None
        self._names: dict[Hashable, int] = {}

    def __len__(self) -> int:
        """Frames held on the GPU."""
        return len(self._names)

    def overrides(
        self, renderer: CameraRenderer, clip: Hashable, index: Hashable, frame: Callable[[], np.ndarray]
    ) -> list:
        """Renderer overrides that show frame ``index`` of ``clip`` for one render, sending it first if this is its
        first view (or it is not held).

        :param renderer: the env's renderer
        :param clip: which clip (a change frees the frames held)
        :param index: which frame of the clip
        :param frame: gives the frame's uint8 (side, side, 3) bytes, called only when they must be sent
        """
        if renderer is not self._renderer:
            # Another renderer draws from here on; names of the last one's context are left to that context.
            self._renderer, self._names = renderer, {}
        if clip != self._clip:
            renderer.delete_textures(list(self._names.values()))
            self._clip, self._names = clip, {}
        name = self._names.get(index)
        if name is None and len(self._names) < self.capacity:
            self._write(clip, index, frame)
            name = renderer.make_textures(1)[0]
            renderer.upload_texture(self._slot.texture_id, name)
            self._names[index] = name
        if name is not None:
            return [renderer.texture_override(self._slot.texture_id, name)]
        self._write(clip, index, frame)
        self._slot.upload_if_changed(renderer)
        return []

    def _write(self, clip: Hashable, index: Hashable, frame: Callable[[], np.ndarray]) -> None:
        if self._slot.holds != (clip, index):
            self._slot.write(frame(), (self._side, self._side), holds=(clip, index))


def camera_frame_override(physics: Physics, camera_id: int, rotation: np.ndarray) -> list:
    """Renderer overrides that turn a camera's frame by ``rotation`` (in the camera's own axes: x right, y up,
    looking along -z) for one render.

    :param physics: the env's physics
    :param camera_id: the rendered camera
    :param rotation: 3x3 rotation applied on the right of the camera's world orientation
    """
    orientation = physics.data.cam_xmat[camera_id].reshape(3, 3)
    return [(physics.data.cam_xmat, camera_id, (orientation @ rotation).reshape(-1))]
