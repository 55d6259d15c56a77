"""One camera of a dm_control Physics rendered into reused buffers, as the benchmarks render it or faster.

``render="benchmark"`` (the default) draws what dm_control's ``physics.render(h, w, camera_id)`` draws, with the
model's own visual settings: shadows, reflections and the model's multisampling (``offsamples``, 4 in dm_control's
tasks). DMC-GB, DMC-GB2, the Distracting Control Suite and dmc2gym (DBC, AMBS) all render that way.
``render="fast"`` turns shadows, reflections and multisampling off.

With the backdrop (the floor and the skybox) hidden the renderer reads the alpha channel of the same pass with
the colour, in one readback: OpenGL clears it to 0, every opaque fragment writes 1, and the multisample resolve
averages the samples, so alpha is the share of a pixel the drawn scene covers (0, 1/4, ..., 1 with 4 samples), and
the colour is already weighted by it. Putting a picture behind the scene is then ``colour + (1 - alpha) * picture``
(:func:`sgfd_envs.backgrounds.composite`), which is what the multisampled render of that picture drawn behind
the scene gives.
"""

from __future__ import annotations

from collections.abc import Sequence

import mujoco
import numpy as np
from dm_control.mujoco import Physics, engine

RENDER_MODES = ("benchmark", "fast")
# OpenGL's pixel formats, the values of mjrContext.readPixelFormat (which mjr_readPixels reads in).
_GL_RGBA = 0x1908


def check_render(render: str) -> str:
    """Return ``render`` if it is one of :data:`RENDER_MODES`, else raise naming them."""
    if render not in RENDER_MODES:
        raise ValueError(f"render must be one of {RENDER_MODES}, got {render!r}")
    return render


def configure_offscreen_buffer(physics: Physics, size: int, render: str = "benchmark") -> None:
    """Set the offscreen buffer up for :class:`CameraRenderer`; call it before anything renders.

    ``"benchmark"`` keeps the model's multisampling; ``"fast"`` turns it off. The buffer grows to fit ``size``.

    :param physics: the dm_control physics, whose rendering context must not exist yet
    :param size: image height and width in pixels
    :param render: one of :data:`RENDER_MODES`
    """
    visual = physics.model.vis
    if check_render(render) == "fast":
        visual.quality.offsamples = 0
    visual.global_.offwidth = max(visual.global_.offwidth, size)
    visual.global_.offheight = max(visual.global_.offheight, size)


class CameraRenderer(engine.Camera):
    """dm_control's camera of one fixed model camera, rendered again and again into its reused buffers, with a
    pose set for one render, and the scene's coverage read with the colour when the backdrop is hidden.

    :param physics: the dm_control physics, set up by :func:`configure_offscreen_buffer` with the same ``render``
    :param size: image height and width in pixels
    :param camera_id: index of a camera defined in the model
    :param hide_backdrop: draw neither the skybox nor any plane geom (the floor), and read the coverage with the
        colour (:meth:`render_with_coverage`), to put a background behind the scene
    :param render: ``"benchmark"`` (the model's shadows, reflections, multisampling) or ``"fast"`` (none of them)
    """

    # MuJoCo draws geom groups 0..5; moving the planes to the last one lets one option hide them.
    _HIDDEN_GROUP = mujoco.mjNGROUP - 1

    def __init__(
        self, physics: Physics, size: int, camera_id: int, hide_backdrop: bool = False, render: str = "benchmark"
    ) -> None:
        model = physics.model
        if not 0 <= camera_id < model.ncam:
            raise ValueError(f"camera_id must be in 0..{model.ncam - 1} for this model, got {camera_id!r}")
        self.render_setting = check_render(render)
        super().__init__(physics, height=size, width=size, camera_id=camera_id)
        self.camera_id = camera_id
        self.size = size
        self.hide_backdrop = bool(hide_backdrop)
        # Set on this camera's own scene once: set and restored around every render (dm_control's
        # render_flag_overrides), they make each render measurably slower.
        if render == "fast":
            self.scene.flags[mujoco.mjtRndFlag.mjRND_SHADOW] = 0
            self.scene.flags[mujoco.mjtRndFlag.mjRND_REFLECTION] = 0
        if self.hide_backdrop:
            planes = model.geom_type == mujoco.mjtGeom.mjGEOM_PLANE
            if np.any(model.geom_group[~planes] == self._HIDDEN_GROUP):
                raise RuntimeError(f"geom group {self._HIDDEN_GROUP} is in use; cannot hide the floor with it")
            model.geom_group[planes] = self._HIDDEN_GROUP
            self.option.geomgroup[self._HIDDEN_GROUP] = 0
            self.scene.flags[mujoco.mjtRndFlag.mjRND_SKYBOX] = 0
            # dm_control's Camera reads the colour into this buffer; with the coverage it reads RGBA, in one read.
            self._rgb_buffer = np.empty((size, size, 4), dtype=np.uint8)
        # Textures sent to the GPU and frames read back since the camera was made (each a synchronous transfer).
        self.uploads = 0
        self.readbacks = 0

    def upload_texture(self, texture_id: int, name: int | None = None) -> None:
        """Send texture ``texture_id`` of the model (after its ``tex_data`` or size changed) to the GPU: into the
        model texture's own OpenGL texture, or into ``name`` (one of :meth:`make_textures`), as MuJoCo sends it
        (the same format, sampling and mip levels), leaving the model texture's own untouched.

        :param texture_id: the model's texture
        :param name: an OpenGL texture name of this camera's context, or None for the model texture's own
        """
        contexts = self._physics.contexts
        context = contexts.mujoco.ptr
        own = context.texture[texture_id]
        with contexts.gl.make_current() as ctx:
            # mjr_uploadTexture fills the OpenGL texture the context names for the model's texture.
            if name is not None:
                context.texture[texture_id] = name
            try:
                ctx.call(mujoco.mjr_uploadTexture, self._physics.model.ptr, context, texture_id)
            finally:
                context.texture[texture_id] = own
        self.uploads += 1

    def make_textures(self, count: int) -> list[int]:
        """``count`` new OpenGL texture names in this camera's context, for :meth:`upload_texture` to fill and
        :meth:`texture_override` to draw. They live until :meth:`delete_textures` or the end of the context
        (``physics.free()``).
        """
        # Imported here, once dm_control has chosen the OpenGL platform of MUJOCO_GL (PyOpenGL binds it at import).
        from OpenGL import GL

        with self._physics.contexts.gl.make_current() as ctx:
            names = ctx.call(GL.glGenTextures, count)
        return [int(name) for name in np.atleast_1d(names)]

    def delete_textures(self, names: Sequence[int]) -> None:
        """Free OpenGL textures of :meth:`make_textures` (their GPU memory)."""
        from OpenGL import GL

        if len(names):
            with self._physics.contexts.gl.make_current() as ctx:
                ctx.call(GL.glDeleteTextures, np.asarray(names, dtype=np.uint32))

    def texture_override(self, texture_id: int, name: int) -> tuple[np.ndarray, int, np.uint32]:
        """A :meth:`render` override that draws the model's texture ``texture_id`` from the OpenGL texture ``name``
        (one of :meth:`make_textures`, filled by :meth:`upload_texture`) for one render: switching textures by name
        sends nothing to the GPU. The context names its own texture again after the render, so it frees its own.
        """
        return (self._physics.contexts.mujoco.ptr.texture, texture_id, np.uint32(name))

    def _draw(self, overrides: Sequence[tuple[np.ndarray, int, np.ndarray]]) -> np.ndarray:
        """dm_control's render of the current state with ``overrides`` set during it: a view of the reused buffer,
        top row first (RGBA with the backdrop hidden)."""
        context = self._physics.contexts.mujoco.ptr
        rgb_format = context.readPixelFormat
        saved = [(array, row, array[row].copy()) for array, row, _ in overrides]
        try:
            for array, row, value in overrides:
                array[row] = value
            if self.hide_backdrop:
                # mjr_readPixels reads in the context's format: RGBA for this render only, since dm_control's
                # physics.render shares the context and reads 3 bytes a pixel.
                context.readPixelFormat = _GL_RGBA
            self.readbacks += 1
            return super().render()
        finally:
            context.readPixelFormat = rgb_format
            for array, row, value in saved:
                array[row] = value

    # Not dm_control's options (overlays, depth, segmentation): the pose of this render.
    def render(self, overrides: Sequence[tuple[np.ndarray, int, np.ndarray]] = ()) -> np.ndarray:  # type: ignore[override]
        """Render the current state.

        :param overrides: ``(array, row, value)`` triples of ``physics.data`` arrays (a camera's
            ``cam_xpos``/``cam_xmat``, a site's ``site_xpos``) or of the context's texture names
            (:meth:`texture_override`) set for this render only and restored after it, so a moved camera changes
            the view and never the simulation
        :return: a new uint8 (H, W, 3) RGB image, top row first
        """
        return self._draw(overrides)[..., :3].copy()

    def render_with_coverage(self) -> tuple[np.ndarray, np.ndarray]:
        """Render the current state with the backdrop hidden (``hide_backdrop=True``).

        :return: the uint8 (H, W, 3) RGB image and the uint8 (H, W) coverage (alpha: 0 where nothing was drawn,
            255 where the scene covers the whole pixel), top row first: views of the renderer's buffer, valid
            until its next render
        """
        if not self.hide_backdrop:
            raise RuntimeError("render_with_coverage needs a renderer made with hide_backdrop=True")
        frame = self._draw(())
        return frame[..., :3], frame[..., 3]
