"""Causal World tasks (the paper's case-study benchmark) as gymnasium envs whose domains differ in one object property.

- ``SGFD/CW-picking-v0``: lift the block; its mass changes across domains (paper section 5.3, Fig. 4).
- ``SGFD/CW-pushing-v0``: push the block to the goal; its size (edge length) changes (appendix C.1).

Each property has ten settings, spread evenly over Causal World's own range for it (its variable spaces
A and B together: mass 0.015..0.1 kg, edge 0.055..0.095 m), and this package's own splits (those of the MT ids'
scaled family): training settings 1, 2, 4, 5, interpolation 3, extrapolation 10 (:mod:`sgfd_envs.morphology`).

Causal World 1.2 speaks gym's old API (``reset() -> obs``, ``step() -> 4-tuple``); shimmy's
``GymV21CompatibilityV0`` turns it into gymnasium's. It is optional: ``pip install -e ".[causalworld]"``.
This module imports it only when an env is made, so registering the ids never needs it.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import gymnasium as gym
import numpy as np

from sgfd_envs.morphology import N_SETTINGS, PACKAGE_SPLIT_SETTINGS, check_setting, select_setting

INSTALL_HINT = 'Causal World ids need the optional extra: pip install -e ".[causalworld]"'
OBJECT = "tool_block"
# Causal World's structured observation entries, in its order, with their sizes (1.2; checked at make time).
ROBOT_OBSERVATIONS = {"time_left_for_task": 1, "joint_positions": 9, "joint_velocities": 9, "end_effector_positions": 9}
OBJECT_OBSERVATIONS = {
    "type": 1,
    "size": 3,
    "cartesian_position": 3,
    "orientation": 4,
    "linear_velocity": 3,
    "angular_velocity": 3,
}
GOAL_OBSERVATIONS = {"type": 1, "size": 3, "cartesian_position": 3, "orientation": 4}


@dataclass(frozen=True)
class Variation:
    """The object property a Causal World id varies across its domains.

    :param parameter: name of the property as a feature, e.g. ``"tool_block_mass"``
    :param variable: Causal World's name of the block variable (``"mass"`` or ``"size"``)
    :param low: value at setting 1
    :param high: value at setting 10
    """

    parameter: str
    variable: str
    low: float
    high: float

    def value(self, setting: int) -> float:
        """The property at one setting (1..10), evenly spaced from ``low`` to ``high``.

        :param setting: an int in 1..10
        """
        step = (self.high - self.low) / (N_SETTINGS - 1)
        return round(self.low + step * (check_setting(setting) - 1), 6)

    def intervention(self, setting: int) -> dict[str, dict[str, Any]]:
        """Causal World's intervention dict that sets the property (a cube for sizes).

        :param setting: an int in 1..10
        """
        value = self.value(setting)
        return {OBJECT: {self.variable: np.full(3, value) if self.variable == "size" else value}}


# Task name -> the property it varies. Ranges: Causal World's variable spaces A and B of the tool block.
VARIATIONS: dict[str, Variation] = {
    "picking": Variation("tool_block_mass", "mass", 0.015, 0.1),
    "pushing": Variation("tool_block_size", "size", 0.055, 0.095),
}


def _state_names() -> list[str]:
    names = []
    groups = [("", ROBOT_OBSERVATIONS), ("tool_block_", OBJECT_OBSERVATIONS), ("goal_block_", GOAL_OBSERVATIONS)]
    for prefix, sizes in groups:
        for key, size in sizes.items():
            names += [f"{prefix}{key}"] if size == 1 else [f"{prefix}{key}[{i}]" for i in range(size)]
    return names


STATE_NAMES: tuple[str, ...] = tuple(_state_names())


def _import_causal_world() -> tuple[Any, Any, Any]:
    try:
        from causal_world.envs import CausalWorld
        from causal_world.task_generators import generate_task
        from shimmy import GymV21CompatibilityV0
    except ImportError as error:
        raise ImportError(f"{INSTALL_HINT} ({error})") from error
    return CausalWorld, generate_task, GymV21CompatibilityV0


class CausalWorldEnv(gym.Env[np.ndarray, np.ndarray]):
    """A Causal World task with one block property fixed per domain, as a gymnasium env.

    Observations are Causal World's structured ones (float32, normalised to [-1, 1] except constants),
    named by :data:`STATE_NAMES`. Episodes end only at Causal World's time limit (its tasks never report
    success as termination), so they end with ``truncated=True``. Every step and reset puts the domain
    label in ``info["domain"]``.

    :param task: ``"picking"`` or ``"pushing"``
    :param split: ``"train"``, ``"interpolation"`` or ``"extrapolation"``
    :param domain: index of the setting within the split
    :param setting: the setting 1..10 itself instead of ``split``/``domain`` (the env is then domain 0 of no split)
    :param split_settings: replace the settings of some splits, e.g. ``{"train": (1, 2, 3, 4)}``
    :param obs_type: only ``"state"`` (the case study uses states with physical meaning)
    :param skip_frame: simulator steps of 4 ms per agent step (Causal World's default 10)
    :param render_mode: None or ``"rgb_array"`` (Causal World's view from above)
    """

    # gymnasium's Env declares metadata an instance attribute (wrappers and envs may set it per env): no ClassVar.
    metadata: dict[str, Any] = {"render_modes": ["rgb_array"], "render_fps": 25}  # noqa: RUF012

    def __init__(
        self,
        task: str,
        split: str | None = None,
        domain: int | None = None,
        *,
        setting: int | None = None,
        split_settings: Mapping[str, Sequence[int]] | None = None,
        obs_type: str = "state",
        skip_frame: int = 10,
        render_mode: str | None = None,
    ) -> None:
        if task not in VARIATIONS:
            raise ValueError(f"task must be one of {tuple(VARIATIONS)}, got {task!r}")
        if obs_type != "state":
            raise ValueError(f"obs_type must be 'state' for Causal World ids, got {obs_type!r}")
        if render_mode not in (None, *self.metadata["render_modes"]):
            raise ValueError(f"render_mode must be None or one of {self.metadata['render_modes']}, got {render_mode!r}")
        if isinstance(skip_frame, bool) or not isinstance(skip_frame, int) or skip_frame < 1:
            raise ValueError(f"skip_frame must be a positive int, got {skip_frame!r}")
        self.split, self.domain, self.n_domains, self.setting = select_setting(
            split, domain, setting, split_settings, ids="Causal World ids", defaults=PACKAGE_SPLIT_SETTINGS
        )
        self.task = task
        self.variation = VARIATIONS[task]
        self.render_mode = render_mode
        self.state_names = STATE_NAMES

        causal_world, generate_task, compatibility = _import_causal_world()
        world = causal_world(
            task=generate_task(task_generator_id=task),
            skip_frame=skip_frame,
            enable_visualization=False,
            observation_mode="structured",
        )
        # The starting state, not a one-off intervention: Causal World's reset() keeps it.
        success, _ = world.set_starting_state(self.variation.intervention(self.setting))
        if not success:
            world.close()
            raise RuntimeError(f"Causal World refused {self.variation.parameter}={self.varied_value} for {task}")
        self._env = compatibility(env=world)
        size = self._env.observation_space.shape[0]
        if size != len(STATE_NAMES):
            self._env.close()
            raise RuntimeError(
                f"Causal World's {task} observation has {size} entries, expected {len(STATE_NAMES)} "
                "(its layout changed; this wrapper knows causal-world 1.2)"
            )
        space = self._env.observation_space
        self.observation_space = gym.spaces.Box(
            space.low.astype(np.float32), space.high.astype(np.float32), dtype=np.float32
        )
        action = self._env.action_space
        self.action_space = gym.spaces.Box(
            action.low.astype(np.float32), action.high.astype(np.float32), dtype=np.float32
        )
        self._closed = False

    @property
    def varied_parameter(self) -> str:
        """Name of the property that differs between domains, e.g. ``"tool_block_mass"``."""
        return self.variation.parameter

    @property
    def varied_value(self) -> float:
        """Its value in this domain (kg for mass, m for the cube's edge)."""
        return self.variation.value(self.setting)

    @property
    def world(self) -> Any:
        """The wrapped ``causal_world.envs.CausalWorld``."""
        return self._env.gym_env

    def _info(self) -> dict[str, int]:
        return {"domain": self.domain, "setting": self.setting}

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[np.ndarray, dict[str, int]]:
        """Start an episode from the domain's starting state.

        :param seed: seeds Causal World (which also seeds numpy's global RNG) and this env's ``np_random``
        :param options: unused
        """
        super().reset(seed=seed)
        obs, _ = self._env.reset(seed=seed)
        return np.asarray(obs, dtype=np.float32), self._info()

    def step(self, action: np.ndarray) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        """One agent step of ``skip_frame`` simulator steps.

        :param action: joint positions, normalised to [-1, 1]
        """
        obs, reward, terminated, truncated, info = self._env.step(np.asarray(action, dtype=np.float64))
        # Causal World's `done` is its time limit alone (BaseTask.is_done is always False): a truncation.
        return (
            np.asarray(obs, dtype=np.float32),
            float(reward),
            False,
            bool(terminated or truncated),
            {**self._info(), "fractional_success": float(info.get("fractional_success", 0.0))},
        )

    def render(self) -> np.ndarray | None:
        """Causal World's RGB view from above, or None without ``render_mode``."""
        if self.render_mode is None:
            return None
        return np.asarray(self.world.render(), dtype=np.uint8)

    def close(self) -> None:
        """Disconnect the simulator; calling it twice is fine."""
        if not self._closed:
            self._closed = True
            self._env.close()
