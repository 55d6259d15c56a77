"""Train a pixel agent on DMC-GB's undistracted task and evaluate it on DMC-GB's test modes.

DMC-GB (Hansen & Wang 2021) trains on dm_control's task as it is (``split="train"``) and tests on changed
colours (``color_easy``, ``color_hard``) and video backgrounds (``video_easy``, ``video_hard``). The agent sees
84x84 pixels, three frames stacked and transposed to channels-first as the zoo wraps them (``VecFrameStack``,
then ``VecTransposeImage``); the replay buffer stores each frame once (``frame_stack=3``). Without ``--data-dir``
the colour sets and videos are the built-in stand-ins (see the docs' Benchmarks page); with it, DMC-GB's files.

The default agent is TED (a classifier of temporal pairs trained with the encoder, on random-shift
augmentation); ``--algo`` picks another. The networks are sized for a CPU (256-wide heads, the paper's 4-layer
encoder): pixel training is slow on a CPU, and a GPU is picked when there is one. ``--cpu-size`` is a run that
finishes in minutes on a laptop's CPU: 600 steps at 64x64 pixels, batch 32, fast rendering, one episode per split.

    python examples/dmcgb_pixels.py                                       # TED, walker-walk, 10k steps
    python examples/dmcgb_pixels.py --cpu-size                            # minutes on a CPU, end to end
    python examples/dmcgb_pixels.py --algo sgqn --eval-splits color_hard video_hard
    python examples/dmcgb_pixels.py --data-dir dmcontrol-generalization-benchmark/src/env/data
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import torch
from stable_baselines3.common.vec_env import VecEnv, VecFrameStack, VecTransposeImage

import sgfd_envs  # registers the DMCGB/* ids
from sb3_sgfd import AMBS, DBC, SGQN, TED, EncoderSAC

sys.path.insert(0, str(Path(__file__).resolve().parent))
# The examples' progress lines and records, beside this file.
import progress

FRAME_STACK = 3
ALGOS = {
    "ted": (TED, dict(augmentation_views=1)),  # TED on RAD's random shift, as its paper
    "sgqn": (SGQN, dict()),
    "ambs": (AMBS, dict(augmentation_views=2, encoder_tau=0.05, max_grad_norm=40.0)),
    "dbc": (DBC, dict()),
    "drq": (EncoderSAC, dict(augmentation_views=2)),  # SAC with two random-shift views (DrQ), no objective
}
# The run's size: the default (a GPU's run), or --cpu-size (minutes on a CPU); a flag given explicitly wins.
DEFAULT_SIZE = dict(steps=10_000, batch_size=128, image_size=84, render="benchmark", eval_episodes=5)
CPU_SIZE = dict(steps=600, batch_size=32, image_size=64, render="fast", eval_episodes=1)


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
    parser.add_argument("--steps", type=int, default=None, help="agent steps (default: 10000)")
    parser.add_argument(
        "--eval-splits", nargs="+", default=["color_hard", "video_easy"], help="test modes (%(default)s)"
    )
    parser.add_argument("--eval-episodes", type=int, default=None, help="episodes per split (default: 5)")
    parser.add_argument("--batch-size", type=int, default=None, help="(default: 128)")
    parser.add_argument("--image-size", type=int, default=None, help="height and width of the pixels (default: 84)")
    parser.add_argument("--buffer-size", type=int, default=100_000, help="transitions kept (%(default)s)")
    parser.add_argument("--data-dir", default=None, help="DMC-GB's src/env/data (default: the built-in stand-ins)")
    parser.add_argument(
        "--render",
        choices=("benchmark", "fast"),
        default=None,
        help="benchmark (default): DMC-GB's pictures (shadows, reflections, multisampling); fast: none of them, "
        "several times faster on a CPU, not the benchmark's pixels",
    )
    parser.add_argument(
        "--cpu-size",
        action="store_true",
        help="a run of minutes on a CPU: "
        + ", ".join(f"--{key.replace('_', '-')} {value}" for key, value in CPU_SIZE.items())
        + " (each unless given)",
    )
    parser.add_argument("--threads", type=int, default=1, help="torch's CPU threads (%(default)s)")
    progress.add_run_arguments(parser)
    args = parser.parse_args(argv)
    for key, value in (CPU_SIZE if args.cpu_size else DEFAULT_SIZE).items():
        if getattr(args, key) is None:
            setattr(args, key, value)
    for flag in ("steps", "batch_size", "image_size", "eval_episodes", "threads"):
        if getattr(args, flag) <= 0:
            parser.error(f"--{flag.replace('_', '-')} must be positive, got {getattr(args, flag)}")
    allowed = sgfd_envs.test_splits(args.env)
    for split in args.eval_splits:
        if split not in allowed:
            parser.error(f"--eval-splits: {split!r} is not a test mode of {args.env}; expected one of {allowed}")
    env_kwargs: dict = dict(render=args.render, image_size=args.image_size)
    if args.data_dir is not None:
        env_kwargs["data_dir"] = args.data_dir
    torch.set_num_threads(args.threads)

    machine, began = progress.machine(), time.perf_counter()
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
    print(
        f"{args.algo} on {args.env} (train), {args.steps} steps, batch {args.batch_size}, "
        f"{args.image_size}x{args.image_size} pixels ({args.render} rendering), device {model.device}, "
        f"torch threads {torch.get_num_threads()}",
        flush=True,
    )
    seconds, cpu_seconds = progress.learn_timed(model, args.steps, f"train {args.algo}", args.progress)
    if args.save:
        model.save(args.save)

    splits = ["train", *args.eval_splits]
    print(f"evaluating on {', '.join(splits)}: {args.eval_episodes} episode(s) each", flush=True)
    eval_start = time.perf_counter()
    returns = {}
    for split in splits:
        env = make_env(args.env, split, args.seed + 1000, **env_kwargs)
        returns[split] = progress.mean_and_std(
            progress.evaluate(model, env, args.eval_episodes, f"evaluate {split}", args.progress)
        )
        env.close()
    eval_seconds = time.perf_counter() - eval_start
    progress.print_returns(returns, args.eval_episodes, eval_seconds)
    if args.record:
        times, argv = (seconds, cpu_seconds, eval_seconds), list(sys.argv[1:] if argv is None else argv)
        progress.write_run_record(args, Path(__file__).name, argv, machine, began, times, returns)
    return returns


if __name__ == "__main__":
    main()
