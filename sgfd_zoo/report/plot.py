"""``sgfd-zoo plot``: learning curves per split and algorithm, mean and a band over seeds."""

from __future__ import annotations

from collections import defaultdict
from pathlib import Path

import numpy as np
from matplotlib.figure import Figure  # no pyplot: no GUI backend, no global figure state

import sgfd_envs
from sgfd_zoo.algos import algo_sort_key, column_name
from sgfd_zoo.arguments import ZooArgumentParser, ZooError
from sgfd_zoo.runs.folders import env_name, find_runs
from sgfd_zoo.runs.safe import make_folder, save_figure

Curve = tuple[np.ndarray, np.ndarray]


def load_curves(folder: Path) -> dict[str, dict[str, dict[str, list[Curve]]]]:
    """env id -> split -> algo -> one (timesteps, mean evaluation return) curve per run (finished or not)."""
    curves: dict = defaultdict(lambda: defaultdict(lambda: defaultdict(list)))
    for run in find_runs(folder, finished=False):
        for split in sgfd_envs.splits(run.env_id):
            evaluations = run.evaluations(split)
            if evaluations is not None and len(evaluations["timesteps"]) > 0:
                curve = (evaluations["timesteps"], evaluations["results"].mean(axis=1))
                curves[run.env_id][split][run.algo].append(curve)
    return curves


def mean_and_band(curves: list[Curve], n_points: int = 200) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Mean and one standard deviation over runs, on the steps every run covers.

    Runs may be evaluated or logged at different steps (another --eval-freq, a resumed run), so each curve is
    interpolated linearly onto a common grid over the range all of them share; curves on identical steps are
    kept as they are.

    :param curves: (steps, values) per run, steps increasing
    :param n_points: points of the common grid when the runs' steps differ
    """
    if not curves:
        raise ValueError("curves must hold at least one (steps, values) curve")
    first_steps = np.asarray(curves[0][0])
    if all(np.array_equal(np.asarray(steps), first_steps) for steps, _ in curves):
        grid = first_steps.astype(np.float64)
    else:
        low = max(float(steps[0]) for steps, _ in curves)
        high = min(float(steps[-1]) for steps, _ in curves)
        grid = np.linspace(low, high, n_points) if high > low else np.array([low])
    values = np.stack([np.interp(grid, steps, vals) for steps, vals in curves])
    return grid, values.mean(axis=0), values.std(axis=0)


def draw_env(env_id: str, curves: dict[str, dict[str, list[Curve]]]) -> Figure:
    """One panel per split: per algorithm, the mean evaluation return and a band of one std over seeds; a run
    evaluated once (or runs that share one step) is a point with an error bar, since a band needs two steps."""
    splits = [split for split in sgfd_envs.splits(env_id) if split in curves]
    fig = Figure(figsize=(4.5 * len(splits), 3.5))
    axes = fig.subplots(1, len(splits), squeeze=False)
    for ax, split in zip(axes[0], splits, strict=True):
        for algo in sorted(curves[split], key=algo_sort_key):
            runs = curves[split][algo]
            steps, mean, std = mean_and_band(runs)
            label = f"{column_name(algo)} ({len(runs)} seed{'s' if len(runs) > 1 else ''})"
            if len(steps) == 1:
                ax.errorbar(steps, mean, yerr=std, fmt="o", capsize=4, label=label)
                continue
            (line,) = ax.plot(steps, mean, label=label)
            ax.fill_between(steps, mean - std, mean + std, color=line.get_color(), alpha=0.2)
        ax.set_title(f"{env_id.split('/')[-1]}: {split}")
        ax.set_xlabel("environment steps")
        ax.set_ylabel("episode return")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    fig.tight_layout()
    return fig


def plot_env(env_id: str, curves: dict[str, dict[str, list[Curve]]], out: Path, root: Path | None = None) -> Path:
    """:func:`draw_env`, saved as ``out/<EnvName>.png`` (written whole, no link followed below ``root``, ``out``
    by default); returns its path."""
    path = out / f"{env_name(env_id)}.png"
    return save_figure(draw_env(env_id, curves), out if root is None else root, path, dpi=100)


def main(argv: list[str]) -> int:
    parser = ZooArgumentParser(prog="sgfd-zoo plot", description=__doc__)
    parser.add_argument("-f", "--folder", required=True, type=Path, help="log folder of sgfd-zoo train")
    parser.add_argument("-o", "--out", type=Path, help="output folder (default: <folder>/plots)")
    args = parser.parse_args(argv)
    if not args.folder.is_dir():
        raise ZooError(f"--folder {args.folder} does not exist")
    curves = load_curves(args.folder)
    if not curves:
        raise ZooError(f"no evaluations_<split>.npz under {args.folder}/<algo>/<run>/ (train with --eval-freq > 0)")
    out = args.out or args.folder / "plots"
    root = args.out or args.folder  # the folder given: nothing below it is a link
    make_folder(root, out)
    for env_id, env_curves in sorted(curves.items()):
        print(f"Wrote {plot_env(env_id, env_curves, out, root)}")
    return 0
