"""
``sgfd-zoo quick``: the whole pipeline in a few minutes on a CPU. Trains SGFD_SAC and the SAC
(Domain Randomisation) baseline with the quick configuration (zoo/hyperparams/quick: state
observations, small networks), evaluates them on the training domains and the unseen ones and prints
the paper-style tables, then plots the learning curves. Runs already finished in the folder are kept.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import sgfd_envs
from zoo import evaluate, plot
from zoo.algos import SGFD_ALGOS
from zoo.cli import check_env_id, train
from zoo.experiment import ZooError


def main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(prog="sgfd-zoo quick", description=__doc__)
    parser.add_argument("--env", default="SGFD/MT-walker-walk-v0", help="an SGFD id")
    parser.add_argument("--algos", nargs="+", default=["sgfd_sac", "sac"], choices=sorted(SGFD_ALGOS))
    parser.add_argument("--seeds", nargs="+", type=int, default=[0, 1])
    parser.add_argument("-f", "--folder", type=Path, default=Path("logs/quick"), help="log folder")
    parser.add_argument("-n", "--n-timesteps", type=int, help="override the quick configuration's steps")
    parser.add_argument("--eval-episodes", type=int, default=4, help="episodes per split")
    args = parser.parse_args(argv)
    check_env_id(args.env)
    if args.n_timesteps is not None and args.n_timesteps < 1:
        raise ZooError(f"--n-timesteps must be >= 1, got {args.n_timesteps}")

    n_timesteps = args.n_timesteps or 20_000
    for algo in args.algos:
        done = (
            {run.seed for run in evaluate.find_runs(args.folder, [algo], [args.env])} if args.folder.is_dir() else set()
        )
        for seed in args.seeds:
            if seed in done:
                print(f"{algo} seed {seed}: already trained in {args.folder}")
                continue
            print(f"=== {algo} on {args.env}, seed {seed} ===")
            train_args = ["--algo", algo, "--env", args.env, "--quick", "-f", str(args.folder), "--seed", str(seed)]
            train_args += ["--eval-freq", str(max(n_timesteps // 5, 1)), "--eval-episodes", str(args.eval_episodes)]
            train_args += ["--num-threads", "1", "--verbose", "0"]
            if args.n_timesteps is not None:
                train_args += ["-n", str(args.n_timesteps)]
            train(train_args)
    splits = ", ".join(sgfd_envs.splits(args.env))
    print(f"=== evaluation on {splits} ===")
    evaluate.main(
        ["-f", str(args.folder), "--env", args.env, "--algo", *args.algos, "--n-episodes", str(args.eval_episodes)]
    )
    plot.main(["-f", str(args.folder)])
    return 0
