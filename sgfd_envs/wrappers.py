"""Small single-purpose gymnasium wrappers of the SGFD envs."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
from gymnasium import spaces


def scale_to_unit(value: float, low: float, high: float) -> float:
    """``value`` mapped linearly from [low, high] to [-1, 1].

    :param value: a parameter value
    :param low: the value mapped to -1 (setting 1)
    :param high: the value mapped to 1 (setting 10)
    """
    if not high > low:
        raise ValueError(f"high must be greater than low, got low={low!r}, high={high!r}")
    return 2.0 * (value - low) / (high - low) - 1.0


def check_observe_parameter(observe_parameter: bool, obs_type: str) -> None:
    """Refuse ``observe_parameter`` unless it is a bool, and on pixels (where the parameter already shows).

    :param observe_parameter: the env kwarg
    :param obs_type: the env's observation type
    """
    if not isinstance(observe_parameter, bool):
        raise ValueError(f"observe_parameter must be True or False, got {observe_parameter!r}")
    if observe_parameter and obs_type != "state":
        raise ValueError(
            f"observe_parameter=True needs obs_type='state', got obs_type={obs_type!r} (on pixels the "
            "morphology already shows in the image)"
        )


class ObserveParameter(gym.ObservationWrapper[np.ndarray, np.ndarray, np.ndarray]):
    """Appends the domain's varied parameter to a flat state observation: the context made visible, as in
    CARL (Benjamins et al., 2023). On pixels a changed morphology shows in the image; on states it does not,
    so state-based agents need it to tell the domains apart.

    :param env: an env with a flat ``Box`` observation space
    :param value: the parameter, already scaled (see :func:`scale_to_unit`)
    :param name: its name, e.g. ``"torso_length"`` (kept as ``parameter_name``)
    """

    def __init__(self, env: gym.Env, value: float, name: str) -> None:
        super().__init__(env)
        space = env.observation_space
        if not isinstance(space, spaces.Box) or len(space.shape) != 1:
            raise ValueError(f"observe_parameter needs a flat Box observation space, got {space}")
        self.parameter_name = name
        self.parameter_value = float(value)
        self.observation_space = spaces.Box(
            np.append(space.low, -1.0).astype(space.dtype),
            np.append(space.high, 1.0).astype(space.dtype),
            dtype=space.dtype,  # type: ignore[arg-type]
        )

    def observation(self, observation: np.ndarray) -> np.ndarray:
        return np.append(observation, self.parameter_value).astype(self.observation_space.dtype, copy=False)


# Agent steps by which the SGFD authors' MT observations lag (see FrameLag).
AUTHORS_FRAME_LAG = 2


class FrameLag(gym.Wrapper[np.ndarray, np.ndarray, np.ndarray, np.ndarray]):
    """Observations ``lag`` agent steps old: at step t the observation of step max(t - lag, 0), the reset's for the
    first ``lag`` steps; rewards, ends and infos are the current step's.

    It reproduces a defect of the SGFD authors' published code on the MT tasks: their ``utils.FrameStack`` wraps
    mtenv's envs, whose observations are already stacks of 3 frames, and returns the oldest of its 3 entries, so
    their agent saw the stack of two agent steps earlier. Stacked by the zoo (``frame_stack: 3``), the frames of
    this wrapper give that stack.

    :param env: the env
    :param lag: agent steps (the authors' code: :data:`AUTHORS_FRAME_LAG`)
    """

    def __init__(self, env: gym.Env, lag: int = AUTHORS_FRAME_LAG) -> None:
        super().__init__(env)
        if isinstance(lag, bool) or not isinstance(lag, int) or lag < 1:
            raise ValueError(f"lag must be a positive int, got {lag!r}")
        self.lag = lag
        # The last lag + 1 observations, oldest first: a plain list, so that a resumed run gets it back
        # (sgfd_envs.state.ResumableState).
        self.history: list[np.ndarray] = []

    def reset(self, **kwargs):  # type: ignore[no-untyped-def]
        observation, info = self.env.reset(**kwargs)
        self.history = [observation] * (self.lag + 1)
        return observation, info

    def step(self, action):  # type: ignore[no-untyped-def]
        observation, reward, terminated, truncated, info = self.env.step(action)
        self.history = [*self.history[1:], observation]
        # a copy: the reset's observation and the first steps' are one object in the history
        return self.history[0].copy(), reward, terminated, truncated, info
