"""``sgfd-zoo plot``: learning curves per split and algorithm, mean and a band over seeds."""

from __future__ import annotations

import argparse
from collections import defaultdict
from pathlib import Path

import numpy as np
from huggingface_sb3 import EnvironmentName
from matplotlib.figure import Figure  # no pyplot: no GUI backend, no global figure state

import sgfd_envs
from zoo.algos import column_name
from zoo.experiment import ZooError


def load_curves(folder: Path) -> dict[str, dict[str, dict[str, list[tuple[np.ndarray, np.ndarray]]]]]:
    """env id -> split -> algo -> one (timesteps, mean return) curve per run, from evaluations_<split>.npz."""
    names = {str(EnvironmentName(env_id)): env_id for env_id in sgfd_envs.SGFD_IDS}
    curves: dict = defaultdict(lambda: defaultdict(lambda: defaultdict(list)))
    for npz in sorted(folder.glob("*/*/evaluations_*.npz")):
        run_dir, algo = npz.parent, npz.parent.parent.name
        env_name = run_dir.name.rpartition("_")[0]
        if env_name not in names:
            continue
        split = npz.stem.removeprefix("evaluations_")
        with np.load(npz) as data:
            if len(data["timesteps"]) == 0:
                continue
            curves[names[env_name]][split][algo].append((data["timesteps"], data["results"].mean(axis=1)))
    return curves


def mean_and_band(runs: list[tuple[np.ndarray, np.ndarray]]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Mean and ± one standard deviation over runs, on the evaluation steps all runs share."""
    length = min(len(steps) for steps, _ in runs)
    steps = runs[0][0][:length]
    values = np.stack([returns[:length] for _, returns in runs])
    mean, std = values.mean(axis=0), values.std(axis=0)
    return steps, mean, std


def plot_env(env_id: str, curves: dict[str, dict[str, list]], out: Path) -> Path:
    splits = [split for split in sgfd_envs.splits(env_id) if split in curves]
    fig = Figure(figsize=(4.5 * len(splits), 3.5))
    axes = fig.subplots(1, len(splits), squeeze=False)
    for ax, split in zip(axes[0], splits, strict=True):
        for algo, runs in sorted(curves[split].items()):
            steps, mean, std = mean_and_band(runs)
            label = f"{column_name(algo)} ({len(runs)} seed{'s' if len(runs) > 1 else ''})"
            (line,) = ax.plot(steps, mean, label=label)
            ax.fill_between(steps, mean - std, mean + std, color=line.get_color(), alpha=0.2)
        ax.set_title(f"{env_id.split('/')[-1]}: {split}")
        ax.set_xlabel("environment steps")
        ax.set_ylabel("episode return")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    fig.tight_layout()
    path = out / f"{EnvironmentName(env_id)}.png"
    fig.savefig(path, dpi=100)
    return path


def main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(prog="sgfd-zoo plot", description=__doc__)
    parser.add_argument("-f", "--folder", required=True, type=Path, help="log folder of sgfd-zoo train")
    parser.add_argument("-o", "--out", type=Path, help="output folder (default: <folder>/plots)")
    args = parser.parse_args(argv)
    if not args.folder.is_dir():
        raise ZooError(f"--folder {args.folder} does not exist")
    curves = load_curves(args.folder)
    if not curves:
        raise ZooError(f"no evaluations_<split>.npz under {args.folder}/<algo>/<run>/ (train with --eval-freq > 0)")
    out = args.out or args.folder / "plots"
    out.mkdir(parents=True, exist_ok=True)
    for env_id, env_curves in sorted(curves.items()):
        print(f"Wrote {plot_env(env_id, env_curves, out)}")
    return 0
