"""SB3 vector envs of an id's domains: one sub-env per domain of a split, monitored, seeded and resumable."""

from __future__ import annotations

import difflib
import functools
import os
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

import gymnasium as gym

from sgfd_envs.registry import ENV_IDS, n_domains
from sgfd_envs.state import ResumableState

if TYPE_CHECKING:
    from stable_baselines3.common.vec_env import DummyVecEnv, SubprocVecEnv, VecEnv


def _stable_baselines3() -> Any:
    """SB3's ``vec_env`` module, or one line saying how to install it (an environments-only install lacks it).
    Imported here, not at the top: torch makes ``import sgfd_envs`` ~3 s slower for gymnasium-only use."""
    try:
        from stable_baselines3.common import vec_env
    except ModuleNotFoundError as error:
        raise ModuleNotFoundError(
            f"make_domain_vec_env needs stable-baselines3 ({error}): pip install stable-baselines3, or the agents from "
            "the clone's root: pip install -e ./sgfd_envs -e . -c constraints.txt"
        ) from None
    return vec_env


def _make_monitored_env(
    env_id: str, split: str, domain: int, action_seed: int, env_kwargs: dict, monitor_file: str | None = None
) -> gym.Env:
    from stable_baselines3.common.monitor import Monitor

    env = gym.make(env_id, split=split, domain=domain, **env_kwargs)
    env.action_space.seed(action_seed)
    # A file that exists is continued (a resumed run), not overwritten; a new one starts with Monitor's header.
    fresh = monitor_file is None or not os.path.exists(monitor_file)
    # outermost, so that SB3's env_method reaches it in a subprocess too
    return ResumableState(Monitor(env, filename=monitor_file, override_existing=fresh))


def _monitor_file(folder: str | None, index: int) -> str | None:
    """SB3's monitor file of sub-env ``index`` in ``folder`` (``make_vec_env``'s name), or None."""
    return None if folder is None else os.path.join(folder, f"{index}.monitor.csv")


def make_domain_vec_env(
    env_id: str,
    split: str = "train",
    n_envs: int | None = None,
    seed: int = 0,
    vec_env_cls: type[DummyVecEnv | SubprocVecEnv] | None = None,
    monitor_dir: str | None = None,
    **env_kwargs,
) -> VecEnv:
    """An SB3 VecEnv with one sub-env per domain of a split (sub-env i is domain i % n_domains).

    Each sub-env is wrapped in SB3's Monitor and seeded ``seed + i`` (its action space too), and outermost in
    :class:`sgfd_envs.state.ResumableState` (``env_method("get_training_state")`` gives its state).

    :param env_id: one of :data:`ENV_IDS`
    :param split: a split of the id (see :func:`splits`)
    :param n_envs: number of sub-envs, default one per domain
    :param seed: seed of sub-env 0
    :param vec_env_cls: SB3's DummyVecEnv (the default) or SubprocVecEnv
    :param monitor_dir: a folder for SB3's monitor files, ``<i>.monitor.csv`` per sub-env (rl-zoo3's layout, which
        its ``plot_train`` reads); an existing file is continued. None: no files
    :param env_kwargs: more kwargs for ``gym.make`` (``obs_type``, ``image_size``, ``background_dir``...)
    """
    default_vec_env_cls = _stable_baselines3().DummyVecEnv

    if env_id not in ENV_IDS:
        close = difflib.get_close_matches(str(env_id), ENV_IDS, n=1)
        hint = f" (did you mean {close[0]}?)" if close else ""
        raise ValueError(f"env_id must be one of {', '.join(ENV_IDS)}, got {env_id!r}{hint}")
    if "domain" in env_kwargs:
        raise ValueError("make_domain_vec_env sets domain= itself (sub-env i gets domain i % n_domains)")
    count = n_domains(env_id, split, **env_kwargs)
    if n_envs is None:
        n_envs = count
    if isinstance(n_envs, bool) or not isinstance(n_envs, int) or n_envs < 1:
        raise ValueError(f"n_envs must be a positive int or None, got {n_envs!r}")

    # A module-level function in a partial pickles by reference, so a subprocess imports sgfd_envs
    # (registering the ids) before it builds its env.
    factories: list[Callable[[], gym.Env]] = [
        functools.partial(
            _make_monitored_env, env_id, split, i % count, seed + i, env_kwargs, _monitor_file(monitor_dir, i)
        )
        for i in range(n_envs)
    ]
    vec_env = (vec_env_cls or default_vec_env_cls)(factories)
    vec_env.seed(seed)
    return vec_env
