"""What the agents say about the observations they are given, each in one line: a space described without its
bounds' arrays, and a warning when a policy without convolutions would flatten images, pointing at the user's
line (the first frame outside this package, Stable-Baselines3 and gymnasium)."""

from __future__ import annotations

import os
import sys
import warnings
from pathlib import Path

import gymnasium
import stable_baselines3
from gymnasium import spaces
from stable_baselines3.common.policies import BasePolicy
from stable_baselines3.common.preprocessing import is_image_space
from torch import nn

# The code between a user's call and a warning: frames in these folders are not the user's.
LIBRARY_FOLDERS = tuple(
    f"{Path(str(file)).resolve().parent}{os.sep}"
    for file in (Path(__file__).parent, stable_baselines3.__file__, gymnasium.__file__)
)


def user_stacklevel(folders: tuple[str, ...] = LIBRARY_FOLDERS) -> int:
    """The ``stacklevel`` that makes a warning raised by the caller of this function name the first frame outside
    ``folders``: the user's line rather than the library's.

    :param folders: the library's folders (resolved paths)
    """
    frame, level = sys._getframe(1), 1
    while frame.f_back is not None and str(Path(frame.f_code.co_filename).resolve()).startswith(folders):
        frame, level = frame.f_back, level + 1
    return level


def describe_space(space: spaces.Space) -> str:
    """A space in one line, without the arrays of its bounds: ``Box(shape=(25,), dtype=float32)``."""
    if isinstance(space, spaces.Box):
        return f"Box(shape={space.shape}, dtype={space.dtype})"
    if isinstance(space, spaces.Dict):
        return "Dict(" + ", ".join(f"{key}: {describe_space(value)}" for key, value in space.spaces.items()) + ")"
    return " ".join(str(space).split())


class FlattenedImagesWarning(UserWarning):
    """A policy without convolutions reads image observations: it flattens every pixel into an MLP."""


def warn_if_flattening_images(policy: BasePolicy) -> None:
    """Warn (one line, at the user's line) when ``policy`` has no convolution but its observations are images, e.g.
    ``MlpPolicy`` on an env whose default observations are pixels.

    :param policy: the model's policy, built
    """
    space = policy.observation_space
    if not is_image_space(space, check_channels=False):
        return
    if any(isinstance(module, nn.Conv2d) for module in policy.modules()):
        return
    warnings.warn(
        f"{type(policy).__name__} flattens the {describe_space(space)} image observations into an MLP; for pixels use "
        "'CnnPolicy' (or give the env obs_type='state' for states)",
        FlattenedImagesWarning,
        stacklevel=user_stacklevel(),
    )
