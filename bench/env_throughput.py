"""Env steps per second at 84x84: sgfd_envs against the prior practice, measured in one run.

Prior practice (DBC/AMBS's dmc2gym): dm_control's ``physics.render(84, 84, camera_id=0)`` with its
default flags (shadows, reflections, 4x multisampling; a new Camera every call), then the colour
rule (blue > green and blue > red) to paste the background frame. Ours: one reused scene, shadows,
reflections and multisampling off, colour and depth read in one pass, depth mask. Both use the same
physics, action repeat and background frames; the methods run in interleaved rounds so machine load
hits both alike, and each figure is the median over rounds.

Usage: ``python bench/env_throughput.py [--steps 300] [--rounds 3] [--env SGFD/walker-walk-v0]``
"""

from __future__ import annotations

import argparse
import os
import statistics
import time
from collections.abc import Callable

import gymnasium as gym
import numpy as np

import sgfd_envs
from sgfd_envs import domains
from sgfd_envs.backgrounds import composite, make_background
from sgfd_envs.registry import task_entry

IMAGE_SIZE = 84


def gym_stepper(env: gym.Env, seed: int) -> Callable[[], None]:
    """One agent step of a gymnasium env with a random action, resetting at episode ends."""
    env.reset(seed=seed)
    env.action_space.seed(seed)

    def step() -> None:
        *_, terminated, truncated, _ = env.step(env.action_space.sample())
        if terminated or truncated:
            env.reset()

    return step


def prior_practice_stepper(env_id: str, seed: int) -> Callable[[], None]:
    """One agent step the DBC way: repeat the action, render with default flags, colour-rule composite."""
    entry = task_entry(env_id)
    dm_env = domains.load(entry.robot, entry.task)
    background = make_background("train", 0, IMAGE_SIZE, IMAGE_SIZE)
    rng = np.random.default_rng(seed)
    action_spec = dm_env.action_spec()
    state = {"control_steps": 0, "frame": 0}

    def reset() -> None:
        dm_env.reset()
        state["control_steps"] = 0
        state["frame"] = int(rng.integers(background.n_frames))

    def step() -> None:
        action = rng.uniform(action_spec.minimum, action_spec.maximum)
        for _ in range(entry.action_repeat):
            dm_env.step(action)
            state["control_steps"] += 1
        rendered = dm_env.physics.render(IMAGE_SIZE, IMAGE_SIZE, camera_id=0)
        red, green, blue = (rendered[..., channel].astype(np.int16) for channel in range(3))
        composite(rendered, (blue > green) & (blue > red), background.frame(state["frame"]))
        state["frame"] += 1
        if state["control_steps"] >= 1000:
            reset()

    reset()
    return step


def steps_per_second(step: Callable[[], None], n_steps: int) -> float:
    """Agent steps per second over ``n_steps`` calls."""
    start = time.perf_counter()
    for _ in range(n_steps):
        step()
    return n_steps / (time.perf_counter() - start)


def main(argv: list[str] | None = None) -> None:
    """Measure and print steps/s of each method and the speed-up."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--env", default="SGFD/walker-walk-v0", help="background id to compare")
    parser.add_argument("--mt-env", default="SGFD/MT-walker-walk-v0", help="MT id measured alongside")
    parser.add_argument("--steps", type=int, default=300, help="agent steps per method per round")
    parser.add_argument("--rounds", type=int, default=3)
    args = parser.parse_args(argv)
    if task_entry(args.env).variation != "background":
        parser.error(f"--env must be a background id, one of {[i for i in sgfd_envs.SGFD_IDS if '/MT-' not in i]}")

    methods = {
        f"ours   {args.env} (pixels, procedural background)": gym_stepper(gym.make(args.env), seed=0),
        f"prior  {args.env} (default render + colour rule)": prior_practice_stepper(args.env, seed=0),
        f"ours   {args.mt_env} (pixels)": gym_stepper(gym.make(args.mt_env), seed=0),
    }
    for step in methods.values():  # warm-up: contexts, caches, background textures
        for _ in range(20):
            step()
    rates: dict[str, list[float]] = {name: [] for name in methods}
    for _ in range(args.rounds):
        for name, step in methods.items():
            rates[name].append(steps_per_second(step, args.steps))

    print(
        f"MUJOCO_GL={os.environ.get('MUJOCO_GL')}, {os.cpu_count()} CPUs, {IMAGE_SIZE}x{IMAGE_SIZE}, "
        f"{args.steps} agent steps x {args.rounds} interleaved rounds, median"
    )
    medians = {name: statistics.median(values) for name, values in rates.items()}
    for name, median in medians.items():
        print(f"  {name:<62} {median:8.1f} steps/s  ({1000 / median:6.2f} ms/step)")
    ours, prior = list(medians.values())[:2]
    print(f"  speed-up of ours over the prior practice: {ours / prior:.1f}x (goal >= 3x)")


if __name__ == "__main__":
    main()
