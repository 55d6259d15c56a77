"""Shared pytest setup."""

# sgfd_envs picks MuJoCo's headless OpenGL backend (EGL) unless MUJOCO_GL is set; that must happen
# before any test module imports dm_control, so import it before collection.
import sgfd_envs  # noqa: F401
