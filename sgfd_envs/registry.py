"""The table of every id (SGFD's and the benchmarks'), their splits, domains and evaluation modes, what stands in
for a benchmark's data, and their registration with gymnasium, each id with its kind's builder as entry point
(:mod:`sgfd_envs.builders`).

Built from import-light facts (:mod:`sgfd_envs.morphology`, :mod:`sgfd_envs.background_splits`,
:mod:`sgfd_envs.benchmarks.facts`): like gymnasium's own table, it loads no simulator, no OpenCV and no env code;
those load when an env is made.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import gymnasium as gym

from sgfd_envs.background_splits import BACKGROUND_SPLITS, n_background_domains
from sgfd_envs.benchmarks import facts
from sgfd_envs.morphology import (
    DEFAULT_MT_ROBOTS,
    MORPHOLOGY_SPLITS,
    PACKAGE_SPLIT_SETTINGS,
    SPLIT_SETTINGS_OF_ROBOTS,
    check_robots,
    split_settings_of,
)

BACKGROUND = "background"
MORPHOLOGY = "morphology"
# Causal World (optional extra): an object property per domain, with the MT ids' settings and splits.
CAUSAL_WORLD = "causal_world"
# The benchmarks of the field (sgfd_envs.benchmarks): one domain per split, the split is the test mode.
DMCGB, DMCGB2, DCS = facts.DMCGB, facts.DMCGB2, facts.DCS
BENCHMARK_KINDS = (DMCGB, DMCGB2, DCS)
# Each benchmark's (domain, task) -> action repeat.
BENCHMARK_TASKS = {DMCGB: facts.DMCGB_TASKS, DMCGB2: facts.DMCGB2_TASKS, DCS: facts.DCS_TASKS}
# dm_control's episodes: 1000 simulator steps; gymnasium's TimeLimit ends them (agent steps = 1000 / repeat).
EPISODE_CONTROL_STEPS = 1000
SPLITS: dict[str, tuple[str, ...]] = {
    BACKGROUND: BACKGROUND_SPLITS,
    MORPHOLOGY: MORPHOLOGY_SPLITS,
    CAUSAL_WORLD: MORPHOLOGY_SPLITS,
    DMCGB: facts.DMCGB_MODES,
    DMCGB2: facts.DMCGB2_MODES,
    DCS: facts.DCS_SPLITS,
}
# Splits that take a parameter, so not in SPLITS (whose splits every periodic evaluation plays): per kind,
# {split: (the kwarg that takes the parameter, its values)}. DMC-GB's distracting_cs (intensity=), which DMC-GB2
# tests on too. evaluation_modes() lists them once per value.
ParameterTable = dict[str, tuple[str, tuple[float, ...]]]
_DISTRACTING_CS: ParameterTable = {facts.DISTRACTING_CS: ("intensity", facts.INTENSITIES)}
PARAMETRIC_SPLITS: dict[str, ParameterTable] = {DMCGB: _DISTRACTING_CS, DMCGB2: _DISTRACTING_CS}
# Each kind's builder in sgfd_envs.builders: its ids' entry point (imported by gym.make, not by gym.spec). DMC-GB's
# builder makes DMC-GB2's envs too.
BUILDERS = {
    BACKGROUND: "make_background_env",
    MORPHOLOGY: "make_morphology_env",
    CAUSAL_WORLD: "make_causal_world_env",
    DMCGB: "make_dmcgb_env",
    DMCGB2: "make_dmcgb_env",
    DCS: "make_dcs_env",
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

    @property
    def entry_point(self) -> str:
        """The builder of this kind of id, as gymnasium's ``module:function``."""
        return f"sgfd_envs.builders:{BUILDERS[self.variation]}"


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
        for name, tasks in BENCHMARK_TASKS.items()
        for (domain, task), repeat in tasks.items()
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


def entry_of_kind(env_id: str, *variations: str) -> TaskEntry:
    """The table row of an id of one of the kinds ``variations``, or a ValueError listing the ids of those kinds."""
    entry = task_entry(env_id)
    if entry.variation not in variations:
        same_kind = tuple(i for i, e in TASKS.items() if e.variation in variations)
        raise ValueError(f"env_id must be a {' or '.join(variations)} id, one of {same_kind}, got {env_id!r}")
    return entry


def splits(env_id: str) -> tuple[str, ...]:
    """Split names of an id, training split first (for a benchmark id: ``"train"``, then its test modes; a split
    taking a parameter, ``distracting_cs``, is in :data:`PARAMETRIC_SPLITS` and :func:`evaluation_modes` instead).

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
    allowed = splits(env_id) + tuple(PARAMETRIC_SPLITS.get(task_entry(env_id).variation, {}))
    if split not in allowed:
        raise ValueError(f"split must be one of {allowed} for {benchmark_of(env_id)} ids, got {split!r}")
    return split


def n_domains(env_id: str, split: str = "train", **env_kwargs) -> int:
    """Number of domains in a split, without building an env.

    :param env_id: one of :data:`ENV_IDS`
    :param split: a split of the id (see :func:`splits`)
    :param env_kwargs: the kwargs the envs would get; ``background_dir``, ``test_domains``, ``robots`` and
        ``split_settings`` matter
    """
    variation = task_entry(env_id).variation
    if variation == BACKGROUND:
        return n_background_domains(split, env_kwargs.get("background_dir"), env_kwargs.get("test_domains"))
    if variation in BENCHMARK_KINDS:
        # One distribution per mode; its episodes resample the distraction.
        check_benchmark_split(env_id, split)
        return 1
    if variation == CAUSAL_WORLD:
        defaults = PACKAGE_SPLIT_SETTINGS
    else:
        defaults = SPLIT_SETTINGS_OF_ROBOTS[check_robots(env_kwargs.get("robots", DEFAULT_MT_ROBOTS))]
    return len(split_settings_of(split, env_kwargs.get("split_settings"), defaults=defaults))


def evaluation_modes(env_id: str) -> tuple[tuple[str, dict[str, Any]], ...]:
    """What ``sgfd-zoo evaluate`` tests a model on: ``(label, kwargs)`` per split, the label the split's name and
    the kwargs its ``split=`` (and more): a split of :data:`PARAMETRIC_SPLITS` once per value of its parameter,
    labelled ``<split>_<value>`` (DMC-GB's and DMC-GB2's ``distracting_cs`` once per intensity,
    ``distracting_cs_<intensity>``, as DMC-GB2 reports it).

    :param env_id: one of :data:`ENV_IDS`
    """
    modes: list[tuple[str, dict[str, Any]]] = [(split, {"split": split}) for split in splits(env_id)]
    for split, (kwarg, values) in PARAMETRIC_SPLITS.get(task_entry(env_id).variation, {}).items():
        modes += [(f"{split}_{value:g}", {"split": split, kwarg: value}) for value in values]
    return tuple(modes)


# What a split shows in place of a benchmark's data when the kwarg that takes the data is not given.
_PAPER_IMAGES = (
    "procedural still images stand in for the paper's Kinetics images; give background_dir= (five images: the first "
    "four train, the fifth tests)"
)
_MOVING_BACKGROUNDS = "procedural clips stand in for Kinetics clips; give background_dir="
_DMCGB_DATA = "procedural colour sets and clips stand in for DMC-GB's data; give data_dir= (DMC-GB's src/env/data)"
_DAVIS = "procedural clips stand in for DAVIS 2017; give background_dir= (DAVIS's JPEGImages/480p)"


def stand_in(env_id: str, split: str = "train", **env_kwargs: Any) -> str | None:
    """What stands in for the benchmark's data in a split, naming the kwarg that takes the real data; None when
    the split shows the data itself or needs none. Numbers measured on a stand-in are not the benchmark's.

    :param env_id: one of :data:`ENV_IDS`
    :param split: a split of the id
    :param env_kwargs: the env's kwargs (``data_dir``, ``background_dir``, ``backgrounds``, ``distractions`` matter)
    """
    variation = task_entry(env_id).variation
    if variation == BACKGROUND:
        if env_kwargs.get("background_dir") is not None:
            return None
        return _MOVING_BACKGROUNDS if env_kwargs.get("backgrounds") == "moving" else _PAPER_IMAGES
    if variation not in BENCHMARK_KINDS or split == "train":
        return None
    if split == facts.DISTRACTING_CS:
        return _DAVIS if env_kwargs.get("background_dir") is None else None
    if variation == DCS:
        shows_videos = "background" in facts.check_distractions(env_kwargs.get("distractions", facts.DISTRACTIONS))
        return _DAVIS if shows_videos and env_kwargs.get("background_dir") is None else None
    uses_data = "color" in split or "video" in split
    return _DMCGB_DATA if uses_data and env_kwargs.get("data_dir") is None else None


def register_envs() -> None:
    """Register every id of :data:`TASKS` with gymnasium (idempotent), its kind's builder as entry point;
    ``TimeLimit`` ends the episodes."""
    for env_id, entry in TASKS.items():
        if env_id in gym.registry:
            continue
        gym.register(
            env_id,
            entry_point=entry.entry_point,
            kwargs={"env_id": env_id},
            max_episode_steps=entry.max_episode_steps,
        )
