"""What every builder (:mod:`sgfd_envs.builders`) shares: refusing, in one line, the keyword arguments of another
kind of id, the keyword arguments an id takes, and saying once per process, at the user's line, what stands in for a
benchmark's data or what a family of robots does not change."""

from __future__ import annotations

import functools
import inspect
import os
import sys
import warnings
from collections.abc import Callable
from pathlib import Path
from typing import Any, TypeVar, cast

import gymnasium as gym
from gymnasium.envs.registration import load_env_creator

from sgfd_envs.registry import stand_in, task_entry

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


def warn_once(message: str, category: type[UserWarning], key: str | None = None) -> None:
    """Warn ``message`` once per process per ``key`` (default: the message), at the user's line."""
    key = message if key is None else key
    if key not in _WARNED:
        _WARNED.add(key)
        warnings.warn(message, category, stacklevel=_user_stacklevel())


def stand_in_warned(env_id: str, split: str, **env_kwargs: Any) -> str | None:
    """:func:`sgfd_envs.registry.stand_in`, warned once per process per kind of stand-in, at the user's line."""
    what = stand_in(env_id, split, **env_kwargs)
    if what is not None:
        warn_once(f"{env_id} split={split!r}: {what}", StandInWarning, key=what)
    return what


class MorphologyWarning(UserWarning):
    """An MT env's settings do not change what the id's name suggests (HiP-BMDP's finger files)."""


def env_kwargs_of(env_id: str) -> tuple[str, ...]:
    """The keyword arguments ``gym.make`` takes for an id (those of its kind's builder, its entry point).

    :param env_id: one of :data:`~sgfd_envs.registry.TASKS`
    """
    builder = load_env_creator(task_entry(env_id).entry_point)
    return _keywords(cast(Callable[..., gym.Env], builder))
