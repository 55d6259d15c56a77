"""One camera of a dm_control Physics rendered into reused buffers, as the benchmarks render it or faster.

``render="benchmark"`` (the default) draws what dm_control's ``physics.render(h, w, camera_id)`` draws, with the
model's own visual settings: shadows, reflections and the model's multisampling (``offsamples``, 4 in dm_control's
tasks). DMC-GB, DMC-GB2, the Distracting Control Suite and dmc2gym (DBC, AMBS) all render that way.
``render="fast"`` turns shadows, reflections and multisampling off.

With a hidden backdrop (the floor and the skybox, or the skybox only) the renderer also reads the alpha channel
of the same pass: OpenGL clears it to 0, every opaque fragment writes 1, and the multisample resolve averages
the samples, so alpha is the share of a pixel the drawn scene covers (0, 1/4, ..., 1 with 4 samples), and the
colour is already weighted by it. Putting a picture behind the scene is then ``colour + (1 - alpha) * picture``
(:func:`sgfd_envs.backgrounds.composite`), which is what the multisampled render of that picture drawn behind
the scene gives.
"""

from __future__ import annotations

from collections.abc import Sequence

import mujoco
import numpy as np
from dm_control.mujoco import Physics, wrapper

RENDER_MODES = ("benchmark", "fast")
HIDE_MODES = ("nothing", "sky", "backdrop")


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


def _read_alpha(context: mujoco.MjrContext, size: int) -> np.ndarray:
    """The alpha channel of the last frame, bottom row first; call it right after ``mjr_readPixels``, which has
    resolved the multisampled buffer into ``offFBO_r``."""
    # Imported here: PyOpenGL must be loaded after dm_control has chosen its platform (EGL, OSMesa, GLFW).
    from OpenGL import GL

    resolved = context.offSamples > 0
    if resolved:
        GL.glBindFramebuffer(GL.GL_READ_FRAMEBUFFER, context.offFBO_r)
    data = GL.glReadPixels(0, 0, size, size, GL.GL_ALPHA, GL.GL_UNSIGNED_BYTE)
    if resolved:
        GL.glBindFramebuffer(GL.GL_FRAMEBUFFER, context.offFBO)
    return np.frombuffer(data, dtype=np.uint8).reshape(size, size)


class CameraRenderer:
    """Renders one fixed camera of a Physics into reused buffers.

    :param physics: the dm_control physics, set up by :func:`configure_offscreen_buffer` with the same ``render``
    :param size: image height and width in pixels
    :param camera_id: index of a camera defined in the model
    :param hide: what is not drawn and reported as uncovered: ``"nothing"``, ``"sky"`` (the skybox) or
        ``"backdrop"`` (the skybox and every plane geom)
    :param render: ``"benchmark"`` (the model's shadows, reflections, multisampling) or ``"fast"`` (none of them)
    """

    # MuJoCo draws geom groups 0..5; moving the planes to the last one lets one option hide them.
    _HIDDEN_GROUP = mujoco.mjNGROUP - 1

    def __init__(
        self, physics: Physics, size: int, camera_id: int, hide: str = "nothing", render: str = "benchmark"
    ) -> None:
        model = physics.model
        if not 0 <= camera_id < model.ncam:
            raise ValueError(f"camera_id must be in 0..{model.ncam - 1} for this model, got {camera_id!r}")
        if hide not in HIDE_MODES:
            raise ValueError(f"hide must be one of {HIDE_MODES}, got {hide!r}")
        self.render_setting = check_render(render)
        self._physics = physics
        self.camera_id = camera_id
        self.size = size
        self._scene = wrapper.MjvScene(model=model)
        self._option = wrapper.MjvOption()
        self._perturb = wrapper.MjvPerturb()
        self._camera = wrapper.MjvCamera()
        self._camera.type = mujoco.mjtCamera.mjCAMERA_FIXED
        self._camera.fixedcamid = camera_id
        if render == "fast":
            self._scene.flags[mujoco.mjtRndFlag.mjRND_SHADOW] = 0
            self._scene.flags[mujoco.mjtRndFlag.mjRND_REFLECTION] = 0
        if hide == "backdrop":
            planes = model.geom_type == mujoco.mjtGeom.mjGEOM_PLANE
            if np.any(model.geom_group[~planes] == self._HIDDEN_GROUP):
                raise RuntimeError(f"geom group {self._HIDDEN_GROUP} is in use; cannot hide the floor with it")
            model.geom_group[planes] = self._HIDDEN_GROUP
            self._option.geomgroup[self._HIDDEN_GROUP] = 0
        if hide != "nothing":
            self._scene.flags[mujoco.mjtRndFlag.mjRND_SKYBOX] = 0
        self._reads_coverage = hide != "nothing"
        self._rect = mujoco.MjrRect(0, 0, size, size)
        self._rgb = np.empty((size, size, 3), dtype=np.uint8)
        self._coverage: np.ndarray | None = None
        contexts = physics.contexts
        with contexts.gl.make_current() as ctx:
            ctx.call(mujoco.mjr_setBuffer, mujoco.mjtFramebuffer.mjFB_OFFSCREEN, contexts.mujoco.ptr)

    def _draw_and_read(self) -> None:
        context = self._physics.contexts.mujoco.ptr
        mujoco.mjr_render(self._rect, self._scene.ptr, context)
        mujoco.mjr_readPixels(self._rgb, None, self._rect, context)
        if self._reads_coverage:
            self._coverage = _read_alpha(context, self.size)

    def upload_texture(self, texture_id: int) -> None:
        """Send texture ``texture_id`` of the model (after its ``tex_data`` or size changed) to the GPU."""
        contexts = self._physics.contexts
        with contexts.gl.make_current() as ctx:
            ctx.call(mujoco.mjr_uploadTexture, self._physics.model.ptr, contexts.mujoco.ptr, texture_id)

    def render(
        self, overrides: Sequence[tuple[np.ndarray, int, np.ndarray]] = ()
    ) -> tuple[np.ndarray, np.ndarray | None]:
        """Render the current state.

        :param overrides: ``(array, row, value)`` triples of ``physics.data`` arrays (a camera's
            ``cam_xpos``/``cam_xmat``, a site's ``site_xpos``) set for this render only and restored after it,
            so a moved camera changes the view and never the simulation
        :return: a new uint8 (H, W, 3) RGB image, top row first, and when something is hidden the uint8 (H, W)
            coverage (alpha: 0 where nothing was drawn, 255 where the scene covers the whole pixel), else None
        """
        physics = self._physics
        saved = [(array, row, array[row].copy()) for array, row, _ in overrides]
        try:
            for array, row, value in overrides:
                array[row] = value
            mujoco.mjv_updateScene(
                physics.model.ptr,
                physics.data.ptr,
                self._option.ptr,
                self._perturb.ptr,
                self._camera.ptr,
                mujoco.mjtCatBit.mjCAT_ALL,
                self._scene.ptr,
            )
        finally:
            for array, row, value in saved:
                array[row] = value
        with physics.contexts.gl.make_current() as ctx:
            ctx.call(self._draw_and_read)
        # OpenGL's first row is the bottom of the image.
        rgb = self._rgb[::-1].copy()
        if self._coverage is None:
            return rgb, None
        return rgb, self._coverage[::-1].copy()
