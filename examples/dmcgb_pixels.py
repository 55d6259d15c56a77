"""Train a pixel agent on DMC-GB's undistracted task and evaluate it on DMC-GB's test modes.

DMC-GB (Hansen & Wang 2021) trains on dm_control's task as it is (``split="train"``) and tests on changed
colours (``color_easy``, ``color_hard``) and video backgrounds (``video_easy``, ``video_hard``). The agent sees
84x84 pixels, three frames stacked and transposed to channels-first as the zoo wraps them (``VecFrameStack``,
then ``VecTransposeImage``); the replay buffer stores each frame once (``frame_stack=3``). Without ``--data-dir``
the colour sets and videos are the built-in stand-ins (see the docs' Benchmarks page); with it, DMC-GB's files.

The default agent is TED (a classifier of temporal pairs trained with the encoder, on random-shift
augmentation); ``--algo`` picks another. The networks are sized for a CPU (256-wide heads, the paper's 4-layer
encoder): pixel training is slow on a CPU, and a GPU is picked when there is one.

    python examples/dmcgb_pixels.py                                       # TED, walker-walk, 10k steps
    python examples/dmcgb_pixels.py --algo sgqn --eval-splits color_hard video_hard
    python examples/dmcgb_pixels.py --data-dir dmcontrol-generalization-benchmark/src/env/data
"""

from __future__ import annotations

import argparse
import time

import torch
from stable_baselines3.common.evaluation import evaluate_policy
from stable_baselines3.common.vec_env import VecEnv, VecFrameStack, VecTransposeImage

import sgfd_envs  # registers the DMCGB/* ids
from sb3_sgfd import AMBS, DBC, SGQN, TED, EncoderSAC

FRAME_STACK = 3
ALGOS = {
    "ted": (TED, dict(augmentation_views=1)),  # TED on RAD's random shift, as its paper
    "sgqn": (SGQN, dict()),
    "ambs": (AMBS, dict(augmentation_views=2, encoder_tau=0.05, max_grad_norm=40.0)),
    "dbc": (DBC, dict()),
    "drq": (EncoderSAC, dict(augmentation_views=2)),  # SAC with two random-shift views (DrQ), no objective
}


def make_env(env_id: str, split: str, seed: int, **env_kwargs) -> VecEnv:
    """One split of a DMC-GB id as the agent sees it: frames stacked, channels first.

    :param env_id: a ``DMCGB/<task>-v0`` id
    :param split: ``"train"`` or a test mode
    :param seed: seed of the environment
    :param env_kwargs: passed to the environment (``data_dir=``, ``render=``)
    """
    env = sgfd_envs.make_domain_vec_env(env_id, split=split, seed=seed, **env_kwargs)
    return VecTransposeImage(VecFrameStack(env, FRAME_STACK))


def main(argv: list[str] | None = None) -> dict[str, tuple[float, float]]:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--env", default="DMCGB/walker-walk-v0", help="a DMCGB/ id (default: %(default)s)")
    parser.add_argument("--algo", choices=tuple(ALGOS), default="ted")
    parser.add_argument("--steps", type=int, default=10_000, help="agent steps (default: %(default)s)")
    parser.add_argument(
        "--eval-splits", nargs="+", default=["color_hard", "video_easy"], help="test modes (%(default)s)"
    )
    parser.add_argument("--eval-episodes", type=int, default=5, help="episodes per split (%(default)s)")
    parser.add_argument("--batch-size", type=int, default=128)
    parser.add_argument("--buffer-size", type=int, default=100_000, help="transitions kept (%(default)s)")
    parser.add_argument("--data-dir", default=None, help="DMC-GB's src/env/data (default: the built-in stand-ins)")
    parser.add_argument(
        "--render",
        choices=("benchmark", "fast"),
        default="benchmark",
        help="benchmark: DMC-GB's pictures (shadows, reflections, multisampling); fast: none of them, several times "
        "faster on a CPU, not the benchmark's pixels",
    )
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--save", default=None, help="save the model to this path (.zip)")
    parser.add_argument("--verbose", type=int, default=1, help="1: SB3's table every 4 episodes, 0: quiet")
    args = parser.parse_args(argv)
    if args.steps <= 0:
        parser.error(f"--steps must be positive, got {args.steps}")
    allowed = sgfd_envs.test_splits(args.env)
    for split in args.eval_splits:
        if split not in allowed:
            parser.error(f"--eval-splits: {split!r} is not a test mode of {args.env}; expected one of {allowed}")
    env_kwargs: dict = dict(render=args.render)
    if args.data_dir is not None:
        env_kwargs["data_dir"] = args.data_dir

    algo_class, algo_kwargs = ALGOS[args.algo]
    model = algo_class(
        "CnnPolicy",
        make_env(args.env, "train", args.seed, **env_kwargs),
        buffer_size=min(args.buffer_size, args.steps),
        batch_size=args.batch_size,
        learning_starts=min(1000, args.steps // 2),
        replay_buffer_kwargs=dict(frame_stack=FRAME_STACK),  # each rendered frame stored once
        policy_kwargs=dict(net_arch=[256, 256], features_extractor_kwargs=dict(features_dim=50)),
        seed=args.seed,
        verbose=args.verbose,
        **algo_kwargs,
    )
    print(f"{args.algo} on {args.env} (train), device {model.device}, torch threads {torch.get_num_threads()}")
    start, cpu_start = time.perf_counter(), time.process_time()
    model.learn(args.steps)
    seconds, cpu_seconds = time.perf_counter() - start, time.process_time() - cpu_start
    # Wall time depends on what else the machine runs; the process's CPU time (over all its threads) much less.
    print(
        f"trained {args.steps} steps in {seconds:.0f} s: {1000 * seconds / args.steps:.0f} ms per step "
        f"({1000 * cpu_seconds / args.steps:.0f} ms of CPU)"
    )
    if args.save:
        model.save(args.save)

    returns = {}
    for split in ["train", *args.eval_splits]:
        env = make_env(args.env, split, args.seed + 1000, **env_kwargs)
        mean, std = evaluate_policy(model, env, n_eval_episodes=args.eval_episodes)
        env.close()
        returns[split] = (float(mean), float(std))
        print(f"{split:>12}: return {mean:7.1f} ± {std:.1f} over {args.eval_episodes} episodes")
    return returns


if __name__ == "__main__":
    main()
