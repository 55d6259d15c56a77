"""The builders of every id, one per kind of id and each its ids' entry point (``gym.spec(id).entry_point``): they
refuse by name the keyword arguments of another kind, check their own, say once per process when a built-in stand-in
plays in place of a benchmark's data (:mod:`sgfd_envs.building`), and make the env."""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

import gymnasium as gym
from dm_control.mujoco import Physics
from dm_control.rl import control

from sgfd_envs import domains
from sgfd_envs.background_splits import (
    BACKGROUND_MOTIONS,
    BACKGROUND_ROBOTS,
    BGR,
    CHANNEL_ORDERS,
    CHANNELS_OF_COMPOSITING,
    COLOUR_KEY,
    COMPOSITINGS,
    HIPBMDP_ROBOTS,
    STILL,
    check_choice,
)
from sgfd_envs.backgrounds import (
    DEFAULT_FRAME_BUDGET,
    BackgroundSource,
    ChannelsReversed,
    check_background_split,
    make_background,
    n_background_domains,
)
from sgfd_envs.benchmarks import dcs, dmcgb, dmcgb2
from sgfd_envs.benchmarks.media import davis_folder
from sgfd_envs.benchmarks.scene import DEFAULT_TEXTURE_CACHE_MB, check_texture_cache_mb
from sgfd_envs.building import (
    MorphologyWarning,
    StandInWarning,
    env_kwargs_of,
    refusing_other_kwargs,
    stand_in_warned,
    warn_once,
)
from sgfd_envs.causal_world import CausalWorldEnv
from sgfd_envs.dmc import Distraction, DMCEnv, DomainLabel, check_image_size
from sgfd_envs.morphology import (
    DEFAULT_MT_ROBOTS,
    HIPBMDP,
    HIPBMDP_FILES,
    SETTINGS,
    SPLIT_SETTINGS_OF_ROBOTS,
    check_domain,
    check_robots,
    select_setting,
)
from sgfd_envs.registry import (
    BACKGROUND,
    CAUSAL_WORLD,
    DCS,
    DMCGB,
    DMCGB2,
    MORPHOLOGY,
    check_benchmark_split,
    entry_of_kind,
)
from sgfd_envs.rendering import check_render
from sgfd_envs.wrappers import FrameLag, ObserveParameter, check_observe_parameter, scale_to_unit

# Their home before the builders' shared parts moved to sgfd_envs.building, kept.
__all__ = ["MorphologyWarning", "StandInWarning", "env_kwargs_of"]


@refusing_other_kwargs
def make_background_env(
    env_id: str,
    split: str = "train",
    domain: int = 0,
    *,
    background_dir: str | Path | None = None,
    backgrounds: str = STILL,
    compositing: str = COLOUR_KEY,
    test_domains: int | None = None,
    background_channels: str | None = None,
    robots: str = HIPBMDP_ROBOTS,
    frame_budget: int = DEFAULT_FRAME_BUDGET,
    grayscale: bool = False,
    obs_type: str = "pixels",
    image_size: int = 84,
    render_mode: str | None = None,
    render: str = "benchmark",
) -> DMCEnv:
    """A distracting-background env (entry point of the background ids). The defaults are the SGFD paper's setup as
    its authors' code built it: one still image per domain, put into the render of the local unmodified robot by
    the authors' colour key, in OpenCV's BGR order; one test domain.

    :param env_id: a background id of :data:`SGFD_IDS`
    :param split: ``"train"`` or ``"test"`` (test sources never appear in training)
    :param domain: index of the background source within the split
    :param background_dir: folder of images/videos (see :mod:`sgfd_envs.background_splits`; five images, the
        first four training, the fifth testing, are the authors' setup), None for the built-in procedural stand-in
    :param backgrounds: ``"still"`` (one image per domain, the paper's) or ``"moving"`` (a frame per agent step of a
        procedural texture or a video, from a random start)
    :param compositing: ``"colour_key"`` (the authors': the blue-dominant pixels of the whole render take the
        background's) or ``"matte"`` (behind the robot by the render's coverage, floor and sky hidden)
    :param test_domains: the built-in test backgrounds, None (the paper's one) or 1..4; a folder decides its own
    :param background_channels: the channel order pasted, ``"bgr"`` (the authors' code: OpenCV's order into the RGB
        render) or ``"rgb"``; None: the compositing's own (colour key: BGR, matte: RGB)
    :param robots: ``"hipbmdp"`` (the local unmodified robot files the authors' code renders: HiP-BMDP's, with
        their floor and sky colours) or ``"dm_control"`` (dm_control's own)
    :param frame_budget: most frames per moving background source (DBC: 1000)
    :param grayscale: grey backgrounds, as DBC's Kinetics setting
    :param obs_type: ``"pixels"`` or ``"state"``
    :param image_size: height and width of the pixel observation
    :param render_mode: None or ``"rgb_array"``
    :param render: ``"benchmark"`` (dm_control's render: shadows, reflections, multisampling) or ``"fast"``
    """
    entry = entry_of_kind(env_id, BACKGROUND)
    check_image_size(image_size)
    check_background_split(split)
    still = check_choice("backgrounds", backgrounds, BACKGROUND_MOTIONS) == STILL
    check_choice("compositing", compositing, COMPOSITINGS)
    channels = CHANNELS_OF_COMPOSITING[compositing] if background_channels is None else background_channels
    check_choice("background_channels", channels, CHANNEL_ORDERS)
    check_choice("robots", robots, BACKGROUND_ROBOTS)
    count = n_background_domains(split, background_dir, test_domains)
    domain = check_domain(domain, count, split)
    check_render(render)
    background: BackgroundSource = make_background(
        split, domain, image_size, image_size, background_dir, frame_budget, grayscale, still, test_domains
    )
    if channels == BGR:
        background = ChannelsReversed(background)
    label = DomainLabel(split=split, domain=domain, n_domains=count)
    if robots == HIPBMDP_ROBOTS:
        dm_env = domains.hipbmdp.load(entry.robot, entry.task, HIPBMDP_FILES[entry.robot].unmodified_setting)
    else:
        dm_env = domains.load(entry.robot, entry.task)
    what = stand_in_warned(env_id, split, background_dir=background_dir, backgrounds=backgrounds)
    return DMCEnv(
        dm_env, label, action_repeat=entry.action_repeat, obs_type=obs_type, image_size=image_size,
        background=background, render_mode=render_mode, render=render, stand_in=what, compositing=compositing,
    )  # fmt: skip


_FINGER_FILES = (
    "HiP-BMDP's finger files (the paper's) change only the size of the invisible touch-sensor sites: every setting "
    "looks and moves alike, and on states only the touch readings differ once the finger touches the spinner; "
    "robots='scaled' gives a finger whose distal link changes"
)


@refusing_other_kwargs
def make_morphology_env(
    env_id: str,
    split: str | None = None,
    domain: int | None = None,
    *,
    setting: int | None = None,
    split_settings: Mapping[str, Sequence[int]] | None = None,
    robots: str = DEFAULT_MT_ROBOTS,
    frame_lag: bool = False,
    obs_type: str = "pixels",
    observe_parameter: bool = False,
    image_size: int = 84,
    render_mode: str | None = None,
    render: str = "benchmark",
) -> gym.Env:
    """A modified-morphology env (entry point of the MT ids). The defaults are the SGFD paper's Table 2 as its
    authors' code built it: HiP-BMDP's robot files, split as the authors split them.

    :param env_id: an MT id of :data:`SGFD_IDS`
    :param split: ``"train"`` (default), ``"interpolation"`` or ``"extrapolation"``
    :param domain: index of the setting within the split (default 0)
    :param setting: pick one setting 1..10 directly instead of ``split``/``domain``; the env is then
        the single domain of no split (``split`` None, ``domain`` 0)
    :param split_settings: replace the settings of some splits, e.g. ``{"train": (1, 2, 3, 4)}``
    :param robots: ``"hipbmdp"`` (HiP-BMDP's files, the paper's: train 2, 3, 5, 6, interpolation 4, extrapolation
        10) or ``"scaled"`` (this package's scaled robots: train 1, 2, 4, 5, interpolation 3, extrapolation 10);
        see :mod:`sgfd_envs.morphology`
    :param frame_lag: observations two agent steps old, as the authors' published code gave its agent on these
        tasks (a defect of that code, which Table 2's numbers carry; :class:`sgfd_envs.wrappers.FrameLag`)
    :param obs_type: ``"pixels"`` or ``"state"``
    :param observe_parameter: append the varied quantity, scaled to [-1, 1] over the ten settings, to the
        state (see :class:`sgfd_envs.wrappers.ObserveParameter`); states only
    :param image_size: height and width of the pixel observation
    :param render_mode: None or ``"rgb_array"``
    :param render: ``"benchmark"`` (dm_control's render: shadows, reflections, multisampling) or ``"fast"``
    """
    entry = entry_of_kind(env_id, MORPHOLOGY)
    check_observe_parameter(observe_parameter, obs_type)
    if not isinstance(frame_lag, bool):
        raise ValueError(f"frame_lag must be True or False, got {frame_lag!r}")
    table = SPLIT_SETTINGS_OF_ROBOTS[check_robots(robots)]
    label_split, label_domain, count, setting = select_setting(split, domain, setting, split_settings, defaults=table)
    if robots == HIPBMDP and entry.robot == "finger":
        warn_once(f"{env_id}: {_FINGER_FILES}", MorphologyWarning)
    morphology = domains.mt_morphology(robots, entry.robot)
    label = DomainLabel(
        split=label_split,
        domain=label_domain,
        n_domains=count,
        setting=setting,
        morphology_parameter=morphology.parameter,
        morphology_value=morphology.value(setting),
    )
    dm_env = domains.load_mt(robots, entry.robot, entry.task, setting)
    env: gym.Env = DMCEnv(
        dm_env, label, action_repeat=entry.action_repeat, obs_type=obs_type, image_size=image_size,
        render_mode=render_mode, render=render,
    )  # fmt: skip
    if observe_parameter:
        low, high = morphology.value(SETTINGS[0]), morphology.value(SETTINGS[-1])
        env = ObserveParameter(env, scale_to_unit(morphology.value(setting), low, high), morphology.parameter)
    return FrameLag(env) if frame_lag else env


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
        stand_in=stand_in_warned(env_id, split, **data_kwargs),
        **common,
    )


def _checked_common(
    env_id: str, split: str, obs_type: str, image_size: int, render_mode: str | None, render: str, texture_cache_mb: int
) -> dict[str, Any]:
    """The keywords every benchmark builder takes, checked, and those of them :class:`DMCEnv` takes (the ``common``
    of :func:`_benchmark_env`)."""
    check_image_size(image_size)
    check_texture_cache_mb(texture_cache_mb)
    check_benchmark_split(env_id, split)
    check_render(render)
    return {"obs_type": obs_type, "image_size": image_size, "render_mode": render_mode, "render": render}


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
    """A DMC-GB or a DMC-GB2 env, as the id's prefix says (entry point of the ``DMCGB/`` and ``DMCGB2/`` ids; see
    :mod:`sgfd_envs.benchmarks.dmcgb` and :mod:`sgfd_envs.benchmarks.dmcgb2`). The two take the same keywords.

    :param env_id: one of ``BENCHMARK_IDS["DMCGB"]`` or ``BENCHMARK_IDS["DMCGB2"]``
    :param split: ``"train"`` (dm_control's task), ``"distracting_cs"`` (DMC-GB's DCS test, which DMC-GB2 tests on
        too) or a test mode: DMC-GB's ``"color_easy"``, ``"color_hard"``, ``"video_easy"``, ``"video_hard"``;
        DMC-GB2's twelve (``"rotate_easy"``, ..., ``"color_video_hard"``)
    :param domain: 0 (each split is one distribution)
    :param data_dir: DMC-GB's ``src/env/data`` folder (colour sets and clips; DMC-GB2's ``envs/dmcgb/data`` holds
        the same files); None: procedural stand-ins
    :param intensity: ``distracting_cs``'s intensity, one of 0.025, 0.05, 0.1, 0.15, 0.2, 0.3, 0.4, 0.5
    :param background_dir: DAVIS's ``JPEGImages/480p`` folder for ``distracting_cs``; None: procedural stand-ins
    :param obs_type: ``"pixels"`` or ``"state"``
    :param image_size: height and width of the pixel observation
    :param render_mode: None or ``"rgb_array"``
    :param render: ``"benchmark"`` (dm_control's render: shadows, reflections, multisampling) or ``"fast"``
    :param texture_cache_mb: ``distracting_cs``: GPU memory (MiB) the sky's frames of the episode's video may take,
        each sent to the GPU once (past it, a frame is sent at each view; 0: no cache)
    """
    entry = entry_of_kind(env_id, DMCGB, DMCGB2)
    common = _checked_common(env_id, split, obs_type, image_size, render_mode, render, texture_cache_mb)
    is_dmcgb2 = entry.variation == DMCGB2

    def make_mode(physics: Physics) -> Distraction:
        if is_dmcgb2:
            return dmcgb2.DMCGB2Distraction(physics, entry.robot, split, image_size, data_dir, render)
        return dmcgb.DMCGBDistraction(physics, split, image_size, data_dir)

    # DMC-GB2 resizes distracting_cs's clips as it resizes its own; DMC-GB, by distracting_cs's default.
    clip_resize = {"interpolation": dmcgb2.RESIZE} if is_dmcgb2 else {}
    make_distraction = dmcgb.family_distraction(
        entry.robot, split, intensity, data_dir, background_dir, image_size, render, make_mode,
        texture_cache_mb=texture_cache_mb, **clip_resize,
    )  # fmt: skip
    dm_env = None
    if is_dmcgb2 and "video" in split:
        side = dmcgb2.projector_texture_side(image_size, render)
        dm_env = dmcgb2.load_with_projector(entry.robot, entry.task, side)
    return _benchmark_env(
        env_id, entry.variation, split, domain, common, make_distraction, dm_env, data_dir=data_dir,
        background_dir=background_dir,
    )  # fmt: skip


# DMC-GB2's builder by its earlier name: DMC-GB's builder serves both benchmarks.
make_dmcgb2_env = make_dmcgb_env


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
    common = _checked_common(env_id, split, obs_type, image_size, render_mode, render, texture_cache_mb)
    if background_dir is not None:
        davis_folder(background_dir)

    def make_distraction(physics: Physics) -> Distraction:
        scale, n_videos = dcs.DIFFICULTIES[split]
        return dcs.DCSDistraction(
            physics, entry.robot, scale, n_videos, dynamic, distractions, background_videos, image_size,
            background_dir, render=render, texture_cache_mb=texture_cache_mb,
        )  # fmt: skip

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
