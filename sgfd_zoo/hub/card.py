"""The model card of a run pushed to the Hub: every split's evaluation, with its domains, in the card's text and in
its metadata (one ``model-index`` result per split, so the Hub's evaluation table lists them all), written with
huggingface_hub's own card classes."""

from __future__ import annotations

import pprint
from typing import Any

import sgfd_envs
from sgfd_envs.registry import CAUSAL_WORLD, MORPHOLOGY, task_entry

TAGS = ["deep-reinforcement-learning", "reinforcement-learning", "stable-baselines3", "sgfd", "domain-generalization"]


def split_domains(env_id: str, split: str, env_kwargs: dict[str, Any]) -> str:
    """What the domains of ``split`` are, in words: their number, and an MT id's morphology settings."""
    env_kwargs = {key: value for key, value in env_kwargs.items() if key not in ("split", "domain")}
    count = sgfd_envs.n_domains(env_id, split, **env_kwargs)
    what = f"{count} domain{'s' if count != 1 else ''}"
    if task_entry(env_id).variation in (MORPHOLOGY, CAUSAL_WORLD):
        from sgfd_envs.morphology import resolve_split_settings

        settings = resolve_split_settings(env_kwargs.get("split_settings"))[split]
        what += f": setting{'s' if len(settings) != 1 else ''} {', '.join(map(str, settings))} of 1-10"
    return what


def evaluation_results(rows: list[dict[str, Any]], env_kwargs: dict[str, Any], n_episodes: int) -> dict[str, Any]:
    """``results.json``: each evaluation mode's return (mean, std, episodes), its split's domains and whether a
    stand-in of a benchmark's data played it.

    :param rows: ``sgfd_zoo.report.evaluate.evaluate_run``'s rows of the run
    :param env_kwargs: the env settings it trained with
    :param n_episodes: episodes per mode
    """
    modes = dict(sgfd_envs.evaluation_modes(rows[0]["env"]))
    results = {}
    for row in rows:
        mode = dict(modes[row["split"]])
        split = mode.pop("split")
        results[row["split"]] = {
            "mean_reward": row["mean_reward"],
            "std_reward": row["std_reward"],
            "n_episodes": row["n_episodes"],
            "split": split,
            "domains": split_domains(row["env"], split, {**env_kwargs, **mode}),
            "stand_in": bool(row["stand_in"]),
        }
    return {"env_id": rows[0]["env"], "deterministic": True, "n_eval_episodes": n_episodes, "splits": results}


def model_card(
    algo: str,
    algo_class: str,
    env_id: str,
    repo_id: str,
    results: dict[str, Any],
    hyperparams: dict[str, Any],
    env_kwargs: dict[str, Any],
) -> str:
    """The card's text, its metadata (library, tags, one result per split) at the top as the Hub reads it.

    :param algo: the zoo's key, e.g. ``sgfd_sac``
    :param algo_class: the algorithm's class name, e.g. ``SGFD_SAC``
    :param env_id: the id it trained on
    :param repo_id: ``<organization>/<name>`` of the repository
    :param results: :func:`evaluation_results`
    :param hyperparams: the run's ``config.yml``
    :param env_kwargs: the env settings it trained with
    """
    from huggingface_hub import ModelCardData
    from huggingface_hub.repocard_data import EvalResult

    splits = results["splits"]
    evals = [
        EvalResult(
            task_type="reinforcement-learning",
            task_name="reinforcement-learning",
            dataset_type=env_id,
            dataset_name=f"{env_id} ({label})",
            dataset_split=label,
            metric_type="mean_reward",
            metric_name=f"mean_reward on {label} ({result['domains']})",
            metric_value=f"{result['mean_reward']:.2f} +/- {result['std_reward']:.2f}",
        )
        for label, result in splits.items()
    ]
    data = ModelCardData(
        library_name="stable-baselines3",
        tags=[env_id, *TAGS],
        model_name=f"{algo_class}-{env_id}",
        eval_results=evals,
    )
    table = "\n".join(
        f"| {label} | {result['domains']} | {result['mean_reward']:.2f} ± {result['std_reward']:.2f} "
        f"| {result['n_episodes']} |{' stand-in' if result['stand_in'] else ''}"
        for label, result in splits.items()
    )
    name = repo_id.split("/")[-1]
    return f"""---
{data.to_yaml()}
---

# **{algo_class}** agent trained on **{env_id}**

A trained **{algo_class}** agent (`{algo}` of sb3-sgfd's zoo, `sgfd-zoo`, built on the RL Zoo) on
**{env_id}**, trained on the domains of its `train` split and evaluated on every split, the unseen domains
included ({_episodes(results["n_eval_episodes"])} per split, deterministic actions).

| split | domains | return (mean ± std over episodes) | episodes |
|---|---|---|---|
{table}

## Usage (with sgfd-zoo)

```bash
sgfd-zoo load-from-hub --algo {algo} --env {env_id} -orga {repo_id.split("/")[0]} -name {name} -f logs
sgfd-zoo enjoy --algo {algo} --env {env_id} -f logs --split {list(splits)[-1]} --no-render
sgfd-zoo record-video --algo {algo} --env {env_id} -f logs --split {list(splits)[-1]}
sgfd-zoo evaluate -f logs
```

The model zip holds pickles (Stable-Baselines3's format): load it only if you trust its author.

## Hyperparameters

```python
{pprint.pformat(hyperparams)}
```

## Environment arguments

```python
{pprint.pformat(env_kwargs)}
```
"""


def _episodes(count: int) -> str:
    return f"{count} episode{'s' if count != 1 else ''}"
