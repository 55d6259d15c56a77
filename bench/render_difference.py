"""How far ``render="fast"`` (no shadows, reflections or multisampling) is from the benchmarks' picture: per task,
the share of pixels off by more than ``--levels`` (of 255, in some channel) against the default render, on the
same states.

Each task's DCS/ id (all six DCS tasks), its undistracted split, is made twice, with the default render and with
``render="fast"``; both are reset with the same seed and take the same random actions, and the observations after
``--steps`` steps are compared (the simulator state is checked equal first: the render path never touches it).
The figure is the mean over ``--episodes`` seeds.

Usage: ``python bench/render_difference.py [--steps 20] [--episodes 3] [--levels 20] [--size 84]``
"""

from __future__ import annotations

import argparse

import benchmark_methods
import gymnasium as gym
import numpy as np

from sgfd_envs.benchmarks import dcs


def observations_after(env_id: str, seed: int, steps: int, size: int) -> tuple[np.ndarray, np.ndarray]:
    """The default render's and the fast path's observation after ``steps`` equal random steps from ``seed``."""
    with gym.make(env_id, image_size=size) as default, gym.make(env_id, image_size=size, render="fast") as fast:
        default.reset(seed=seed)
        fast.reset(seed=seed)
        rng = np.random.default_rng(seed)
        for _ in range(steps):
            action = rng.uniform(-1.0, 1.0, default.action_space.shape).astype(np.float32)
            default_observation, *_ = default.step(action)
            fast_observation, *_ = fast.step(action)
        default_state = default.get_wrapper_attr("physics").get_state()
        fast_state = fast.get_wrapper_attr("physics").get_state()
        if not np.array_equal(default_state, fast_state):
            raise RuntimeError(f"{env_id} seed {seed}: the two renders' simulator states differ")
    return default_observation, fast_observation


def main(argv: list[str] | None = None) -> None:
    """Print, per task, the share of pixels the fast path changes by more than ``--levels``."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=20, help="agent steps before the compared observation")
    parser.add_argument("--episodes", type=int, default=3, help="episodes (seeds 0, 1, ...) per task")
    parser.add_argument("--levels", type=int, default=20, help="a pixel is off when a channel differs by more")
    parser.add_argument("--size", type=int, default=84, help="observation height and width")
    args = parser.parse_args(argv)
    print(
        f'render="fast" against the default render, DCS/ ids undistracted, {args.size}x{args.size}, '
        f"after {args.steps} steps, seeds 0-{args.episodes - 1}: share of pixels off by more than {args.levels} levels"
    )
    print("\n| task | pixels off | per episode |\n|---|---|---|")
    for domain, task in sorted(dcs.TASKS):
        shares = []
        for seed in range(args.episodes):
            default, fast = observations_after(f"DCS/{domain}-{task}-v0", seed, args.steps, args.size)
            shares.append(benchmark_methods.disagreement(fast, default, args.levels))
        episodes = ", ".join(f"{share:.1%}" for share in shares)
        print(f"| {domain}-{task} | {np.mean(shares):.1%} | {episodes} |", flush=True)


if __name__ == "__main__":
    from recording import run_recorded  # the bench's --record FILE

    run_recorded(main, __file__)
