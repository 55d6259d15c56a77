"""The table of SGFD ids, their splits and domains, and their registration with gymnasium."""

from __future__ import annotations

import functools
import inspect
import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import gymnasium as gym

from sgfd_envs import domains
from sgfd_envs.backgrounds import (
    BACKGROUND_SPLITS,
    DEFAULT_FRAME_BUDGET,
    check_background_split,
    make_background,
    n_background_domains,
)
from sgfd_envs.causal_world import CausalWorldEnv, make_causal_world_env
from sgfd_envs.dmc import DMCEnv, DomainLabel, check_image_size
from sgfd_envs.morphology import MORPHOLOGY_SPLITS, SETTINGS, check_domain, select_setting, split_settings_of
from sgfd_envs.wrappers import ObserveParameter, check_observe_parameter, scale_to_unit

if TYPE_CHECKING:
    from stable_baselines3.common.vec_env import VecEnv

BACKGROUND = "background"
MORPHOLOGY = "morphology"
# Causal World (optional extra): an object property per domain, with the MT ids' settings and splits.
CAUSAL_WORLD = "causal_world"
# dm_control's episodes: 1000 simulator steps; gymnasium's TimeLimit ends them (agent steps = 1000 / repeat).
EPISODE_CONTROL_STEPS = 1000
SPLITS: dict[str, tuple[str, ...]] = {
    BACKGROUND: BACKGROUND_SPLITS,
    MORPHOLOGY: MORPHOLOGY_SPLITS,
    CAUSAL_WORLD: MORPHOLOGY_SPLITS,
}


@dataclass(frozen=True)
class TaskEntry:
    """One registered id.

    :param robot: dm_control robot (``walker``, ``cheetah``, ``finger``)
    :param task: task of that robot
    :param variation: ``"background"`` (task-irrelevant), ``"morphology"`` (task-relevant, MT) or
        ``"causal_world"`` (an object property, Causal World)
    :param action_repeat: dm_control steps per agent step (paper: 2)
    """

    robot: str
    task: str
    variation: str
    action_repeat: int = 2

    @property
    def max_episode_steps(self) -> int | None:
        """Agent steps in an episode (None: Causal World ends its episodes itself)."""
        if self.variation == CAUSAL_WORLD:
            return None
        return math.ceil(EPISODE_CONTROL_STEPS / self.action_repeat)


# THE table: every SGFD id, registered on `import sgfd_envs`.
TASKS: dict[str, TaskEntry] = {
    "SGFD/walker-walk-v0": TaskEntry("walker", "walk", BACKGROUND),
    "SGFD/cheetah-run-v0": TaskEntry("cheetah", "run", BACKGROUND),
    "SGFD/finger-spin-v0": TaskEntry("finger", "spin", BACKGROUND),
    "SGFD/walker-run-v0": TaskEntry("walker", "run", BACKGROUND),
    "SGFD/finger-turn-v0": TaskEntry("finger", "turn", BACKGROUND),
    "SGFD/MT-walker-walk-v0": TaskEntry("walker", "walk", MORPHOLOGY),
    "SGFD/MT-cheetah-run-v0": TaskEntry("cheetah", "run", MORPHOLOGY),
    "SGFD/MT-finger-spin-v0": TaskEntry("finger", "spin", MORPHOLOGY),
    "SGFD/MT-walker-run-v0": TaskEntry("walker", "run", MORPHOLOGY),
    "SGFD/MT-finger-turn-v0": TaskEntry("finger", "turn", MORPHOLOGY),
    "SGFD/CW-picking-v0": TaskEntry("trifinger", "picking", CAUSAL_WORLD, action_repeat=1),
    "SGFD/CW-pushing-v0": TaskEntry("trifinger", "pushing", CAUSAL_WORLD, action_repeat=1),
}
# The DeepMind Control benchmark of the paper's tables; the Causal World ids are its case studies.
SGFD_IDS: tuple[str, ...] = tuple(i for i, entry in TASKS.items() if entry.variation != CAUSAL_WORLD)
CAUSAL_WORLD_IDS: tuple[str, ...] = tuple(i for i, entry in TASKS.items() if entry.variation == CAUSAL_WORLD)


def task_entry(env_id: str) -> TaskEntry:
    """The table row of an SGFD id.

    :param env_id: one of :data:`SGFD_IDS`
    """
    if env_id not in TASKS:
        raise ValueError(f"env_id must be one of {SGFD_IDS}, got {env_id!r}")
    return TASKS[env_id]


def _entry_of_kind(env_id: str, variation: str) -> TaskEntry:
    entry = task_entry(env_id)
    if entry.variation != variation:
        same_kind = tuple(i for i, e in TASKS.items() if e.variation == variation)
        raise ValueError(f"env_id must be a {variation} id, one of {same_kind}, got {env_id!r}")
    return entry


def splits(env_id: str) -> tuple[str, ...]:
    """Split names of an id, training split first.

    :param env_id: one of :data:`SGFD_IDS`
    """
    return SPLITS[task_entry(env_id).variation]


def test_splits(env_id: str) -> tuple[str, ...]:
    """The splits whose domains are never seen in training.

    :param env_id: one of :data:`SGFD_IDS`
    """
    return splits(env_id)[1:]


def n_domains(env_id: str, split: str = "train", **env_kwargs) -> int:
    """Number of domains in a split, without building an env.

    :param env_id: one of :data:`SGFD_IDS`
    :param split: a split of the id (see :func:`splits`)
    :param env_kwargs: the kwargs the envs would get; ``background_dir`` and ``split_settings`` matter
    """
    if task_entry(env_id).variation == BACKGROUND:
        return n_background_domains(split, env_kwargs.get("background_dir"))
    return len(split_settings_of(split, env_kwargs.get("split_settings")))


def make_background_env(
    env_id: str,
    split: str = "train",
    domain: int = 0,
    *,
    background_dir: str | Path | None = None,
    frame_budget: int = DEFAULT_FRAME_BUDGET,
    grayscale: bool = False,
    obs_type: str = "pixels",
    image_size: int = 84,
    render_mode: str | None = None,
) -> DMCEnv:
    """A distracting-background env (entry point of the background ids).

    :param env_id: a background id of :data:`SGFD_IDS`
    :param split: ``"train"`` or ``"test"`` (test sources never appear in training)
    :param domain: index of the background source within the split
    :param background_dir: folder of videos/images (see :mod:`sgfd_envs.backgrounds`), None for the
        built-in procedural backgrounds
    :param frame_budget: most frames per background source (DBC: 1000)
    :param grayscale: grey backgrounds, as DBC's Kinetics setting
    :param obs_type: ``"pixels"`` or ``"state"``
    :param image_size: height and width of the pixel observation
    :param render_mode: None or ``"rgb_array"``
    """
    entry = _entry_of_kind(env_id, BACKGROUND)
    check_image_size(image_size)
    check_background_split(split)
    count = n_background_domains(split, background_dir)
    domain = check_domain(domain, count, split)
    background = make_background(split, domain, image_size, image_size, background_dir, frame_budget, grayscale)
    label = DomainLabel(split=split, domain=domain, n_domains=count)
    return DMCEnv(
        domains.load(entry.robot, entry.task),
        label,
        action_repeat=entry.action_repeat,
        obs_type=obs_type,
        image_size=image_size,
        background=background,
        render_mode=render_mode,
    )


def make_morphology_env(
    env_id: str,
    split: str | None = None,
    domain: int | None = None,
    *,
    setting: int | None = None,
    split_settings: Mapping[str, Sequence[int]] | None = None,
    obs_type: str = "pixels",
    observe_parameter: bool = False,
    image_size: int = 84,
    render_mode: str | None = None,
) -> gym.Env:
    """A modified-morphology env (entry point of the MT ids).

    :param env_id: an MT id of :data:`SGFD_IDS`
    :param split: ``"train"`` (default), ``"interpolation"`` or ``"extrapolation"``
    :param domain: index of the setting within the split (default 0)
    :param setting: pick one setting 1..10 directly instead of ``split``/``domain``; the env is then
        the single domain of no split (``split`` None, ``domain`` 0)
    :param split_settings: replace the settings of some splits, e.g. ``{"train": (1, 2, 3, 4)}``
    :param obs_type: ``"pixels"`` or ``"state"``
    :param observe_parameter: append the varied length, scaled to [-1, 1] over the ten settings, to the
        state (see :class:`sgfd_envs.wrappers.ObserveParameter`); states only
    :param image_size: height and width of the pixel observation
    :param render_mode: None or ``"rgb_array"``
    """
    entry = _entry_of_kind(env_id, MORPHOLOGY)
    check_observe_parameter(observe_parameter, obs_type)
    label_split, label_domain, count, setting = select_setting(split, domain, setting, split_settings)
    morphology = domains.morphology(entry.robot)
    label = DomainLabel(
        split=label_split,
        domain=label_domain,
        n_domains=count,
        setting=setting,
        morphology_parameter=morphology.parameter,
        morphology_value=morphology.value(setting),
    )
    dm_env = domains.load(entry.robot, entry.task, morphology.scale(setting))
    env = DMCEnv(
        dm_env,
        label,
        action_repeat=entry.action_repeat,
        obs_type=obs_type,
        image_size=image_size,
        render_mode=render_mode,
    )
    if not observe_parameter:
        return env
    scaled = scale_to_unit(morphology.value(setting), morphology.value(SETTINGS[0]), morphology.value(SETTINGS[-1]))
    return ObserveParameter(env, scaled, morphology.parameter)


BUILDERS: dict[str, Callable[..., gym.Env]] = {
    BACKGROUND: make_background_env,
    MORPHOLOGY: make_morphology_env,
    CAUSAL_WORLD: make_causal_world_env,
}


def env_kwargs_of(env_id: str) -> tuple[str, ...]:
    """The keyword arguments ``gym.make`` takes for an id (those of its kind's builder).

    :param env_id: one of :data:`TASKS`
    """
    builder = BUILDERS[task_entry(env_id).variation]
    names = inspect.signature(builder).parameters
    if builder is make_causal_world_env:
        names = {**names, **inspect.signature(CausalWorldEnv).parameters}
    return tuple(name for name in names if name not in ("env_id", "task", "kwargs"))


def make_env(env_id: str, **kwargs: Any) -> gym.Env:
    """The entry point of every id: refuses, by name, keyword arguments of the other kind of id (a background
    id given ``setting=``, an MT id given ``background_dir=``), then builds the env.

    :param env_id: one of :data:`TASKS`
    :param kwargs: the id's keyword arguments (:func:`env_kwargs_of`)
    """
    allowed = env_kwargs_of(env_id)
    unknown = [name for name in kwargs if name not in allowed]
    if unknown:
        kind = task_entry(env_id).variation.replace("_", " ")
        raise ValueError(
            f"{env_id} does not take {', '.join(map(repr, unknown))}: {kind} ids take {', '.join(allowed)}"
        )
    return BUILDERS[task_entry(env_id).variation](env_id, **kwargs)


def register_envs() -> None:
    """Register every id of :data:`TASKS` with gymnasium (idempotent); ``TimeLimit`` ends the episodes."""
    for env_id, entry in TASKS.items():
        if env_id in gym.registry:
            continue
        gym.register(
            env_id,
            entry_point=make_env,
            kwargs={"env_id": env_id},
            max_episode_steps=entry.max_episode_steps,
        )


def _make_monitored_env(env_id: str, split: str, domain: int, action_seed: int, env_kwargs: dict) -> gym.Env:
    from stable_baselines3.common.monitor import Monitor

    env = gym.make(env_id, split=split, domain=domain, **env_kwargs)
    env.action_space.seed(action_seed)
    return Monitor(env)


def make_domain_vec_env(
    env_id: str,
    split: str = "train",
    n_envs: int | None = None,
    seed: int = 0,
    vec_env_cls: type[VecEnv] | None = None,
    **env_kwargs,
) -> VecEnv:
    """An SB3 VecEnv with one sub-env per domain of a split (sub-env i is domain i % n_domains).

    Each sub-env is wrapped in SB3's Monitor and seeded ``seed + i`` (its action space too).

    :param env_id: one of :data:`SGFD_IDS`
    :param split: a split of the id (see :func:`splits`)
    :param n_envs: number of sub-envs, default one per domain
    :param seed: seed of sub-env 0
    :param vec_env_cls: SB3 VecEnv class, default DummyVecEnv
    :param env_kwargs: more kwargs for ``gym.make`` (``obs_type``, ``image_size``, ``background_dir``...)
    """
    # Imported here, not at the top: torch makes `import sgfd_envs` ~3 s slower for gymnasium-only use.
    from stable_baselines3.common.vec_env import DummyVecEnv

    task_entry(env_id)
    if "domain" in env_kwargs:
        raise ValueError("make_domain_vec_env sets domain= itself (sub-env i gets domain i % n_domains)")
    count = n_domains(env_id, split, **env_kwargs)
    if n_envs is None:
        n_envs = count
    if isinstance(n_envs, bool) or not isinstance(n_envs, int) or n_envs < 1:
        raise ValueError(f"n_envs must be a positive int or None, got {n_envs!r}")

    # A module-level function in a partial pickles by reference, so a subprocess imports sgfd_envs
    # (registering the ids) before it builds its env.
    factories = [
        functools.partial(_make_monitored_env, env_id, split, i % count, seed + i, env_kwargs) for i in range(n_envs)
    ]
    vec_env = (vec_env_cls or DummyVecEnv)(factories)
    vec_env.seed(seed)
    return vec_env
