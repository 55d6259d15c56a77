"""The wrapping of a run's vector envs, as rl-zoo3 wraps its training envs: evaluation, the figures and training
wrap alike (this module needs SB3, not rl-zoo3)."""

from __future__ import annotations

from gymnasium import spaces
from stable_baselines3.common.preprocessing import is_image_space, is_image_space_channels_first
from stable_baselines3.common.vec_env import VecEnv, VecFrameStack, VecTransposeImage


def wrap_like_training(env: VecEnv, frame_stack: int | None, normalize=None, eval_env: bool = True) -> VecEnv:
    """Frame stacking and channel-first transposition, as rl-zoo3 wraps its training envs."""
    if normalize is not None:
        env = normalize(env, eval_env)
    if frame_stack:
        env = VecFrameStack(env, frame_stack)
    space = env.observation_space
    if isinstance(space, spaces.Box) and is_image_space(space) and not is_image_space_channels_first(space):
        env = VecTransposeImage(env)
    return env
