"""A dm_control task as a gymnasium env: action repeat, pixels or state, headless rendering.

Rendering (:mod:`sgfd_envs.rendering`) reuses one MuJoCo scene per env and draws what dm_control's
``physics.render`` draws (``render="benchmark"``, the default) or the same without shadows, reflections and
multisampling (``render="fast"``). A background source goes into the whole render by the SGFD authors' colour key
(``compositing="colour_key"``, :func:`~sgfd_envs.backgrounds.colour_key`), or behind the scene by the pass's coverage
with the floor (every plane geom) and the skybox hidden (``"matte"``, :func:`~sgfd_envs.backgrounds.composite`).

The benchmark ids (:mod:`sgfd_envs.benchmarks`) pass a :class:`Distraction` instead: it changes what is
drawn (materials, textures, the camera's pose for one render) and never the physics.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Protocol

import gymnasium as gym
import mujoco
import numpy as np
from dm_control.mujoco import Physics
from dm_control.rl import control
from gymnasium import spaces

from sgfd_envs.backgrounds import BackgroundSource, colour_key, composite
from sgfd_envs.limits import check_image_size_limit
from sgfd_envs.rendering import CameraRenderer, check_render, configure_offscreen_buffer
from sgfd_envs.state import HasState

OBS_TYPES = ("pixels", "state")
COMPOSITINGS = ("colour_key", "matte")


def check_image_size(image_size: int) -> int:
    """Return ``image_size`` if it is a positive int of at most :data:`~sgfd_envs.limits.MAX_IMAGE_SIZE`, else raise.

    :param image_size: height and width of images in pixels
    """
    if isinstance(image_size, bool) or not isinstance(image_size, (int, np.integer)) or image_size < 1:
        raise ValueError(f"image_size must be a positive int, got {image_size!r}")
    return check_image_size_limit(int(image_size))


@dataclass(frozen=True)
class DomainLabel:
    """Which domain of which split an env is, and for MT ids its morphology.

    :param split: split name (``"train"``, ``"test"``, ``"interpolation"``, ...), None for a
        single MT ``setting`` picked outside the splits
    :param domain: index of the domain within the split (``info["domain"]``)
    :param n_domains: number of domains in the split
    :param setting: MT setting 1..10, None for background ids
    :param morphology_parameter: name of the varied length, e.g. ``"torso_length"`` (MT only)
    :param morphology_value: that length in metres (MT only)
    """

    split: str | None
    domain: int
    n_domains: int
    setting: int | None = None
    morphology_parameter: str | None = None
    morphology_value: float | None = None


class Distraction(Protocol):
    """A benchmark's change to the picture (colours, textures, camera pose, a video behind the robot).

    It is made for one env's physics. It may edit the model's visual fields (materials, textures) and the
    poses the renderer uses for one render; the physics, and so the task and its rewards, stay those of
    dm_control. Its randomness comes from the generator the env hands it, separate from the physics' seed.
    """

    def start_episode(self, rng: np.random.Generator, reseeded: bool) -> None:
        """Draw this episode's distraction, after dm_control's reset.

        :param rng: the distraction's generator
        :param reseeded: whether ``reset(seed=...)`` just reseeded ``rng`` (sequences restart)
        """
        ...

    def control_step(self) -> None:
        """Advance a dynamic distraction after one dm_control step."""
        ...

    def render(self, renderer: CameraRenderer, agent_step: int) -> np.ndarray:
        """The frame of the current state: uint8 (H, W, 3).

        :param renderer: the env's renderer, which draws the whole scene (floor and skybox included)
        :param agent_step: agent steps since the reset
        """
        ...


# Offset of the distraction's seed stream: reset(seed=s) seeds the physics from s and the distraction from
# (s, this), so a seed gives the same physics in every split.
DISTRACTION_SEED_STREAM = 0x5EED
# The model fields a dm_control task may draw anew each episode (reacher's target place and size, finger's turn
# target): part of an env's state, since the simulator's state does not hold them.
TASK_MODEL_FIELDS = ("geom_pos", "geom_size", "site_pos", "site_size")


class DMCEnv(gym.Env[np.ndarray, np.ndarray]):
    """A dm_control task as a gymnasium env.

    The env never truncates: the registered ids end their episodes with gymnasium's ``TimeLimit`` (1000
    dm_control steps, i.e. 500 agent steps at action repeat 2). ``terminated`` only if dm_control's
    discount is 0.
    The reward of an agent step is the sum over its repeats. ``reset(seed=s)`` seeds the task's
    initial state and the background start, so the same actions reproduce the same episode.

    :param dm_env: dm_control environment with no time limit (see :func:`sgfd_envs.domains.load`)
    :param label: split, domain and morphology of this env
    :param action_repeat: dm_control steps per agent step
    :param obs_type: ``"pixels"`` (uint8 (size, size, 3)) or ``"state"`` (float32 flat vector of
        dm_control's observation dict, in its order)
    :param image_size: height and width of pixel observations and renders
    :param background: source of background frames, None to render floor and skybox
    :param compositing: how a background goes into the render: ``"matte"`` (behind the scene by its coverage, the
        floor and the skybox hidden) or ``"colour_key"`` (the SGFD authors' mask of the blue-dominant pixels)
    :param camera_id: model camera to render
    :param render_mode: None or ``"rgb_array"`` (``render()`` returns the current frame)
    :param distraction: a benchmark's visual distraction (instead of ``background``); its generator is
        seeded from ``(seed, DISTRACTION_SEED_STREAM)`` at ``reset(seed=seed)``
    :param render: ``"benchmark"`` (dm_control's ``physics.render`` with the model's shadows, reflections and
        multisampling) or ``"fast"`` (none of the three; see :mod:`sgfd_envs.rendering`)
    :param stand_in: what the env shows in place of a benchmark's data (e.g. ``"procedural clips for data_dir"``),
        None when it shows the data itself; ``info["stand_in"]`` says whether there is one
    """

    # gymnasium's Env declares metadata an instance attribute (__init__ sets this env's render_fps): no ClassVar.
    metadata: dict[str, Any] = {"render_modes": ["rgb_array"], "render_fps": 25}  # noqa: RUF012

    def __init__(
        self,
        dm_env: control.Environment,
        label: DomainLabel,
        *,
        action_repeat: int = 2,
        obs_type: str = "pixels",
        image_size: int = 84,
        background: BackgroundSource | None = None,
        camera_id: int = 0,
        render_mode: str | None = None,
        distraction: Distraction | None = None,
        render: str = "benchmark",
        stand_in: str | None = None,
        compositing: str = "matte",
    ) -> None:
        if compositing not in COMPOSITINGS:
            raise ValueError(f"compositing must be one of {COMPOSITINGS}, got {compositing!r}")
        if background is not None and distraction is not None:
            raise ValueError("give either background= or distraction=, not both")
        if obs_type not in OBS_TYPES:
            raise ValueError(f"obs_type must be one of {OBS_TYPES}, got {obs_type!r}")
        check_image_size(image_size)
        check_render(render)
        if isinstance(action_repeat, bool) or not isinstance(action_repeat, int) or action_repeat < 1:
            raise ValueError(f"action_repeat must be a positive int, got {action_repeat!r}")
        if render_mode not in (None, *self.metadata["render_modes"]):
            raise ValueError(f"render_mode must be None or one of {self.metadata['render_modes']}, got {render_mode!r}")
        self._dm_env = dm_env
        self.label = label
        self.action_repeat = action_repeat
        self.obs_type = obs_type
        self.image_size = int(image_size)
        self.render_mode = render_mode
        self._background = background
        self._matte = background is not None and compositing == "matte"
        self._distraction = distraction
        self._distraction_rng: np.random.Generator | None = None
        self._camera_id = camera_id
        self.render_setting = render
        self.stand_in = stand_in
        configure_offscreen_buffer(dm_env.physics, self.image_size, render)
        # Made on first render, so state-only envs never open an OpenGL context.
        self._renderer: CameraRenderer | None = None
        self.metadata = {**self.metadata, "render_fps": round(1 / (dm_env.control_timestep() * action_repeat))}

        action_spec = dm_env.action_spec()
        self.action_space = spaces.Box(
            action_spec.minimum.astype(np.float32), action_spec.maximum.astype(np.float32), dtype=np.float32
        )
        if obs_type == "pixels":
            self.observation_space = spaces.Box(0, 255, (self.image_size, self.image_size, 3), dtype=np.uint8)
        else:
            state_size = sum(int(np.prod(spec.shape)) for spec in dm_env.observation_spec().values())
            self.observation_space = spaces.Box(-np.inf, np.inf, (state_size,), dtype=np.float32)

        self._agent_steps = 0
        # Where the background sequence starts, as a fraction of its length: drawn at reset, turned into
        # a frame index only when a frame is needed, so state observations never decode a video.
        self._background_phase = 0.0
        self._last_frame: np.ndarray | None = None
        self._closed = False

    # --- labels -----------------------------------------------------------------------------------

    @property
    def domain(self) -> int:
        """Index of this env's domain within its split (``info["domain"]``)."""
        return self.label.domain

    @property
    def split(self) -> str | None:
        """Name of this env's split."""
        return self.label.split

    @property
    def n_domains(self) -> int:
        """Number of domains in this env's split."""
        return self.label.n_domains

    @property
    def setting(self) -> int | None:
        """MT setting 1..10 (None for background ids)."""
        return self.label.setting

    @property
    def morphology_parameter(self) -> str | None:
        """Name of the length MT varies, e.g. ``"torso_length"`` (None for background ids)."""
        return self.label.morphology_parameter

    @property
    def morphology_value(self) -> float | None:
        """The varied length in metres (None for background ids)."""
        return self.label.morphology_value

    @property
    def distraction(self) -> Distraction | None:
        """The benchmark distraction this env draws (None for SGFD's ids and a benchmark's train split)."""
        return self._distraction

    @property
    def renderer(self) -> CameraRenderer | None:
        """The env's camera (None before its first frame); its ``uploads`` and ``readbacks`` count the transfers."""
        return self._renderer

    @property
    def physics(self) -> Physics:
        """The dm_control physics (read it; changing it mid-episode breaks reproducibility)."""
        return self._dm_env.physics

    def _info(self) -> dict[str, Any]:
        info: dict[str, Any] = {"domain": self.label.domain, "stand_in": self.stand_in is not None}
        if self.label.setting is not None:
            info["setting"] = self.label.setting
        return info

    # --- observations -----------------------------------------------------------------------------

    def _frame(self) -> np.ndarray:
        if self._renderer is None:
            self._renderer = CameraRenderer(
                self._dm_env.physics,
                self.image_size,
                self._camera_id,
                hide_backdrop=self._matte,
                render=self.render_setting,
            )
        if self._distraction is not None:
            return self._distraction.render(self._renderer, self._agent_steps)
        if self._background is None:
            return self._renderer.render()
        start = int(self._background_phase * self._background.n_frames)
        background = self._background.frame(start + self._agent_steps)
        if not self._matte:
            return colour_key(self._renderer.render(), background)
        rgb, coverage = self._renderer.render_with_coverage()
        return composite(rgb, coverage, background)

    def _observation(self, dm_observation: dict[str, np.ndarray]) -> np.ndarray:
        if self.obs_type == "state":
            self._last_frame = None
            return np.concatenate([np.asarray(value, dtype=np.float32).ravel() for value in dm_observation.values()])
        self._last_frame = self._frame()
        return self._last_frame.copy()

    # --- gymnasium API ----------------------------------------------------------------------------

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[np.ndarray, dict[str, Any]]:
        """Start an episode; ``seed`` seeds the initial state and the background start (a distraction
        from a stream of its own).

        :param seed: seed of this env's ``np_random``
        :param options: unused
        """
        super().reset(seed=seed)
        self._dm_env.task.random.seed(int(self.np_random.integers(2**31)))
        time_step = self._dm_env.reset()
        self._agent_steps = 0
        if self._background is not None:
            self._background_phase = float(self.np_random.random())
        if self._distraction is not None:
            # A seed, or the first reset, (re)starts the distraction's generator and its sequences.
            if seed is not None or self._distraction_rng is None:
                entropy = None if seed is None else [int(seed), DISTRACTION_SEED_STREAM]
                self._distraction_rng = np.random.default_rng(entropy)
                self._distraction.start_episode(self._distraction_rng, reseeded=True)
            else:
                self._distraction.start_episode(self._distraction_rng, reseeded=False)
        return self._observation(time_step.observation), self._info()

    def step(self, action: np.ndarray) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        """Apply ``action`` for ``action_repeat`` dm_control steps (fewer if the episode terminates).

        :param action: float array in the action space
        """
        action = np.asarray(action, dtype=np.float64)
        if action.shape != self.action_space.shape or not np.isfinite(action).all():
            raise ValueError(
                f"action must be a finite array of shape {self.action_space.shape} (the action space), got "
                f"{np.array2string(action, precision=3, threshold=12)}"
            )
        reward = 0.0
        terminated = False
        for _ in range(self.action_repeat):
            time_step = self._dm_env.step(action)
            if self._distraction is not None:
                self._distraction.control_step()
            reward += time_step.reward or 0.0
            terminated = bool(time_step.discount == 0.0)
            if terminated:
                break
        self._agent_steps += 1
        return self._observation(time_step.observation), float(reward), terminated, False, self._info()

    # --- the state a resumed run continues from ---------------------------------------------------

    @property
    def state_unavailable(self) -> str | None:
        """Why ``get_state`` cannot give this env's state, or None when it can."""
        if self._distraction is not None and not isinstance(self._distraction, HasState):
            return f"its distraction ({type(self._distraction).__name__}) keeps a state get_state does not take"
        return None

    def get_state(self) -> dict[str, Any]:
        """Everything the env's next steps depend on: the simulator's integration state (MuJoCo's
        ``mjSTATE_INTEGRATION``: positions, velocities, activations, controls, time and the solver's warm start),
        the model fields a task sets per episode (:data:`TASK_MODEL_FIELDS`), dm_control's step counters, the
        task's and the env's random generators, the episode's agent steps and background phase, and the
        distraction's generator and state. ``set_state`` on an env made with the same arguments continues bit for
        bit. A distraction with state of its own beyond its generator (the benchmark ids')
        provides ``get_state``/``set_state``; one without them makes this raise ``NotImplementedError``.
        """
        if self.state_unavailable is not None:
            raise NotImplementedError(f"{self.spec.id if self.spec else 'this env'}: {self.state_unavailable}")
        physics = self._dm_env.physics
        distraction = self._distraction.get_state() if isinstance(self._distraction, HasState) else None
        return {
            "physics": physics.get_state(mujoco.mjtState.mjSTATE_INTEGRATION),
            "model": {name: getattr(physics.model, name).copy() for name in TASK_MODEL_FIELDS},
            "dm_env": {"step_count": self._dm_env._step_count, "reset_next_step": self._dm_env._reset_next_step},
            "task_random": self._dm_env.task.random.get_state(),
            "np_random": self.np_random.bit_generator.state,
            "agent_steps": self._agent_steps,
            "background_phase": self._background_phase,
            "distraction_random": None if self._distraction_rng is None else self._distraction_rng.bit_generator.state,
            "distraction": distraction,
        }

    def set_state(self, state: dict[str, Any]) -> None:
        """Continue from ``get_state``'s state (see there).

        :param state: what ``get_state`` returned, of an env made with the same arguments
        """
        physics = self._dm_env.physics
        physics.set_state(np.asarray(state["physics"]), mujoco.mjtState.mjSTATE_INTEGRATION)
        for name, value in state.get("model", {}).items():  # (checkpoints from before it was saved lack it)
            getattr(physics.model, name)[:] = value
        # dm_control ends every step with mj_step1 (the position- and velocity-dependent quantities, which its
        # next step starts from): the same here.
        mujoco.mj_step1(physics.model.ptr, physics.data.ptr)
        self._dm_env._step_count = state["dm_env"]["step_count"]
        self._dm_env._reset_next_step = state["dm_env"]["reset_next_step"]
        self._dm_env.task.random.set_state(state["task_random"])
        self.np_random.bit_generator.state = state["np_random"]
        self._agent_steps = state["agent_steps"]
        self._background_phase = state["background_phase"]
        if state["distraction_random"] is not None:
            self._distraction_rng = np.random.default_rng()
            self._distraction_rng.bit_generator.state = state["distraction_random"]
        if isinstance(self._distraction, HasState) and state["distraction"] is not None:
            self._distraction.set_state(state["distraction"])
        self._last_frame = None

    def render(self) -> np.ndarray | None:
        """The current frame (the pixel observation, or a fresh render for state observations)."""
        if self.render_mode is None:
            return None
        if self._last_frame is not None:
            return self._last_frame.copy()
        return self._frame()

    def close(self) -> None:
        """Free the physics and its rendering context; calling it twice is fine."""
        if not self._closed:
            self._closed = True
            self._dm_env.physics.free()
