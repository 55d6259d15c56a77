"""
``sgfd-zoo quick``: the whole pipeline in about ten minutes on a 2-core CPU. A sweep (``sgfd-zoo sweep``) of
SGFD_SAC and the SAC (Domain Randomisation) baseline with the quick configuration (sgfd_zoo/hyperparams/quick:
state observations with the morphology parameter, small networks, 20k steps) on two seeds, one run per CPU
core at a time, with live progress; then evaluation on the training domains and the unseen ones: the
paper-style tables, and the aggregate statistics with 95% confidence intervals over the seeds; and the
learning curves. Runs already finished in the folder are kept, so running it again only adds what is
missing (e.g. more --seeds).
"""

from __future__ import annotations

import argparse
from pathlib import Path

from sgfd_zoo import plot, sweep
from sgfd_zoo.algos import SGFD_ALGOS
from sgfd_zoo.arguments import check_at_least, check_env_id

DEFAULT_STEPS = 20_000


def main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(prog="sgfd-zoo quick", description=__doc__)
    parser.add_argument("--env", default="SGFD/MT-walker-walk-v0", help="a registered id (sgfd_envs.ENV_IDS)")
    parser.add_argument("--algos", nargs="+", default=["sgfd_sac", "sac"], choices=sorted(SGFD_ALGOS))
    parser.add_argument("--seeds", nargs="+", type=int, default=[0, 1], help="seeds: the spread of the results")
    parser.add_argument("-f", "--folder", type=Path, default=Path("logs/quick"), help="log folder")
    parser.add_argument("-n", "--n-timesteps", type=int, help=f"override the quick configuration's {DEFAULT_STEPS}")
    parser.add_argument("--eval-episodes", type=int, default=8, help="episodes per split")
    parser.add_argument(
        "--progress-interval", type=float, default=60.0, help="seconds between progress blocks in a log"
    )
    args = parser.parse_args(argv)
    check_env_id(args.env)
    check_at_least("--n-timesteps", args.n_timesteps, 1)
    check_at_least("--eval-episodes", args.eval_episodes, 1)

    n_timesteps = args.n_timesteps or DEFAULT_STEPS
    sweep_args = ["--algos", *args.algos, "--envs", args.env, "--seeds", *map(str, args.seeds)]
    sweep_args += ["-f", str(args.folder), "--n-episodes", str(args.eval_episodes)]
    sweep_args += ["--progress-interval", str(args.progress_interval)]
    train_args = ["--quick", "--eval-freq", str(max(n_timesteps // 4, 1)), "--eval-episodes", str(args.eval_episodes)]
    train_args += ["--no-progress", "--verbose", "0"]
    if args.n_timesteps is not None:
        train_args += ["-n", str(args.n_timesteps)]
    status = sweep.main([*sweep_args, *train_args])
    if status == 0:
        plot.main(["-f", str(args.folder)])
    return status
