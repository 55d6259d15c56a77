"""Train SGFD on four robot morphologies and evaluate it on morphologies it never saw.

The agent trains on the ``train`` split of an MT id (4 robots, one sub-env each) and is evaluated on the
``interpolation`` and ``extrapolation`` splits. Both sides observe the same thing: the robot's state with the
varied length appended (``obs_type="state"``, ``observe_parameter=True``), so a policy trained on one can be
evaluated on the other. The example's own settings, small enough for a laptop: 256-wide networks, one update per
collected transition, the weights on the actor's loss only (the ``sgfd-zoo quick`` configuration is similar but
not the same; its values live in ``sgfd_zoo/hyperparams/quick/``).

    python examples/mt_state_extrapolation.py                          # 20k steps on MT-walker-walk
    python examples/mt_state_extrapolation.py --env SGFD/MT-cheetah-run-v0 --save sgfd_cheetah
    python examples/mt_state_extrapolation.py --algo sac               # the Domain Randomisation baseline
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import torch
from stable_baselines3 import SAC

import sgfd_envs  # registers the SGFD/* ids
from sb3_sgfd import SGFD_SAC, MlpPolicy

sys.path.insert(0, str(Path(__file__).resolve().parent))
# The examples' progress lines and records, beside this file.
import progress

OBSERVATION = dict(obs_type="state", observe_parameter=True)  # the same on the training and the test splits


def make_model(algo: str, env_id: str, seed: int, steps: int, classifier_start: int, verbose: int = 0) -> SAC:
    """SGFD_SAC (``algo="sgfd"``) or SB3's SAC with the same policy (``"sac"``, Domain Randomisation) on the
    training split of ``env_id``.

    :param algo: ``"sgfd"`` or ``"sac"``
    :param env_id: an MT id, e.g. ``"SGFD/MT-walker-walk-v0"``
    :param seed: seed of the model and the environments
    :param steps: the steps it will train (a short run takes fewer random actions first)
    :param classifier_start: step from which SGFD's domain classifier trains (its weights follow once it is
        accurate); a run shorter than this is plain SAC
    :param verbose: SB3's verbosity (1: a table of training figures every 4 episodes)
    """
    train_env = sgfd_envs.make_domain_vec_env(env_id, split="train", seed=seed, **OBSERVATION)
    common = dict(
        policy_kwargs=dict(net_arch=[256, 256]),
        learning_rate=1e-3,
        batch_size=128,
        tau=0.01,
        learning_starts=min(1000, steps // 2),  # random actions first (1000, or half a short run)
        gradient_steps=-1,  # one update per collected transition (4 per step of the 4 sub-envs)
        seed=seed,
        verbose=verbose,
    )
    if algo == "sac":
        return SAC(MlpPolicy, train_env, **common)
    return SGFD_SAC(
        "MlpPolicy",
        train_env,
        classifier_start=classifier_start,
        actor_update_interval=1,  # as SAC above, so that the comparison isolates the reweighting
        reweight_critic=False,  # the weights on the actor's loss only, as Algorithm 1 (line 19)
        **common,
    )


def evaluate(
    model: SAC, env_id: str, splits: list[str], episodes: int, seed: int, label: str = "evaluate"
) -> dict[str, tuple[float, float]]:
    """Mean and std of the episode return on each split, with a line per episode.

    :param model: a trained model
    :param env_id: the id it trained on
    :param splits: splits of ``env_id`` (``"train"``: the training domains)
    :param episodes: episodes per split
    :param seed: seed of the evaluation environments
    :param label: the start of each progress line
    """
    returns = {}
    for split in splits:
        env = sgfd_envs.make_domain_vec_env(env_id, split=split, seed=seed + 1000, **OBSERVATION)
        returns[split] = progress.mean_and_std(progress.evaluate(model, env, episodes, f"{label} {split}"))
        env.close()
    return returns


def main(argv: list[str] | None = None) -> dict[str, tuple[float, float]]:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--env", default="SGFD/MT-walker-walk-v0", help="an MT id (default: %(default)s)")
    parser.add_argument("--algo", choices=("sgfd", "sac"), default="sgfd", help="sac: Domain Randomisation")
    parser.add_argument("--steps", type=int, default=20_000, help="agent steps over all sub-envs (%(default)s)")
    parser.add_argument("--classifier-start", type=int, default=None, help="default: a fifth of --steps")
    parser.add_argument("--eval-episodes", type=int, default=10, help="episodes per split (%(default)s)")
    parser.add_argument("--splits", nargs="+", default=None, help="splits to evaluate on (default: every one)")
    progress.add_run_arguments(parser)
    args = parser.parse_args(argv)
    if args.steps <= 0:
        parser.error(f"--steps must be positive, got {args.steps}")
    splits = sgfd_envs.splits(args.env) if args.splits is None else args.splits
    for split in splits:
        if split not in sgfd_envs.splits(args.env):
            parser.error(f"--splits: {split!r} is not a split of {args.env}; expected {sgfd_envs.splits(args.env)}")
    torch.set_num_threads(1)  # small networks: one thread is as fast, and leaves the other cores free

    classifier_start = args.steps // 5 if args.classifier_start is None else args.classifier_start
    machine, began = progress.machine(), time.perf_counter()
    model = make_model(args.algo, args.env, args.seed, args.steps, classifier_start, args.verbose)
    run = f"{args.algo} {args.env.split('/')[-1]} seed {args.seed}"
    seconds, cpu_seconds = progress.learn_timed(model, args.steps, f"train {run}", args.progress, ms_digits=1)
    if args.save:
        model.save(args.save)

    eval_start = time.perf_counter()
    returns = evaluate(model, args.env, splits, args.eval_episodes, args.seed, f"evaluate {run}")
    eval_seconds = time.perf_counter() - eval_start
    progress.print_returns(returns, args.eval_episodes, eval_seconds)
    if args.record:
        times, argv = (seconds, cpu_seconds, eval_seconds), list(sys.argv[1:] if argv is None else argv)
        progress.write_run_record(args, Path(__file__).name, argv, machine, began, times, returns, ms_digits=1)
    return returns


if __name__ == "__main__":
    main()
