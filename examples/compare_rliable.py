"""Compare two algorithms over tasks and seeds with rliable: IQM with stratified-bootstrap confidence intervals.

Trains SGFD and the Domain Randomisation baseline (SB3's SAC with the same policy) on the training split of each
MT task for each seed, evaluates every run on a test split, and reports what Agarwal et al. (NeurIPS 2021)
recommend for few runs: the interquartile mean (IQM) of the normalised score (return / 1000) over all runs and
tasks with a 95% stratified-bootstrap confidence interval, and the probability that SGFD improves on DR.

The runs are those of ``mt_state_extrapolation.py`` (states with the varied length appended, that example's
settings), each in its own process, ``--jobs`` at a time. Five seeds are the least the studies in
``studies/`` rest on; fewer show the method, not an answer.

    python examples/compare_rliable.py                                    # 2 tasks x 3 seeds x 2 algorithms
    python examples/compare_rliable.py --tasks walker-walk --seeds 0 1 --steps 2000 --eval-episodes 4 --jobs 2
    python examples/compare_rliable.py --tasks walker-walk cheetah-run finger-spin --seeds 0 1 2 3 4 --jobs 2
"""

from __future__ import annotations

import argparse
import csv
import sys
import time
from concurrent.futures import ProcessPoolExecutor, as_completed
from pathlib import Path

import numpy as np
from rliable import library as rly
from rliable import metrics

sys.path.insert(0, str(Path(__file__).resolve().parent))
# The example beside this one: one run, trained and evaluated; and the examples' progress lines and records.
import mt_state_extrapolation
import progress

ALGOS = {"sgfd": "SGFD", "sac": "DR"}
MAX_RETURN = 1000.0  # a DeepMind Control episode earns at most 1 per simulator step of 1000


def run(algo: str, task: str, seed: int, steps: int, split: str, episodes: int, interval: float) -> float:
    """The mean return on ``split`` of one run trained on the training split of ``SGFD/MT-<task>-v0``; its progress
    lines every ``interval`` seconds."""
    argv = ["--algo", algo, "--env", f"SGFD/MT-{task}-v0", "--steps", str(steps), "--seed", str(seed)]
    argv += ["--eval-episodes", str(episodes), "--splits", split, "--verbose", "0", "--progress", str(interval)]
    return mt_state_extrapolation.main(argv)[split][0]


def interquartile_means(scores: dict[str, np.ndarray], reps: int, seed: int) -> tuple[dict, dict, dict, dict]:
    """IQM per algorithm and P(first algorithm > second), each with its 95% stratified-bootstrap interval.

    :param scores: algorithm -> normalised scores, runs (seeds) x tasks
    :param reps: bootstrap replications
    :param seed: seeds the bootstrap (rliable draws its indices from numpy's global generator)
    """
    np.random.seed(seed)
    iqm, iqm_ci = rly.get_interval_estimates(scores, lambda x: np.array([metrics.aggregate_iqm(x)]), reps=reps)
    first, second = scores
    pair = {f"{first} > {second}": (scores[first], scores[second])}
    improvement, improvement_ci = rly.get_interval_estimates(pair, metrics.probability_of_improvement, reps=reps)
    return iqm, iqm_ci, improvement, improvement_ci


def main(argv: list[str] | None = None) -> dict[str, float]:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--tasks", nargs="+", default=["walker-walk", "cheetah-run"], help="MT tasks (%(default)s)")
    parser.add_argument("--seeds", nargs="+", type=int, default=[0, 1, 2], help="(default: %(default)s)")
    parser.add_argument("--steps", type=int, default=20_000, help="agent steps per run (%(default)s)")
    parser.add_argument("--split", default="extrapolation", choices=("train", "interpolation", "extrapolation"))
    parser.add_argument("--eval-episodes", type=int, default=10, help="episodes per run (%(default)s)")
    parser.add_argument("--jobs", type=int, default=1, help="runs trained at once, one process each")
    parser.add_argument("--reps", type=int, default=2000, help="bootstrap replications (%(default)s)")
    parser.add_argument("--out", type=Path, default=None, help="write the scores to this csv")
    parser.add_argument("--progress", type=float, default=30.0, help="seconds between each run's progress lines")
    parser.add_argument("--record", default=None, help="write the command, machine, time and results (json)")
    args = parser.parse_args(argv)
    if args.jobs < 1:
        parser.error(f"--jobs must be at least 1, got {args.jobs}")

    runs = [(algo, task, seed) for algo in ALGOS for task in args.tasks for seed in args.seeds]
    machine, began = progress.machine(), time.perf_counter()
    print(f"{len(runs)} runs of {args.steps} steps, {args.jobs} at a time, each in its own process", flush=True)
    with ProcessPoolExecutor(max_workers=args.jobs) as pool:
        settings = (args.steps, args.split, args.eval_episodes, args.progress)
        futures = {pool.submit(run, *key, *settings): key for key in runs}
        done = {}
        for future in as_completed(futures):
            key = futures[future]
            done[key] = future.result()
            algo, task, seed = key
            print(
                f"[{len(done)}/{len(runs)}] {algo} {task} seed {seed}: {args.split} return {done[key]:.1f} "
                f"({progress.duration(time.perf_counter() - began)} in all)",
                flush=True,
            )
    returns = {key: done[key] for key in runs}

    if args.out:
        with args.out.open("w", newline="") as file:
            writer = csv.writer(file)
            writer.writerow(["algo", "task", "seed", "split", "return"])
            writer.writerows([ALGOS[a], t, s, args.split, r] for (a, t, s), r in returns.items())

    # rliable's layout: per algorithm a (runs x tasks) matrix of normalised scores.
    scores = {
        ALGOS[algo]: np.array([[returns[algo, task, seed] / MAX_RETURN for task in args.tasks] for seed in args.seeds])
        for algo in ALGOS
    }
    iqm, iqm_ci, improvement, improvement_ci = interquartile_means(scores, args.reps, seed=0)
    print(
        f"\n{args.split}: normalised score (return / 1000), {len(args.tasks)} task(s) x {len(args.seeds)} seed(s), "
        f"95% stratified-bootstrap CIs"
    )
    for name in scores:
        low, high = iqm_ci[name][:, 0]
        print(f"  IQM {name:>4}: {iqm[name][0]:.3f} [{low:.3f}, {high:.3f}]")
    for pair, value in improvement.items():
        low, high = np.asarray(improvement_ci[pair]).reshape(-1)[:2]
        print(f"  P({pair}): {value:.2f} [{low:.2f}, {high:.2f}]")
    seconds = time.perf_counter() - began
    print(f"{len(runs)} runs in {progress.duration(seconds)}")
    if args.record:
        figures = dict(
            wall_seconds=round(seconds, 1),
            returns={f"{ALGOS[a]} {t} seed {s}": round(r, 1) for (a, t, s), r in returns.items()},
            iqm={
                name: [round(float(iqm[name][0]), 3), *(round(float(v), 3) for v in iqm_ci[name][:, 0])]
                for name in scores
            },
            improvement={
                f"P({pair})": [
                    round(float(value), 2),
                    *(round(float(v), 2) for v in np.asarray(improvement_ci[pair]).reshape(-1)[:2]),
                ]
                for pair, value in improvement.items()
            },
        )
        progress.write_record(
            args.record, Path(__file__).name, list(sys.argv[1:] if argv is None else argv), figures, machine
        )
    return {name: float(iqm[name][0]) for name in scores}


if __name__ == "__main__":
    main()
