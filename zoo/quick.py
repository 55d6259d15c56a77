"""
``sgfd-zoo quick``: the whole pipeline in a few minutes on a CPU. A sweep (``sgfd-zoo sweep``) of SGFD_SAC
and the SAC (Domain Randomisation) baseline with the quick configuration (zoo/hyperparams/quick: state
observations, small networks, 20k steps), one run per CPU core at a time; then evaluation on the training
domains and the unseen ones (the paper-style tables are printed) and the learning curves. Runs already
finished in the folder are kept, so running it again only adds what is missing (e.g. more --seeds).
"""

from __future__ import annotations

import argparse
from pathlib import Path

from zoo import plot, sweep
from zoo.algos import SGFD_ALGOS
from zoo.cli import check_env_id
from zoo.experiment import ZooError


def main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(prog="sgfd-zoo quick", description=__doc__)
    parser.add_argument("--env", default="SGFD/MT-walker-walk-v0", help="an SGFD id")
    parser.add_argument("--algos", nargs="+", default=["sgfd_sac", "sac"], choices=sorted(SGFD_ALGOS))
    parser.add_argument("--seeds", nargs="+", type=int, default=[0], help="more seeds give the tables a spread")
    parser.add_argument("-f", "--folder", type=Path, default=Path("logs/quick"), help="log folder")
    parser.add_argument("-n", "--n-timesteps", type=int, help="override the quick configuration's 20k steps")
    parser.add_argument("--eval-episodes", type=int, default=8, help="episodes per split")
    args = parser.parse_args(argv)
    check_env_id(args.env)
    if args.n_timesteps is not None and args.n_timesteps < 1:
        raise ZooError(f"--n-timesteps must be >= 1, got {args.n_timesteps}")
    if args.eval_episodes < 1:
        raise ZooError(f"--eval-episodes must be >= 1, got {args.eval_episodes}")

    n_timesteps = args.n_timesteps or 20_000
    sweep_args = ["--algos", *args.algos, "--envs", args.env, "--seeds", *map(str, args.seeds)]
    sweep_args += ["-f", str(args.folder), "--n-episodes", str(args.eval_episodes)]
    train_args = ["--quick", "--eval-freq", str(max(n_timesteps // 4, 1)), "--eval-episodes", str(args.eval_episodes)]
    train_args += ["--no-progress", "--verbose", "0"]
    if args.n_timesteps is not None:
        train_args += ["-n", str(args.n_timesteps)]
    status = sweep.main([*sweep_args, *train_args])
    if status == 0:
        plot.main(["-f", str(args.folder)])
    return status
