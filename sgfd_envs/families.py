"""The families of envs the SGFD ids make, the keywords that choose one, and the family of the envs a run recorded
before those keywords existed, so that nothing saved is evaluated or resumed on other envs than it trained on.

Since version 0.3.0 the SGFD ids make, by default, the paper's tasks as its authors' code built them (HiP-BMDP's
robots for the MT ids; still images under the authors' colour key for the background ids), and the earlier envs are
a keyword away (:data:`EARLIER_FAMILY`). A run of ``sgfd-zoo`` records the family keywords it ran with
(:func:`family_kwargs`); a run that recorded none was trained before 0.3.0, on the earlier family
(:func:`env_kwargs_as_trained`).

Import-light: reading a run's records needs no simulator.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from sgfd_envs.background_splits import BACKGROUND_KEYWORDS, PROCEDURAL_SEEDS
from sgfd_envs.morphology import DEFAULT_MT_ROBOTS, SCALED
from sgfd_envs.registry import BACKGROUND, MORPHOLOGY, task_entry

# The version whose defaults are the paper's tasks; runs of earlier versions trained on EARLIER_FAMILY.
FAMILY_VERSION = "0.3.0"
# Each kind's family keywords with their defaults (the paper's tasks).
FAMILY_KEYWORDS: dict[str, dict[str, Any]] = {
    BACKGROUND: dict(BACKGROUND_KEYWORDS),
    MORPHOLOGY: {"robots": DEFAULT_MT_ROBOTS},
}
# The envs of versions before 0.3.0: dm_control's robots with moving procedural textures (or a folder's videos)
# behind them by coverage, four built-in test textures; this package's scaled MT robots with its own splits.
EARLIER_FAMILY: dict[str, dict[str, Any]] = {
    BACKGROUND: {
        "robots": "dm_control",
        "backgrounds": "moving",
        "compositing": "matte",
        "test_domains": len(PROCEDURAL_SEEDS["test"]),
    },
    MORPHOLOGY: {"robots": SCALED},
}


def family_kwargs(env_id: str, env_kwargs: Mapping[str, Any] | None = None) -> dict[str, Any]:
    """The family keywords an env of ``env_id`` made with ``env_kwargs`` runs with, given or default ({} for ids
    of one family: the benchmarks', Causal World's). What a run records.

    :param env_id: a registered id
    :param env_kwargs: its keyword arguments
    """
    defaults = FAMILY_KEYWORDS.get(task_entry(env_id).variation, {})
    return {keyword: (env_kwargs or {}).get(keyword, default) for keyword, default in defaults.items()}


def earlier_family(env_id: str, env_kwargs: Mapping[str, Any] | None = None) -> dict[str, Any]:
    """``env_kwargs`` completed with the family the id made before version 0.3.0, where they name no other (a
    folder's test files, ``background_dir``, decide their number themselves).

    :param env_id: a registered id
    :param env_kwargs: the keyword arguments recorded
    """
    kwargs = dict(env_kwargs or {})
    earlier = dict(EARLIER_FAMILY.get(task_entry(env_id).variation, {}))
    if kwargs.get("background_dir") is not None:
        earlier.pop("test_domains", None)
    return {**earlier, **kwargs}


def env_kwargs_as_trained(
    env_id: str, env_kwargs: Mapping[str, Any] | None, recorded_family: Mapping[str, Any] | None
) -> dict[str, Any]:
    """The keyword arguments that make the envs a run trained on: its recorded family keywords
    (:func:`family_kwargs`, recorded since version 0.3.0) under its env kwargs, or, for a run that recorded no
    family, the earlier family (:func:`earlier_family`).

    :param env_id: the run's id
    :param env_kwargs: the env kwargs the run recorded
    :param recorded_family: the family keywords the run recorded, None when it recorded none
    """
    if recorded_family is None:
        return earlier_family(env_id, env_kwargs)
    known = FAMILY_KEYWORDS.get(task_entry(env_id).variation, {})
    return {**{k: v for k, v in recorded_family.items() if k in known}, **dict(env_kwargs or {})}
