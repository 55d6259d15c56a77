"""The table of every id (SGFD's and the benchmarks'), their splits and domains, and their registration with
gymnasium."""

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
from sgfd_envs.benchmarks import BENCHMARKS, dcs, dmcgb, dmcgb2
from sgfd_envs.benchmarks.media import check_data_dir, davis_folder
from sgfd_envs.causal_world import CausalWorldEnv, make_causal_world_env
from sgfd_envs.dmc import DMCEnv, DomainLabel, check_image_size
from sgfd_envs.morphology import MORPHOLOGY_SPLITS, SETTINGS, check_domain, select_setting, split_settings_of
from sgfd_envs.state import ResumableState
from sgfd_envs.wrappers import ObserveParameter, check_observe_parameter, scale_to_unit

if TYPE_CHECKING:
    from stable_baselines3.common.vec_env import VecEnv

BACKGROUND = "background"
MORPHOLOGY = "morphology"
# Causal World (optional extra): an object property per domain, with the MT ids' settings and splits.
CAUSAL_WORLD = "causal_world"
# The benchmarks of the field (sgfd_envs.benchmarks): one domain per split, the split is the test mode.
DMCGB, DMCGB2, DCS = dmcgb.NAME, dmcgb2.NAME, dcs.NAME
BENCHMARK_KINDS = (DMCGB, DMCGB2, DCS)
# dm_control's episodes: 1000 simulator steps; gymnasium's TimeLimit ends them (agent steps = 1000 / repeat).
EPISODE_CONTROL_STEPS = 1000
SPLITS: dict[str, tuple[str, ...]] = {
    BACKGROUND: BACKGROUND_SPLITS,
    MORPHOLOGY: MORPHOLOGY_SPLITS,
    CAUSAL_WORLD: MORPHOLOGY_SPLITS,
    DMCGB: dmcgb.MODES,
    DMCGB2: dmcgb2.MODES,
    DCS: dcs.SPLITS,
}


@dataclass(frozen=True)
class TaskEntry:
    """One registered id.

    :param robot: dm_control robot (``walker``, ``cheetah``, ``finger``, ``cartpole``, ``ball_in_cup``, ...)
    :param task: task of that robot
    :param variation: ``"background"`` (task-irrelevant), ``"morphology"`` (task-relevant, MT),
        ``"causal_world"`` (an object property, Causal World), or a benchmark of :data:`BENCHMARK_KINDS`
    :param action_repeat: dm_control steps per agent step (paper: 2; the benchmarks: theirs per task)
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


def benchmark_id(benchmark: str, domain: str, task: str) -> str:
    """The id of a benchmark task: ``DMCGB/ball_in_cup-catch-v0``."""
    return f"{benchmark}/{domain}-{task}-v0"


# THE table: every id, registered on `import sgfd_envs`.
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
    **{
        benchmark_id(name, domain, task): TaskEntry(domain, task, name, action_repeat=repeat)
        for name, module in BENCHMARKS.items()
        for (domain, task), repeat in module.TASKS.items()
    },
}
# The DeepMind Control benchmark of the paper's tables; the Causal World ids are its case studies.
SGFD_IDS: tuple[str, ...] = tuple(i for i, entry in TASKS.items() if entry.variation in (BACKGROUND, MORPHOLOGY))
CAUSAL_WORLD_IDS: tuple[str, ...] = tuple(i for i, entry in TASKS.items() if entry.variation == CAUSAL_WORLD)
# Benchmark name -> its ids (DMCGB/..., DMCGB2/..., DCS/...).
BENCHMARK_IDS: dict[str, tuple[str, ...]] = {
    name: tuple(i for i, entry in TASKS.items() if entry.variation == name) for name in BENCHMARK_KINDS
}
# Every registered id.
ENV_IDS: tuple[str, ...] = tuple(TASKS)


def task_entry(env_id: str) -> TaskEntry:
    """The table row of an id.

    :param env_id: one of :data:`ENV_IDS`
    """
    if env_id not in TASKS:
        raise ValueError(f"env_id must be one of {ENV_IDS}, got {env_id!r}")
    return TASKS[env_id]


def benchmark_of(env_id: str) -> str | None:
    """The benchmark an id belongs to (``"DMCGB"``, ``"DMCGB2"``, ``"DCS"``), None for SGFD's own ids.

    :param env_id: one of :data:`ENV_IDS`
    """
    variation = task_entry(env_id).variation
    return variation if variation in BENCHMARK_KINDS else None


def _entry_of_kind(env_id: str, variation: str) -> TaskEntry:
    entry = task_entry(env_id)
    if entry.variation != variation:
        same_kind = tuple(i for i, e in TASKS.items() if e.variation == variation)
        raise ValueError(f"env_id must be a {variation} id, one of {same_kind}, got {env_id!r}")
    return entry


def splits(env_id: str) -> tuple[str, ...]:
    """Split names of an id, training split first (for a benchmark id: ``"train"``, then its test modes).

    :param env_id: one of :data:`ENV_IDS`
    """
    return SPLITS[task_entry(env_id).variation]


def test_splits(env_id: str) -> tuple[str, ...]:
    """The splits whose domains are never seen in training.

    :param env_id: one of :data:`ENV_IDS`
    """
    return splits(env_id)[1:]


def check_benchmark_split(env_id: str, split: str) -> str:
    """Return ``split`` if it is a split of the benchmark id ``env_id``, else raise naming the allowed ones."""
    allowed = splits(env_id)
    if split not in allowed:
        raise ValueError(f"split must be one of {allowed} for {benchmark_of(env_id)} ids, got {split!r}")
    return split


def n_domains(env_id: str, split: str = "train", **env_kwargs) -> int:
    """Number of domains in a split, without building an env.

    :param env_id: one of :data:`ENV_IDS`
    :param split: a split of the id (see :func:`splits`)
    :param env_kwargs: the kwargs the envs would get; ``background_dir`` and ``split_settings`` matter
    """
    variation = task_entry(env_id).variation
    if variation == BACKGROUND:
        return n_background_domains(split, env_kwargs.get("background_dir"))
    if variation in BENCHMARK_KINDS:
        # One distribution per mode; its episodes resample the distraction.
        check_benchmark_split(env_id, split)
        return 1
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


def _benchmark_env(
    env_id: str,
    kind: str,
    split: str,
    domain: int,
    obs_type: str,
    image_size: int,
    render_mode: str | None,
    make_distraction: Callable[[Any], Any],
    dm_env: Any = None,
) -> DMCEnv:
    """A benchmark id's env: its dm_control task, and ``make_distraction(physics)`` unless the split is train."""
    entry = _entry_of_kind(env_id, kind)
    check_image_size(image_size)
    check_benchmark_split(env_id, split)
    domain = check_domain(domain, 1, split)
    if dm_env is None:
        dm_env = domains.load_suite(entry.robot, entry.task)
    distraction = None if split == "train" else make_distraction(dm_env.physics)
    return DMCEnv(
        dm_env,
        DomainLabel(split=split, domain=domain, n_domains=1),
        action_repeat=entry.action_repeat,
        obs_type=obs_type,
        image_size=image_size,
        render_mode=render_mode,
        distraction=distraction,
    )


def make_dmcgb_env(
    env_id: str,
    split: str = "train",
    domain: int = 0,
    *,
    data_dir: str | Path | None = None,
    obs_type: str = "pixels",
    image_size: int = 84,
    render_mode: str | None = None,
) -> DMCEnv:
    """A DMC-GB env (entry point of the ``DMCGB/`` ids; see :mod:`sgfd_envs.benchmarks.dmcgb`).

    :param env_id: one of ``BENCHMARK_IDS["DMCGB"]``
    :param split: ``"train"`` (dm_control's task) or a test mode: ``"color_easy"``, ``"color_hard"``,
        ``"video_easy"``, ``"video_hard"``
    :param domain: 0 (each split is one distribution)
    :param data_dir: DMC-GB's ``src/env/data`` folder (colour sets and clips); None: procedural stand-ins
    :param obs_type: ``"pixels"`` or ``"state"``
    :param image_size: height and width of the pixel observation
    :param render_mode: None or ``"rgb_array"``
    """
    if data_dir is not None:
        check_data_dir(data_dir)
    return _benchmark_env(
        env_id, DMCGB, split, domain, obs_type, image_size, render_mode,
        lambda physics: dmcgb.DMCGBDistraction(physics, split, image_size, data_dir),
    )  # fmt: skip


def make_dmcgb2_env(
    env_id: str,
    split: str = "train",
    domain: int = 0,
    *,
    data_dir: str | Path | None = None,
    obs_type: str = "pixels",
    image_size: int = 84,
    render_mode: str | None = None,
) -> DMCEnv:
    """A DMC-GB2 env (entry point of the ``DMCGB2/`` ids; see :mod:`sgfd_envs.benchmarks.dmcgb2`).

    :param env_id: one of ``BENCHMARK_IDS["DMCGB2"]``
    :param split: ``"train"`` or one of the twelve test modes (``"rotate_easy"``, ..., ``"color_video_hard"``)
    :param domain: 0 (each split is one distribution)
    :param data_dir: DMC-GB's data folder (DMC-GB2's ``envs/dmcgb/data`` holds the same files); None:
        procedural stand-ins
    :param obs_type: ``"pixels"`` or ``"state"``
    :param image_size: height and width of the pixel observation
    :param render_mode: None or ``"rgb_array"``
    """
    entry = _entry_of_kind(env_id, DMCGB2)
    if data_dir is not None:
        check_data_dir(data_dir)
    check_image_size(image_size)
    check_benchmark_split(env_id, split)
    dm_env = None
    if "video" in split:
        dm_env = dmcgb2.load_with_projector(entry.robot, entry.task, dmcgb2.projector_texture_side(image_size))
    return _benchmark_env(
        env_id, DMCGB2, split, domain, obs_type, image_size, render_mode,
        lambda physics: dmcgb2.DMCGB2Distraction(physics, entry.robot, split, image_size, data_dir),
        dm_env,
    )  # fmt: skip


def make_dcs_env(
    env_id: str,
    split: str = "train",
    domain: int = 0,
    *,
    dynamic: bool = False,
    distractions: Sequence[str] = dcs.DISTRACTIONS,
    background_videos: str = "train",
    background_dir: str | Path | None = None,
    obs_type: str = "pixels",
    image_size: int = 84,
    render_mode: str | None = None,
) -> DMCEnv:
    """A Distracting Control Suite env (entry point of the ``DCS/`` ids; see :mod:`sgfd_envs.benchmarks.dcs`).

    :param env_id: one of ``BENCHMARK_IDS["DCS"]``
    :param split: ``"train"`` (no distraction) or a difficulty: ``"easy"``, ``"medium"``, ``"hard"``
    :param domain: 0 (each split is one distribution)
    :param dynamic: distractions that move during the episode (DCS's default: static)
    :param distractions: any of ``"background"``, ``"camera"``, ``"colour"`` (default all three)
    :param background_videos: DCS's DAVIS list, ``"train"`` (60 videos) or ``"validation"`` (30)
    :param background_dir: DAVIS's ``JPEGImages/480p`` folder (or the DAVIS folder above it); None:
        procedural stand-ins
    :param obs_type: ``"pixels"`` or ``"state"``
    :param image_size: height and width of the pixel observation
    :param render_mode: None or ``"rgb_array"``
    """
    entry = _entry_of_kind(env_id, DCS)
    # Checked on every split, train too, so a bad value fails where it is given.
    distractions = dcs.check_distractions(distractions)
    if not isinstance(dynamic, bool):
        raise ValueError(f"dynamic must be True or False, got {dynamic!r}")
    if background_videos not in dcs.VIDEO_SPLITS:
        raise ValueError(f"background_videos must be one of {dcs.VIDEO_SPLITS}, got {background_videos!r}")
    if background_dir is not None:
        davis_folder(background_dir)
    return _benchmark_env(
        env_id, DCS, split, domain, obs_type, image_size, render_mode,
        lambda physics: dcs.DCSDistraction(
            physics, entry.robot, split, dynamic, distractions, background_videos, image_size, background_dir
        ),
    )  # fmt: skip


BUILDERS: dict[str, Callable[..., gym.Env]] = {
    BACKGROUND: make_background_env,
    MORPHOLOGY: make_morphology_env,
    CAUSAL_WORLD: make_causal_world_env,
    DMCGB: make_dmcgb_env,
    DMCGB2: make_dmcgb2_env,
    DCS: make_dcs_env,
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
    # outermost, so that SB3's env_method reaches it in a subprocess too
    return ResumableState(Monitor(env))


def make_domain_vec_env(
    env_id: str,
    split: str = "train",
    n_envs: int | None = None,
    seed: int = 0,
    vec_env_cls: type[VecEnv] | None = None,
    **env_kwargs,
) -> VecEnv:
    """An SB3 VecEnv with one sub-env per domain of a split (sub-env i is domain i % n_domains).

    Each sub-env is wrapped in SB3's Monitor and seeded ``seed + i`` (its action space too), and outermost in
    :class:`sgfd_envs.state.ResumableState` (``env_method("get_training_state")`` gives its state).

    :param env_id: one of :data:`ENV_IDS`
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
