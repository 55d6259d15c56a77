"""Aggregate statistics over runs and tasks as the field reports them (Agarwal et al., NeurIPS 2021: rliable).

Per split, on normalised scores (return / 1000, the most a DeepMind Control episode of 1000 steps can earn):
the interquartile mean (IQM), the mean and the optimality gap with 95% stratified-bootstrap confidence
intervals (runs resampled within each task), the probability that the reference algorithm (SGFD) improves on
each other one, and sample-efficiency curves (IQM over training). Written as ``scores.csv`` (one row per run
and split), ``aggregate.csv``, ``aggregate.md`` and figures.
"""

from __future__ import annotations

import csv
import io
from collections import defaultdict
from collections.abc import Collection, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from sgfd_envs.benchmarks import dcs, dmcgb2
from sgfd_zoo.algos import algo_sort_key, column_name
from sgfd_zoo.report.markdown import markdown_text
from sgfd_zoo.runs import bounded
from sgfd_zoo.runs.fields import finite_number, safe_name
from sgfd_zoo.runs.folders import RunFolder
from sgfd_zoo.runs.records import RunRecord
from sgfd_zoo.runs.safe import make_folder, save_figure, write_file, write_text

MAX_RETURN = 1000.0
SCORE_FIELDS = ["algo", "env", "seed", "split", "return"]
AGGREGATE_FIELDS = ["split", "algo", "metric", "value", "ci_low", "ci_high"]
METRICS = ("IQM", "mean", "optimality_gap")
IMPROVEMENT = "probability_of_improvement"
# SGFD's splits, then the benchmarks' modes in their papers' order (DMC-GB's are a subsequence of DMC-GB2's).
SPLIT_ORDER = (
    "train",
    "test",
    "interpolation",
    "extrapolation",
    *dmcgb2.MODES[1:],
    *dcs.SPLITS[1:],
)


def split_sort_key(split: str) -> tuple[int, str]:
    return (SPLIT_ORDER.index(split) if split in SPLIT_ORDER else len(SPLIT_ORDER), split)


def score_rows(results: Sequence[dict[str, Any]]) -> list[dict[str, Any]]:
    """One row per run and split, ``algo,env,seed,split,return``: the mean evaluation return of the run; a return
    that is not finite is refused in one line naming the run (no table averages a NaN away or shows one).

    :param results: rows of ``sgfd-zoo evaluate`` (algo, env, split, seed, mean_reward, ...)
    """
    rows = [
        {
            "algo": r["algo"],
            "env": r["env"],
            "seed": int(r["seed"]),
            "split": r["split"],
            "return": finite_number(r["mean_reward"], f"{r['split']} mean_reward", r.get("run", "a result")),
        }
        for r in results
    ]
    return sorted(rows, key=lambda r: (split_sort_key(r["split"]), algo_sort_key(r["algo"]), r["env"], r["seed"]))


def score_matrices(scores: Sequence[dict[str, Any]], split: str) -> tuple[dict[str, np.ndarray], list[str]]:
    """algo -> normalised scores (runs x tasks) of one split, and the tasks (columns).

    Tasks are the envs every algorithm ran; each algorithm keeps, per task, the same number of runs (the
    fewest it has on any of those tasks, lowest seeds first), as the stratified bootstrap needs a matrix.
    """
    by_algo: dict[str, dict[str, dict[int, float]]] = defaultdict(lambda: defaultdict(dict))
    for row in scores:
        if row["split"] == split:
            by_algo[row["algo"]][row["env"]][int(row["seed"])] = float(row["return"]) / MAX_RETURN
    if not by_algo:
        return {}, []
    tasks = sorted(set.intersection(*(set(envs) for envs in by_algo.values())))
    matrices = {}
    for algo, envs in by_algo.items():
        n_runs = min(len(envs[task]) for task in tasks) if tasks else 0
        if n_runs:
            columns = [[envs[task][seed] for seed in sorted(envs[task])[:n_runs]] for task in tasks]
            matrices[algo] = np.array(columns).T
    return matrices, tasks


def interquartile_mean(scores: np.ndarray) -> float:
    """rliable's ``aggregate_iqm`` (scipy's 25% ``trim_mean`` over every run and task), to the last bit, without
    scipy's per-call argument handling: the bootstrap calls it thousands of times per table.

    The same partition as scipy's (the kept slice holds the same values in the same order), so the same mean.
    """
    flat = np.ravel(scores)
    cut = int(0.25 * flat.size)
    kept = np.partition(flat, (cut, flat.size - cut - 1))[cut : flat.size - cut]
    return float(np.mean(kept))


def probability_of_improvement(scores_x: np.ndarray, scores_y: np.ndarray) -> float:
    """rliable's ``probability_of_improvement``: per task, the share of (x run, y run) pairs in which x scores
    higher, ties counting half (the Mann-Whitney U of x over the number of pairs, what rliable gets from scipy's
    ``mannwhitneyu``), averaged over tasks; a task whose two columns are equal counts 0.5, as in rliable.
    Counted directly: sums of halves and ones are exact, so the result equals rliable's to the last bit."""
    probabilities = []
    for task in range(scores_x.shape[1]):
        x, y = scores_x[:, task], scores_y[:, task]
        if np.array_equal(x, y):
            probabilities.append(0.5)
            continue
        wins = np.sum(x[:, None] > y[None, :]) + 0.5 * np.sum(x[:, None] == y[None, :])
        probabilities.append(wins / (x.size * y.size))
    return float(np.mean(probabilities))


def interval_estimates(*args: Any, seed: int, **kwargs: Any) -> tuple[dict[str, np.ndarray], dict[str, np.ndarray]]:
    """rliable's ``get_interval_estimates`` (stratified bootstrap), reproducible for a seed.

    rliable's bootstrap draws its indices from numpy's global RNG (its ``random_state`` reaches arch only,
    which does not draw them), so that RNG is seeded here and restored afterwards.
    """
    from rliable import library as rly

    state = np.random.get_state()
    np.random.seed(seed)
    try:
        return rly.get_interval_estimates(*args, **kwargs)
    finally:
        np.random.set_state(state)


def aggregate(
    scores: Sequence[dict[str, Any]], reference: str | None = None, reps: int = 2000, seed: int = 0
) -> list[dict[str, Any]]:
    """IQM, mean and optimality gap with 95% stratified-bootstrap CIs per split and algorithm, and the
    probability that ``reference`` improves on each other algorithm.

    :param scores: rows of :func:`score_rows`
    :param reference: the algorithm compared with the others (default: the first in the tables' order)
    :param reps: bootstrap replications
    :param seed: seeds the bootstrap
    :return: rows ``split,algo,metric,value,ci_low,ci_high``; for the probability of improvement, ``algo`` is
        the other algorithm and the value is P(reference > algo)
    """
    from rliable import metrics

    def measures(x: np.ndarray) -> np.ndarray:
        return np.array([interquartile_mean(x), metrics.aggregate_mean(x), metrics.aggregate_optimality_gap(x)])

    rows = []
    for split in sorted({row["split"] for row in scores}, key=split_sort_key):
        matrices, _ = score_matrices(scores, split)
        if not matrices:
            continue
        algos = sorted(matrices, key=algo_sort_key)
        points, intervals = interval_estimates({algo: matrices[algo] for algo in algos}, measures, reps=reps, seed=seed)
        for algo in algos:
            for index, metric in enumerate(METRICS):
                low, high = intervals[algo][:, index]
                rows.append(_row(split, algo, metric, points[algo][index], low, high))
        best = reference if reference in matrices else algos[0]
        pairs = {other: (matrices[best], matrices[other]) for other in algos if other != best}
        if pairs:
            probabilities, probability_cis = interval_estimates(pairs, probability_of_improvement, reps=reps, seed=seed)
            for other in pairs:
                low, high = np.asarray(probability_cis[other]).reshape(-1)[:2]
                rows.append(_row(split, other, f"{IMPROVEMENT}_of_{best}", float(probabilities[other]), low, high))
    return rows


def _row(split: str, algo: str, metric: str, value: float, low: float, high: float) -> dict[str, Any]:
    return {
        "split": split,
        "algo": algo,
        "metric": metric,
        "value": float(value),
        "ci_low": float(low),
        "ci_high": float(high),
    }


STAND_IN_MARK = " (stand-in)"
STAND_IN_NOTE = (
    "\nMarked (stand-in): played on sgfd_envs' procedural stand-ins of the benchmark's data (no data_dir / "
    "background_dir given), not the benchmark's numbers.\n"
)


def on_stand_in(row: dict[str, Any]) -> bool:
    """Whether a result row was played on a stand-in (``stand_in`` as written, or read back from csv)."""
    return str(row.get("stand_in", False)).lower() in ("true", "1")


def render_aggregate(
    rows: Sequence[dict[str, Any]], scores: Sequence[dict[str, Any]], stand_in_splits: Collection[str] = ()
) -> str:
    """Markdown: per split a table of algorithms with IQM, mean, optimality gap and P(reference > algo), each
    ``value [ci_low, ci_high]``, and how many runs and tasks it rests on; a split played on a stand-in of a
    benchmark's data (``stand_in_splits``) is marked so in its heading."""
    out = io.StringIO()
    for split in sorted({row["split"] for row in rows}, key=split_sort_key):
        matrices, tasks = score_matrices(scores, split)
        cells: dict[str, dict[str, str]] = defaultdict(dict)
        reference = ""
        for row in rows:
            if row["split"] != split:
                continue
            metric = row["metric"]
            if metric.startswith(IMPROVEMENT):
                reference = metric.removeprefix(f"{IMPROVEMENT}_of_")
                metric = IMPROVEMENT
            cells[row["algo"]][metric] = f"{row['value']:.3f} [{row['ci_low']:.3f}, {row['ci_high']:.3f}]"
        runs = {algo: matrix.shape[0] for algo, matrix in matrices.items()}
        mark = STAND_IN_MARK if split in stand_in_splits else ""
        out.write(
            f"# {markdown_text(split)}{mark}: normalised score (return / {MAX_RETURN:g}), {len(tasks)} task(s), "
            f"95% stratified-bootstrap CIs\n\n"
        )
        improvement = f"P({markdown_text(column_name(reference))} > algo)" if reference else "P(improvement)"
        out.write(
            f"| algo | runs per task | IQM | mean | optimality gap | {improvement} |\n|---|---|---|---|---|---|\n"
        )
        for algo in sorted(cells, key=algo_sort_key):
            row_cells = [cells[algo].get(metric, "–") for metric in (*METRICS, IMPROVEMENT)]
            out.write(f"| {markdown_text(column_name(algo))} | {runs.get(algo, 0)} | {' | '.join(row_cells)} |\n")
        out.write("\n")
    if set(stand_in_splits) & {row["split"] for row in rows}:
        out.write(STAND_IN_NOTE)
    return out.getvalue()


def efficiency_curves(
    runs: Sequence[RunFolder | RunRecord], split: str
) -> tuple[np.ndarray, dict[str, np.ndarray]] | None:
    """Training steps and, per algorithm, normalised evaluation returns (runs x tasks x steps) of one split,
    on the evaluation steps every run shares (None if they share none)."""
    by_algo: dict[str, dict[str, list[tuple[np.ndarray, np.ndarray]]]] = defaultdict(lambda: defaultdict(list))
    for run in runs:
        evaluations = run.evaluations(split)
        if evaluations is not None and len(evaluations["timesteps"]):
            curve = (evaluations["timesteps"], evaluations["results"].mean(axis=1) / MAX_RETURN)
            by_algo[run.algo][run.env_id].append(curve)
    if not by_algo:
        return None
    tasks = sorted(set.intersection(*(set(envs) for envs in by_algo.values())))
    curves = [curve for envs in by_algo.values() for task in tasks for curve in envs[task]]
    if not tasks or not curves:
        return None
    steps = sorted(set.intersection(*(set(steps.tolist()) for steps, _ in curves)))
    if not steps:
        return None
    matrices = {}
    for algo, envs in by_algo.items():
        n_runs = min(len(envs[task]) for task in tasks)
        per_task = []
        for task in tasks:
            per_task.append(
                [[dict(zip(s.tolist(), v, strict=True))[step] for step in steps] for s, v in envs[task][:n_runs]]
            )
        matrices[algo] = np.array(per_task).transpose(1, 0, 2)
    return np.array(steps), matrices


def at_steps(curve: tuple[np.ndarray, np.ndarray], steps: Sequence[int]) -> list[float]:
    """The curve's values at the given steps (each one of its steps)."""
    values = dict(zip(curve[0].tolist(), curve[1].tolist(), strict=True))
    return [values[step] for step in steps]


def write_figures(
    rows: Sequence[dict[str, Any]], runs: Sequence[RunFolder | RunRecord], out: Path, reps: int = 2000, seed: int = 0
) -> list[Path]:
    """Per split: interval estimates, probabilities of improvement and sample-efficiency curves (PNG)."""
    import matplotlib

    matplotlib.use("Agg")  # rliable draws with pyplot; no display is needed
    from matplotlib import pyplot as plt
    from rliable import plot_utils

    root = out.parent  # the folder the command was given: no link below it is followed
    make_folder(root, out)
    written = []
    for split in sorted({row["split"] for row in rows}, key=split_sort_key):
        safe_name(split, "split", out)  # it names the figures' files
        split_rows = [row for row in rows if row["split"] == split]
        algos = sorted({row["algo"] for row in split_rows if row["metric"] in METRICS}, key=algo_sort_key)
        points = {column_name(a): [_value(split_rows, a, m, "value") for m in METRICS] for a in algos}
        intervals = {
            column_name(a): np.array(
                [[_value(split_rows, a, m, key) for m in METRICS] for key in ("ci_low", "ci_high")]
            )
            for a in algos
        }
        row_height = 0.5
        # rliable places the x label at a fixed share of the figure's height; below the tick labels instead
        # (about 0.6 inch under the axes, which start at 11% of the height)
        label_y = 0.11 - 0.6 / (row_height * len(points))
        fig, _ = plot_utils.plot_interval_estimates(
            points, intervals, metric_names=["IQM", "Mean", "Optimality gap"], algorithms=list(points)[::-1],
            xlabel="normalised score (return / 1000)", subfigure_width=3.2, row_height=row_height, max_ticks=3,
            xlabel_y_coordinate=label_y,
        )  # fmt: skip
        fig.suptitle(f"{split}: 95% stratified-bootstrap CIs", y=1.16)
        written.append(_save(fig, root, out / f"aggregate_{split}.png", plt))

        improvement = [row for row in split_rows if row["metric"].startswith(IMPROVEMENT)]
        if improvement:
            reference = column_name(improvement[0]["metric"].removeprefix(f"{IMPROVEMENT}_of_"))
            pairs = {f"{reference},{column_name(row['algo'])}": row["value"] for row in improvement}
            cis = {
                f"{reference},{column_name(row['algo'])}": np.array([[row["ci_low"]], [row["ci_high"]]])
                for row in improvement
            }
            ax = plot_utils.plot_probability_of_improvement(pairs, cis, figsize=(4.5, 0.5 + 0.5 * len(pairs)))
            ax.set_title(f"{split}: P({reference} > other)")
            written.append(_save(ax.figure, root, out / f"probability_of_improvement_{split}.png", plt))

        curves = efficiency_curves(runs, split)
        if curves is not None and len(curves[0]) > 1:
            steps, matrices = curves

            def iqm_over_time(scores: np.ndarray) -> np.ndarray:
                return np.array([interquartile_mean(scores[..., t]) for t in range(scores.shape[-1])])

            iqm, iqm_cis = interval_estimates(matrices, iqm_over_time, reps=max(reps // 10, 200), seed=seed)
            ordered = sorted(matrices, key=algo_sort_key)
            fig, ax = plt.subplots(figsize=(5.5, 3.8))
            plot_utils.plot_sample_efficiency_curve(
                steps, {column_name(a): iqm[a] for a in ordered}, {column_name(a): iqm_cis[a] for a in ordered},
                algorithms=[column_name(a) for a in ordered], xlabel="environment steps", ylabel="IQM normalised score",
                ax=ax, labelsize="medium", ticklabelsize="medium",
            )  # fmt: skip
            ax.legend(fontsize=8)
            ax.set_title(f"{split}: sample efficiency (IQM, 95% CIs)", fontsize=10)
            written.append(_save(fig, root, out / f"sample_efficiency_{split}.png", plt))
    return written


def _value(rows: Sequence[dict[str, Any]], algo: str, metric: str, key: str) -> float:
    return next(float(row[key]) for row in rows if row["algo"] == algo and row["metric"] == metric)


def _save(fig: Any, root: Path, path: Path, plt: Any) -> Path:
    """``fig`` saved to ``path`` (written whole; no link followed below ``root``, the folder the command was
    given)."""
    save_figure(fig, root, path, dpi=100, bbox_inches="tight")
    plt.close(fig)
    return path


def write_csv(rows: Sequence[dict[str, Any]], path: Path, fields: Sequence[str]) -> Path:
    """``rows`` as a CSV file, written whole; a link at ``path`` is refused, not followed."""

    def write(tmp: str) -> None:
        with open(tmp, "w", newline="") as handle:
            writer = csv.DictWriter(handle, fieldnames=list(fields))
            writer.writeheader()
            writer.writerows(rows)

    write_file(path.parent, path, write)
    return path


def read_csv(path: Path) -> list[dict[str, Any]]:
    """Every row of ``path``, within the limits of :mod:`sgfd_zoo.runs.bounded`."""
    return list(bounded.read_csv(path))


def write_statistics(
    results: Sequence[dict[str, Any]],
    runs: Sequence[RunFolder | RunRecord],
    folder: Path,
    reference: str | None = None,
    reps: int = 2000,
    seed: int = 0,
) -> tuple[str, list[Path]]:
    """``scores.csv``, ``aggregate.csv``, ``aggregate.md`` in ``folder`` and the figures in ``folder/plots``.

    :return: the markdown and the files written
    """
    scores = score_rows(results)
    rows = aggregate(scores, reference, reps, seed)
    markdown = render_aggregate(rows, scores, {row["split"] for row in results if on_stand_in(row)})
    files = [write_csv(scores, folder / "scores.csv", SCORE_FIELDS)]
    files.append(write_csv(rows, folder / "aggregate.csv", AGGREGATE_FIELDS))
    files.append(write_text(folder, folder / "aggregate.md", markdown))
    files += write_figures(rows, runs, folder / "plots", reps, seed)
    return markdown, files
