"""``sgfd-zoo evaluate``: every trained model of a log folder on every split, as the paper's tables."""

from __future__ import annotations

import argparse
import csv
import io
from collections import defaultdict
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch as th
import yaml
from huggingface_sb3 import EnvironmentName
from pytablewriter import MarkdownTableWriter
from rl_zoo3.utils import ALGOS
from stable_baselines3.common.evaluation import evaluate_policy

import sgfd_envs
from zoo.algos import SGFD_ALGOS, column_name, register_algorithms
from zoo.experiment import ZooError, wrap_like_training

RESULT_FIELDS = ["algo", "env", "split", "seed", "mean_reward", "std_reward", "n_episodes", "run"]
# Order of the paper's tables: SGFD first, then the baselines and ablations.
ALGO_ORDER = list(SGFD_ALGOS)


@dataclass(frozen=True)
class Run:
    """One finished training run in rl-zoo3's layout: <folder>/<algo>/<EnvName>_<id>/<EnvName>.zip."""

    algo: str
    env_id: str
    path: Path
    seed: int
    env_kwargs: dict[str, Any]
    frame_stack: int | None

    @property
    def model_path(self) -> Path:
        return self.path / f"{EnvironmentName(self.env_id)}.zip"


def find_runs(folder: Path, algos: list[str] | None = None, env_ids: list[str] | None = None) -> list[Run]:
    """The finished runs under ``folder``, optionally only of some algorithms and env ids."""
    runs = []
    names = {str(EnvironmentName(env_id)): env_id for env_id in sgfd_envs.SGFD_IDS}
    for algo_dir in sorted(path for path in folder.iterdir() if path.is_dir()):
        if algos and algo_dir.name not in algos:
            continue
        for run_dir in sorted(path for path in algo_dir.iterdir() if path.is_dir()):
            env_name, _, run_id = run_dir.name.rpartition("_")
            if env_name not in names or not run_id.isdigit() or (env_ids and names[env_name] not in env_ids):
                continue
            config_dir = run_dir / env_name
            if not (run_dir / f"{env_name}.zip").exists() or not (config_dir / "args.yml").exists():
                continue  # unfinished (or crashed: resume it with `sgfd-zoo train --resume`)
            args = yaml.load((config_dir / "args.yml").read_text(), Loader=yaml.UnsafeLoader)
            config = yaml.load((config_dir / "config.yml").read_text(), Loader=yaml.UnsafeLoader)
            env_kwargs = args.get("env_kwargs") or config.get("env_kwargs") or {}
            frame_stack = config.get("frame_stack")
            runs.append(Run(algo_dir.name, names[env_name], run_dir, int(args["seed"]), env_kwargs, frame_stack))
    return runs


def evaluate_run(run: Run, n_episodes: int, seed: int = 0) -> list[dict[str, Any]]:
    """Mean and std of the episode return of ``run``'s final model on each split of its env."""
    register_algorithms()
    if run.algo not in ALGOS:
        raise ZooError(f"{run.path}: unknown algorithm {run.algo!r}")
    # Evaluation needs no replay buffer: don't allocate the training one.
    model = ALGOS[run.algo].load(run.model_path, custom_objects={"buffer_size": 1}, device="cpu")
    rows = []
    for split in sgfd_envs.splits(run.env_id):
        env = sgfd_envs.make_domain_vec_env(run.env_id, split=split, seed=seed, **run.env_kwargs)
        env = wrap_like_training(env, run.frame_stack)
        rewards, _ = evaluate_policy(model, env, n_eval_episodes=n_episodes, return_episode_rewards=True)
        env.close()
        rows.append(
            {
                "algo": run.algo,
                "env": run.env_id,
                "split": split,
                "seed": run.seed,
                "mean_reward": float(np.mean(rewards)),
                "std_reward": float(np.std(rewards)),
                "n_episodes": len(rewards),
                "run": str(run.path),
            }
        )
    return rows


def render_tables(results: list[dict[str, Any]]) -> str:
    """
    The paper's layout, one markdown table per split: tasks as rows, algorithms as columns,
    ``mean ± std`` over seeds (of each seed's mean return), and a Total row summing the means.
    """
    by_cell: dict[tuple[str, str, str], list[float]] = defaultdict(list)
    for row in results:
        by_cell[(row["split"], row["env"], row["algo"])].append(float(row["mean_reward"]))
    split_order = ["train", "test", "interpolation", "extrapolation"]
    splits = sorted({key[0] for key in by_cell}, key=lambda s: (split_order.index(s) if s in split_order else 99, s))
    out = io.StringIO()
    for split in splits:
        envs = sorted({env for s, env, _ in by_cell if s == split})
        algos = sorted(
            {algo for s, _, algo in by_cell if s == split},
            key=lambda a: (ALGO_ORDER.index(a) if a in ALGO_ORDER else 99, a),
        )
        totals = dict.fromkeys(algos, 0.0)
        matrix = []
        for env in envs:
            cells = [_task_name(env)]
            for algo in algos:
                values = by_cell.get((split, env, algo))
                if values is None:
                    cells.append("–")
                    continue
                totals[algo] += float(np.mean(values))
                cells.append(f"{np.mean(values):.1f} ± {np.std(values):.1f}")
            matrix.append(cells)
        matrix.append(["**Total**", *(f"**{totals[algo]:.1f}**" for algo in algos)])
        counts = [len(values) for (s, _, _), values in by_cell.items() if s == split]
        seeds = str(min(counts)) if min(counts) == max(counts) else f"{min(counts)}-{max(counts)}"
        writer = MarkdownTableWriter(
            table_name=f"{split} (mean ± std over {seeds} seed{'s' if max(counts) > 1 else ''})",
            headers=["Task", *(column_name(algo) for algo in algos)],
            value_matrix=matrix,
        )
        writer.margin = 1
        out.write(writer.dumps())
        out.write("\n")
    return out.getvalue()


def _task_name(env_id: str) -> str:
    return env_id.split("/", 1)[-1].rsplit("-v", 1)[0]


def write_results(results: list[dict[str, Any]], folder: Path) -> tuple[Path, Path]:
    csv_path, md_path = folder / "results.csv", folder / "results.md"
    with csv_path.open("w", newline="") as handle:
        writer = csv.DictWriter(handle, fieldnames=RESULT_FIELDS)
        writer.writeheader()
        writer.writerows(results)
    md_path.write_text(render_tables(results))
    return csv_path, md_path


def read_results(path: Path) -> list[dict[str, Any]]:
    with path.open(newline="") as handle:
        return list(csv.DictReader(handle))


def main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(prog="sgfd-zoo evaluate", description=__doc__)
    parser.add_argument("-f", "--folder", required=True, type=Path, help="log folder of sgfd-zoo train")
    parser.add_argument("--algo", nargs="+", help="only these algorithm keys")
    parser.add_argument("--env", nargs="+", help="only these env ids")
    parser.add_argument("--n-episodes", type=int, default=10, help="episodes per split (spread over its domains)")
    parser.add_argument("--seed", type=int, default=0, help="seed of the evaluation envs")
    parser.add_argument(
        "--num-threads", type=int, default=1, help="torch threads (small-batch inference: more only contend)"
    )
    args = parser.parse_args(argv)
    if not args.folder.is_dir():
        raise ZooError(f"--folder {args.folder} does not exist (train first: sgfd-zoo train -f {args.folder} ...)")
    if args.n_episodes < 1:
        raise ZooError(f"--n-episodes must be >= 1, got {args.n_episodes}")
    if args.num_threads < 1:
        raise ZooError(f"--num-threads must be >= 1, got {args.num_threads}")
    th.set_num_threads(args.num_threads)
    for env_id in args.env or []:
        if env_id not in sgfd_envs.SGFD_IDS:
            raise ZooError(f"--env {env_id!r} is not an SGFD id; choose from {', '.join(sgfd_envs.SGFD_IDS)}")
    runs = find_runs(args.folder, args.algo, args.env)
    if not runs:
        raise ZooError(f"no finished run under {args.folder} (expected <algo>/<EnvName>_<id>/<EnvName>.zip)")
    results = []
    for run in runs:
        print(f"Evaluating {run.algo} on {run.env_id} (seed {run.seed}): {run.path}")
        results += evaluate_run(run, args.n_episodes, args.seed)
    csv_path, md_path = write_results(results, args.folder)
    print()
    print(md_path.read_text())
    print(f"Wrote {csv_path} and {md_path}")
    return 0
