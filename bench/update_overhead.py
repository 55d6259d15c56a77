"""
Cost of one gradient step of SGFD_SAC next to SB3's SAC: same CnnPolicy (the paper's encoder, 1024-wide
heads), batch 128, 9x84x84 observations (3 stacked 84x84 frames of SGFD/walker-walk-v0), one replay
buffer of real transitions from the 4 training domains. Steps are interleaved (SAC, SGFD, SAC, ...)
so both see the same machine load; the script prints medians and their ratio.

SGFD is timed in its steady state (classifier past its accuracy threshold: encode, saliency, weight
solver, weighted losses) and, separately, while its classifier trains (up to 10 extra batches per step,
a short phase of a run).

    python bench/update_overhead.py [--steps 15] [--batch-size 128]
"""

from __future__ import annotations

import argparse
import statistics
import time

import numpy as np
import torch as th
from stable_baselines3 import SAC
from stable_baselines3.common.vec_env import VecFrameStack, VecTransposeImage

import sgfd_envs
from sb3_sgfd import SGFD_SAC, CnnPolicy, DomainReplayBuffer


def pixel_env():
    env = sgfd_envs.make_domain_vec_env("SGFD/walker-walk-v0", split="train")
    return VecTransposeImage(VecFrameStack(env, 3))


def fill(model, n_steps: int, seed: int) -> None:
    """Random-action transitions, stored as SB3 stores them."""
    env = model.get_env()
    rng = np.random.default_rng(seed)
    obs = env.reset()
    for _ in range(n_steps):
        actions = rng.uniform(-1, 1, size=(env.num_envs, *env.action_space.shape)).astype(np.float32)
        next_obs, rewards, dones, infos = env.step(actions)
        model._last_obs = obs
        model._store_transition(model.replay_buffer, actions, next_obs, rewards, dones, infos)
        obs = next_obs


def time_step(model, batch_size: int) -> float:
    start = time.perf_counter()
    model.train(gradient_steps=1, batch_size=batch_size)
    return time.perf_counter() - start


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--steps", type=int, default=15, help="timed gradient steps per algorithm")
    parser.add_argument("--batch-size", type=int, default=128)
    parser.add_argument("--fill", type=int, default=100, help="vec-env steps of data (x4 domains)")
    args = parser.parse_args()

    common = dict(buffer_size=10_000, batch_size=args.batch_size, learning_rate=1e-3, tau=0.01, seed=0)
    sac = SAC(CnnPolicy, pixel_env(), replay_buffer_class=DomainReplayBuffer, **common)
    # actor_update_interval=1 so both update actor and critic at every step: the ratio is SGFD's own cost.
    steady = SGFD_SAC("CnnPolicy", pixel_env(), actor_update_interval=1, accuracy_threshold=1e-6, **common)
    training = SGFD_SAC("CnnPolicy", pixel_env(), actor_update_interval=1, accuracy_threshold=1.0, **common)
    for model in (sac, steady, training):
        model.classifier_start = 0  # SGFD acts from the first step here
        model._setup_learn(10**6)
        fill(model, args.fill, seed=0)
    print(f"obs {sac.observation_space.shape}, batch {args.batch_size}, torch threads {th.get_num_threads()}")

    for model in (sac, steady, training):  # warm-up: allocator, first classifier steps
        time_step(model, args.batch_size)
    times: dict[str, list[float]] = {"SAC": [], "SGFD steady": [], "SGFD classifier training": []}
    for _ in range(args.steps):
        times["SAC"].append(time_step(sac, args.batch_size))
        times["SGFD steady"].append(time_step(steady, args.batch_size))
        times["SGFD classifier training"].append(time_step(training, args.batch_size))
    assert steady.classifier_ready and "weight_ess" in steady._sgfd_stats, "SGFD did not reweight"

    base = statistics.median(times["SAC"])
    print(f"{'update':<28}{'median s/step':>14}{'vs SAC':>9}")
    for name, values in times.items():
        median = statistics.median(values)
        print(f"{name:<28}{median:>14.3f}{median / base:>8.2f}x")
    ess = statistics.mean(steady._sgfd_stats["weight_ess"])
    print(
        f"SGFD steady-state overhead: {statistics.median(times['SGFD steady']) / base:.3f}x SAC (goal <= 1.10); "
        f"weight ESS {ess:.2f} n"
    )


if __name__ == "__main__":
    main()
