"""Write a PNG grid of every SGFD id (its training domain 0 next to one unseen split), or of a benchmark's ids
(each task in its train split and every test mode).

Usage: ``python -m sgfd_envs.demo --out grid.png [--benchmark DMCGB|DMCGB2|DCS]``
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

import cv2
import gymnasium as gym
import numpy as np

from sgfd_envs.dmc import DMCEnv, DomainLabel
from sgfd_envs.registry import BENCHMARK_IDS, SGFD_IDS, benchmark_of, splits, test_splits

_TILE = 168
_LABEL_HEIGHT = 34


def rollout(env_id: str, steps: int = 30, seed: int = 0, **env_kwargs: Any) -> tuple[np.ndarray, DomainLabel]:
    """The pixel observation after ``steps`` seeded random actions, and which domain the env was (its label: split,
    domain and, for MT ids, setting and morphology value), from one env.

    :param env_id: one of :data:`SGFD_IDS` or :data:`BENCHMARK_IDS`
    :param steps: agent steps taken after reset, so the robot is in motion
    :param seed: seed of the reset and the actions
    :param env_kwargs: passed to ``gym.make`` (split, domain, image_size, ...)
    """
    with gym.make(env_id, **env_kwargs) as env:
        observation, _ = env.reset(seed=seed)
        env.action_space.seed(seed)
        for _ in range(steps):
            observation, *_ = env.step(env.action_space.sample())
        unwrapped = env.unwrapped
        if not isinstance(unwrapped, DMCEnv):
            raise ValueError(f"env_id must be one of SGFD_IDS or BENCHMARK_IDS (a DeepMind Control id), got {env_id!r}")
        label = unwrapped.label
    return observation, label


def observe(
    env_id: str, split: str, steps: int = 30, seed: int = 0, image_size: int = 84, domain: int = 0, **env_kwargs: Any
) -> tuple[np.ndarray, str]:
    """The pixel observation of a domain of a split after ``steps`` random actions, and a caption.

    :param env_id: one of :data:`SGFD_IDS` or :data:`BENCHMARK_IDS`
    :param split: a split of the id
    :param steps: agent steps taken after reset, so the robot is in motion
    :param seed: seed of the reset and the actions
    :param image_size: observation size
    :param domain: index of the domain within the split
    :param env_kwargs: other arguments of ``gym.make``
    """
    observation, label = rollout(env_id, steps, seed, split=split, domain=domain, image_size=image_size, **env_kwargs)
    # A benchmark's split is one distribution (domain 0 says nothing).
    caption = split if benchmark_of(env_id) else f"{split} {domain}"
    if label.setting is not None:
        caption += f" s{label.setting} {label.morphology_value:.3g}m"
    return observation, caption


def _labelled(image: np.ndarray, lines: list[str]) -> np.ndarray:
    """An RGB tile upscaled to the grid size with text lines above it."""
    tile = cv2.resize(image, (_TILE, _TILE), interpolation=cv2.INTER_NEAREST)
    label = np.full((_LABEL_HEIGHT, _TILE, 3), 255, dtype=np.uint8)
    for row, line in enumerate(lines):
        cv2.putText(label, line, (3, 14 + 15 * row), cv2.FONT_HERSHEY_SIMPLEX, 0.38, (0, 0, 0), 1, cv2.LINE_AA)
    return np.vstack([label, tile])


def demo_grid(steps: int = 30, seed: int = 0, image_size: int = 84) -> np.ndarray:
    """RGB grid, one row per robot task: background train, background test, MT train, MT extrapolation.

    :param steps: agent steps taken after reset
    :param seed: seed of the resets and actions
    :param image_size: observation size
    """
    rows: dict[str, list[np.ndarray]] = {}
    for env_id in SGFD_IDS:
        task_name = env_id.removeprefix("SGFD/").removeprefix("MT-")
        for split in ("train", test_splits(env_id)[-1]):
            observation, caption = observe(env_id, split, steps, seed, image_size)
            rows.setdefault(task_name, []).append(_labelled(observation, [env_id.removeprefix("SGFD/"), caption]))
    return np.vstack([np.hstack(tiles) for tiles in rows.values()])


def benchmark_observations(
    benchmark: str,
    steps: int = 30,
    seed: int = 0,
    image_size: int = 84,
    tasks: tuple[str, ...] | None = None,
) -> list[list[tuple[str, str, np.ndarray]]]:
    """A benchmark's observations: one row per task, one (task, split, observation) per split (train, then every
    test mode).

    :param benchmark: ``"DMCGB"``, ``"DMCGB2"`` or ``"DCS"``
    :param steps: agent steps taken after reset
    :param seed: seed of the resets and actions
    :param image_size: observation size
    :param tasks: task names as in the ids (``"walker-walk"``), in this order; None: every task of the benchmark
    """
    if benchmark not in BENCHMARK_IDS:
        raise ValueError(f"benchmark must be one of {tuple(BENCHMARK_IDS)}, got {benchmark!r}")
    known = {env_id.split("/", 1)[1].rsplit("-v", 1)[0]: env_id for env_id in BENCHMARK_IDS[benchmark]}
    unknown = [task for task in tasks or () if task not in known]
    if unknown:
        raise ValueError(f"tasks must be tasks of {benchmark} ({', '.join(known)}), got {unknown!r}")
    rows = []
    for task_name in tasks or tuple(known):
        env_id = known[task_name]
        row = []
        for split in splits(env_id):
            observation, caption = observe(env_id, split, steps, seed, image_size)
            row.append((task_name, caption, observation))
        rows.append(row)
    return rows


def benchmark_grid(
    benchmark: str, steps: int = 30, seed: int = 0, image_size: int = 84, tasks: tuple[str, ...] | None = None
) -> np.ndarray:
    """RGB grid of a benchmark: one row per task, one column per split (train, then every test mode).

    :param benchmark: ``"DMCGB"``, ``"DMCGB2"`` or ``"DCS"``
    :param steps: agent steps taken after reset
    :param seed: seed of the resets and actions
    :param image_size: observation size
    :param tasks: task names as in the ids (``"walker-walk"``); None: every task of the benchmark
    """
    rows = benchmark_observations(benchmark, steps, seed, image_size, tasks)
    return np.vstack([np.hstack([_labelled(image, [task, split]) for task, split, image in row]) for row in rows])


def main(argv: list[str] | None = None) -> None:
    """Command line entry: build every id (of SGFD or of one benchmark) and write the grid."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, required=True, help="PNG file to write")
    parser.add_argument(
        "--benchmark", choices=("SGFD", *BENCHMARK_IDS), default="SGFD", help="whose ids (default: SGFD's ten)"
    )
    parser.add_argument("--steps", type=int, default=30, help="random agent steps after reset")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--image-size", type=int, default=84)
    args = parser.parse_args(argv)
    if args.benchmark == "SGFD":
        grid = demo_grid(args.steps, args.seed, args.image_size)
    else:
        grid = benchmark_grid(args.benchmark, args.steps, args.seed, args.image_size)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    if not cv2.imwrite(str(args.out), cv2.cvtColor(grid, cv2.COLOR_RGB2BGR)):
        raise OSError(f"could not write {str(args.out)!r}")
    print(f"wrote {args.out} ({grid.shape[1]}x{grid.shape[0]})")


if __name__ == "__main__":
    main()
