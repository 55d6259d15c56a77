"""The builders of every id, one per kind of id and each its ids' entry point (``gym.spec(id).entry_point``): they
refuse by name the keyword arguments of another kind, check their own, say once per process when a built-in stand-in
plays in place of a benchmark's data, and make the env."""

from __future__ import annotations

import functools
import inspect
import os
import sys
import warnings
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any, TypeVar, cast

import gymnasium as gym
from dm_control.mujoco import Physics
from dm_control.rl import control
from gymnasium.envs.registration import load_env_creator

from sgfd_envs import domains
from sgfd_envs.backgrounds import DEFAULT_FRAME_BUDGET, check_background_split, make_background, n_background_domains
from sgfd_envs.benchmarks import dcs, dmcgb, dmcgb2
from sgfd_envs.benchmarks.media import check_data_dir, davis_folder
from sgfd_envs.benchmarks.scene import DEFAULT_TEXTURE_CACHE_MB, check_texture_cache_mb
from sgfd_envs.causal_world import CausalWorldEnv
from sgfd_envs.dmc import Distraction, DMCEnv, DomainLabel, check_image_size
from sgfd_envs.morphology import SETTINGS, check_domain, select_setting
from sgfd_envs.registry import (
    BACKGROUND,
    CAUSAL_WORLD,
    DCS,
    DMCGB,
    DMCGB2,
    MORPHOLOGY,
    check_benchmark_split,
    entry_of_kind,
    stand_in,
    task_entry,
)
from sgfd_envs.rendering import check_render
from sgfd_envs.wrappers import ObserveParameter, check_observe_parameter, scale_to_unit

Builder = TypeVar("Builder", bound=Callable[..., gym.Env])


def _keywords(builder: Callable[..., gym.Env]) -> tuple[str, ...]:
    """The keyword arguments a builder takes besides the id."""
    return tuple(name for name in inspect.signature(builder).parameters if name != "env_id")


def refusing_other_kwargs(builder: Builder) -> Builder:
    """``builder`` refusing, in one line, a keyword argument it does not take (a background id given ``setting=``, an
    MT id given ``background_dir=``), naming the id's kind and the keyword arguments it takes, where Python would
    raise a TypeError."""
    takes = _keywords(builder)

    @functools.wraps(builder)
    def build(env_id: str, *args: Any, **kwargs: Any) -> gym.Env:
        unknown = [name for name in kwargs if name not in takes]
        if unknown:
            kind = task_entry(env_id).variation.replace("_", " ")
            raise ValueError(
                f"{env_id} does not take {', '.join(map(repr, unknown))}: {kind} ids take {', '.join(takes)}"
            )
        return builder(env_id, *args, **kwargs)

    # What gymnasium.make reads: render_mode="human" then builds the env for "rgb_array" and shows its frames in a
    # window (gymnasium's HumanRendering wrapper, drawn with pygame).
    build.metadata = {"render_modes": ["rgb_array"], "render_fps": 25}  # type: ignore[attr-defined]
    return cast(Builder, build)


class StandInWarning(UserWarning):
    """An env plays a built-in stand-in in place of a benchmark's data: its numbers are not the benchmark's."""


_WARNED: set[str] = set()
# The packages between a user's line and a builder's warning (gym.make, make_domain_vec_env, SB3's vector envs).
_LIBRARIES = ("sgfd_envs", "gymnasium", "stable_baselines3")


def _user_stacklevel() -> int:
    """The ``stacklevel`` that makes a warning raised by the caller of this function name the user's line: the
    first frame outside the packages of ``_LIBRARIES`` (those imported)."""
    loaded = [sys.modules[name] for name in _LIBRARIES if name in sys.modules]
    folders = tuple(f"{Path(str(module.__file__)).resolve().parent}{os.sep}" for module in loaded)
    frame, level = sys._getframe(1), 1
    while frame.f_back is not None and str(Path(frame.f_code.co_filename).resolve()).startswith(folders):
        frame, level = frame.f_back, level + 1
    return level


def _stand_in(env_id: str, split: str, **env_kwargs: Any) -> str | None:
    """:func:`sgfd_envs.registry.stand_in`, warned once per process per kind of stand-in, at the user's line."""
    what = stand_in(env_id, split, **env_kwargs)
    if what is not None and what not in _WARNED:
        _WARNED.add(what)
        warnings.warn(f"{env_id} split={split!r}: {what}", StandInWarning, stacklevel=_user_stacklevel())
    return what


@refusing_other_kwargs
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
    render: str = "benchmark",
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
    :param render: ``"benchmark"`` (dm_control's render: shadows, reflections, multisampling) or ``"fast"``
    """
    entry = entry_of_kind(env_id, BACKGROUND)
    check_image_size(image_size)
    check_background_split(split)
    count = n_background_domains(split, background_dir)
    domain = check_domain(domain, count, split)
    check_render(render)
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
        render=render,
        stand_in=_stand_in(env_id, split, background_dir=background_dir),
    )


@refusing_other_kwargs
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
    render: str = "benchmark",
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
    :param render: ``"benchmark"`` (dm_control's render: shadows, reflections, multisampling) or ``"fast"``
    """
    entry = entry_of_kind(env_id, MORPHOLOGY)
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
        render=render,
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
    common: dict[str, Any],
    make_distraction: Callable[[Physics], Distraction],
    dm_env: control.Environment | None = None,
    **data_kwargs: Any,
) -> DMCEnv:
    """A benchmark id's env: its dm_control task, and ``make_distraction(physics)`` unless the split is train.

    :param common: ``obs_type``, ``image_size``, ``render_mode``, ``render``
    :param data_kwargs: the kwargs that take the benchmark's data (for :func:`sgfd_envs.registry.stand_in`)
    """
    entry = entry_of_kind(env_id, kind)
    domain = check_domain(domain, 1, split)
    if dm_env is None:
        dm_env = domains.load_suite(entry.robot, entry.task)
    distraction = None if split == "train" else make_distraction(dm_env.physics)
    return DMCEnv(
        dm_env,
        DomainLabel(split=split, domain=domain, n_domains=1),
        action_repeat=entry.action_repeat,
        distraction=distraction,
        stand_in=_stand_in(env_id, split, **data_kwargs),
        **common,
    )


def _check_common(env_id: str, split: str, image_size: int, render: str, texture_cache_mb: int) -> None:
    check_image_size(image_size)
    check_texture_cache_mb(texture_cache_mb)
    check_benchmark_split(env_id, split)
    check_render(render)


def _dmcgb_family_distraction(
    robot: str,
    split: str,
    intensity: float | None,
    data_dir: str | Path | None,
    background_dir: str | Path | None,
    image_size: int,
    render: str,
    make_mode: Callable[[Physics], Distraction],
    **distracting_cs_kwargs: Any,
) -> Callable[[Physics], Distraction]:
    """Check the data kwargs DMC-GB and DMC-GB2 share, and give their distraction's factory: DMC-GB's
    ``distracting_cs`` at ``intensity`` for that split, ``make_mode(physics)`` for the others.

    :param robot: the dm_control domain
    :param distracting_cs_kwargs: more kwargs of :func:`sgfd_envs.benchmarks.dmcgb.distracting_cs`
    """
    intensity = dmcgb.check_intensity(split, intensity)
    if data_dir is not None:
        check_data_dir(data_dir)
    if background_dir is not None:
        davis_folder(background_dir)

    def make_distraction(physics: Physics) -> Distraction:
        if split == dmcgb.DISTRACTING_CS:
            assert intensity is not None  # check_intensity requires one with this split
            return dmcgb.distracting_cs(
                physics, robot, intensity, image_size, background_dir, render, **distracting_cs_kwargs
            )
        return make_mode(physics)

    return make_distraction


@refusing_other_kwargs
def make_dmcgb_env(
    env_id: str,
    split: str = "train",
    domain: int = 0,
    *,
    data_dir: str | Path | None = None,
    intensity: float | None = None,
    background_dir: str | Path | None = None,
    obs_type: str = "pixels",
    image_size: int = 84,
    render_mode: str | None = None,
    render: str = "benchmark",
    texture_cache_mb: int = DEFAULT_TEXTURE_CACHE_MB,
) -> DMCEnv:
    """A DMC-GB env (entry point of the ``DMCGB/`` ids; see :mod:`sgfd_envs.benchmarks.dmcgb`).

    :param env_id: one of ``BENCHMARK_IDS["DMCGB"]``
    :param split: ``"train"`` (dm_control's task) or a test mode: ``"color_easy"``, ``"color_hard"``,
        ``"video_easy"``, ``"video_hard"``, ``"distracting_cs"``
    :param domain: 0 (each split is one distribution)
    :param data_dir: DMC-GB's ``src/env/data`` folder (colour sets and clips); None: procedural stand-ins
    :param intensity: ``distracting_cs``'s intensity, one of 0.025, 0.05, 0.1, 0.15, 0.2, 0.3, 0.4, 0.5
    :param background_dir: DAVIS's ``JPEGImages/480p`` folder for ``distracting_cs``; None: procedural stand-ins
    :param obs_type: ``"pixels"`` or ``"state"``
    :param image_size: height and width of the pixel observation
    :param render_mode: None or ``"rgb_array"``
    :param render: ``"benchmark"`` (dm_control's render: shadows, reflections, multisampling) or ``"fast"``
    :param texture_cache_mb: ``distracting_cs``: GPU memory (MiB) the sky's frames of the episode's video may take,
        each sent to the GPU once (past it, a frame is sent at each view; 0: no cache)
    """
    entry = entry_of_kind(env_id, DMCGB)
    _check_common(env_id, split, image_size, render, texture_cache_mb)
    make_distraction = _dmcgb_family_distraction(
        entry.robot, split, intensity, data_dir, background_dir, image_size, render,
        lambda physics: dmcgb.DMCGBDistraction(physics, split, image_size, data_dir),
        texture_cache_mb=texture_cache_mb,
    )  # fmt: skip
    common = {"obs_type": obs_type, "image_size": image_size, "render_mode": render_mode, "render": render}
    return _benchmark_env(
        env_id, DMCGB, split, domain, common, make_distraction, data_dir=data_dir, background_dir=background_dir
    )


@refusing_other_kwargs
def make_dmcgb2_env(
    env_id: str,
    split: str = "train",
    domain: int = 0,
    *,
    data_dir: str | Path | None = None,
    intensity: float | None = None,
    background_dir: str | Path | None = None,
    obs_type: str = "pixels",
    image_size: int = 84,
    render_mode: str | None = None,
    render: str = "benchmark",
    texture_cache_mb: int = DEFAULT_TEXTURE_CACHE_MB,
) -> DMCEnv:
    """A DMC-GB2 env (entry point of the ``DMCGB2/`` ids; see :mod:`sgfd_envs.benchmarks.dmcgb2`).

    :param env_id: one of ``BENCHMARK_IDS["DMCGB2"]``
    :param split: ``"train"``, one of the twelve test modes (``"rotate_easy"``, ..., ``"color_video_hard"``) or
        ``"distracting_cs"`` (its DCS test)
    :param domain: 0 (each split is one distribution)
    :param data_dir: DMC-GB's data folder (DMC-GB2's ``envs/dmcgb/data`` holds the same files); None:
        procedural stand-ins
    :param intensity: ``distracting_cs``'s intensity, one of 0.025, 0.05, 0.1, 0.15, 0.2, 0.3, 0.4, 0.5
    :param background_dir: DAVIS's ``JPEGImages/480p`` folder for ``distracting_cs``; None: procedural stand-ins
    :param obs_type: ``"pixels"`` or ``"state"``
    :param image_size: height and width of the pixel observation
    :param render_mode: None or ``"rgb_array"``
    :param render: ``"benchmark"`` (dm_control's render: shadows, reflections, multisampling) or ``"fast"``
    :param texture_cache_mb: ``distracting_cs``: GPU memory (MiB) the sky's frames of the episode's video may take,
        each sent to the GPU once (past it, a frame is sent at each view; 0: no cache)
    """
    entry = entry_of_kind(env_id, DMCGB2)
    _check_common(env_id, split, image_size, render, texture_cache_mb)
    make_distraction = _dmcgb_family_distraction(
        entry.robot, split, intensity, data_dir, background_dir, image_size, render,
        lambda physics: dmcgb2.DMCGB2Distraction(physics, entry.robot, split, image_size, data_dir, render),
        interpolation=dmcgb2.RESIZE, texture_cache_mb=texture_cache_mb,
    )  # fmt: skip
    dm_env = None
    if "video" in split:
        side = dmcgb2.projector_texture_side(image_size, render)
        dm_env = dmcgb2.load_with_projector(entry.robot, entry.task, side)
    common = {"obs_type": obs_type, "image_size": image_size, "render_mode": render_mode, "render": render}
    return _benchmark_env(
        env_id, DMCGB2, split, domain, common, make_distraction, dm_env, data_dir=data_dir,
        background_dir=background_dir,
    )  # fmt: skip


@refusing_other_kwargs
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
    render: str = "benchmark",
    texture_cache_mb: int = DEFAULT_TEXTURE_CACHE_MB,
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
    :param render: ``"benchmark"`` (dm_control's render: shadows, reflections, multisampling) or ``"fast"``
    :param texture_cache_mb: GPU memory (MiB) the sky's frames of the episode's video may take, each sent to the GPU
        once (past it, a frame is sent at each view; 0: no cache)
    """
    entry = entry_of_kind(env_id, DCS)
    # Checked on every split, train too, so a bad value fails where it is given.
    distractions = dcs.check_distractions(distractions)
    if not isinstance(dynamic, bool):
        raise ValueError(f"dynamic must be True or False, got {dynamic!r}")
    if background_videos not in dcs.VIDEO_SPLITS:
        raise ValueError(f"background_videos must be one of {dcs.VIDEO_SPLITS}, got {background_videos!r}")
    _check_common(env_id, split, image_size, render, texture_cache_mb)
    if background_dir is not None:
        davis_folder(background_dir)

    def make_distraction(physics: Physics) -> Distraction:
        scale, n_videos = dcs.DIFFICULTIES[split]
        return dcs.DCSDistraction(
            physics, entry.robot, scale, n_videos, dynamic, distractions, background_videos, image_size,
            background_dir, render=render, texture_cache_mb=texture_cache_mb,
        )  # fmt: skip

    common = {"obs_type": obs_type, "image_size": image_size, "render_mode": render_mode, "render": render}
    return _benchmark_env(
        env_id, DCS, split, domain, common, make_distraction, background_dir=background_dir,
        distractions=distractions,
    )  # fmt: skip


@refusing_other_kwargs
def make_causal_world_env(
    env_id: str,
    split: str | None = None,
    domain: int | None = None,
    *,
    setting: int | None = None,
    split_settings: Mapping[str, Sequence[int]] | None = None,
    obs_type: str = "state",
    observe_parameter: bool = False,
    skip_frame: int = 10,
    render_mode: str | None = None,
) -> gym.Env:
    """A Causal World env (entry point of the ``SGFD/CW-`` ids; see :class:`sgfd_envs.causal_world.CausalWorldEnv`).

    :param env_id: one of :data:`~sgfd_envs.registry.CAUSAL_WORLD_IDS`
    :param split: ``"train"`` (default), ``"interpolation"`` or ``"extrapolation"``
    :param domain: index of the setting within the split (default 0)
    :param setting: the setting 1..10 itself instead of ``split``/``domain``
    :param split_settings: replace the settings of some splits, e.g. ``{"train": (1, 2, 3, 4)}``
    :param obs_type: only ``"state"``
    :param observe_parameter: append the block property, scaled to [-1, 1] over the ten settings, to the state
        (see :class:`sgfd_envs.wrappers.ObserveParameter`)
    :param skip_frame: simulator steps of 4 ms per agent step (Causal World's default 10)
    :param render_mode: None or ``"rgb_array"``
    """
    entry = entry_of_kind(env_id, CAUSAL_WORLD)
    check_observe_parameter(observe_parameter, obs_type)
    env = CausalWorldEnv(
        entry.task, split, domain, setting=setting, split_settings=split_settings, obs_type=obs_type,
        skip_frame=skip_frame, render_mode=render_mode,
    )  # fmt: skip
    if not observe_parameter:
        return env
    variation = env.variation
    scaled = scale_to_unit(variation.value(env.setting), variation.value(SETTINGS[0]), variation.value(SETTINGS[-1]))
    return ObserveParameter(env, scaled, variation.parameter)


def env_kwargs_of(env_id: str) -> tuple[str, ...]:
    """The keyword arguments ``gym.make`` takes for an id (those of its kind's builder, its entry point).

    :param env_id: one of :data:`~sgfd_envs.registry.TASKS`
    """
    builder = load_env_creator(task_entry(env_id).entry_point)
    return _keywords(cast(Callable[..., gym.Env], builder))
