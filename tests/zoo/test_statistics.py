"""sgfd_zoo.report.statistics: scores per run and split, aggregate metrics with stratified-bootstrap CIs, figures."""

from __future__ import annotations

import numpy as np
import pytest
from rliable import metrics

from sgfd_zoo.report.statistics import (
    IMPROVEMENT,
    aggregate,
    interquartile_mean,
    probability_of_improvement,
    read_csv,
    render_aggregate,
    score_matrices,
    score_rows,
    write_statistics,
)

TASKS = ("SGFD/MT-walker-walk-v0", "SGFD/MT-cheetah-run-v0")


def results(returns: dict[str, dict[str, list[float]]], split: str = "interpolation") -> list[dict]:
    """Rows as sgfd-zoo evaluate writes them: algo -> task -> one mean return per seed."""
    return [
        {"algo": algo, "env": task, "split": split, "seed": seed, "mean_reward": value, "run": "x"}
        for algo, tasks in returns.items()
        for task, values in tasks.items()
        for seed, value in enumerate(values)
    ]


def test_scores_are_one_row_per_run_and_split_and_matrices_are_normalised_runs_by_tasks():
    rows = score_rows(
        results({"sac": {TASKS[0]: [100.0, 300.0], TASKS[1]: [500.0, 700.0, 900.0]}})
        + results({"sac": {TASKS[0]: [10.0, 30.0]}}, split="train")
    )
    assert set(rows[0]) == {"algo", "env", "seed", "split", "return"}
    assert [row["split"] for row in rows] == ["train"] * 2 + ["interpolation"] * 5  # the tables' split order
    matrices, tasks = score_matrices(rows, "interpolation")
    assert tasks == sorted(TASKS)
    # the same number of runs per task (the fewest: 2), lowest seeds first; return / 1000
    np.testing.assert_allclose(matrices["sac"], [[0.5, 0.1], [0.7, 0.3]])


def test_aggregate_matches_rliables_metrics_and_its_intervals_hold_the_estimates():
    rng = np.random.default_rng(0)
    returns = {
        "sgfd_sac": {task: list(600 + 50 * rng.standard_normal(5)) for task in TASKS},
        "sac": {task: list(300 + 50 * rng.standard_normal(5)) for task in TASKS},
    }
    scores = score_rows(results(returns))
    rows = aggregate(scores, reference="sgfd_sac", reps=500)
    matrices, _ = score_matrices(scores, "interpolation")
    by_key = {(row["algo"], row["metric"]): row for row in rows}
    for algo, matrix in matrices.items():
        assert by_key[(algo, "IQM")]["value"] == pytest.approx(metrics.aggregate_iqm(matrix))
        assert by_key[(algo, "mean")]["value"] == pytest.approx(matrix.mean())
        assert by_key[(algo, "optimality_gap")]["value"] == pytest.approx(np.mean(np.maximum(1 - matrix, 0)))
        for metric in ("IQM", "mean", "optimality_gap"):
            row = by_key[(algo, metric)]
            assert row["ci_low"] <= row["value"] <= row["ci_high"] and row["ci_low"] < row["ci_high"]
    # SGFD's every run beats every SAC run: it improves on SAC with probability 1
    improvement = by_key[("sac", f"{IMPROVEMENT}_of_sgfd_sac")]
    assert improvement["value"] == pytest.approx(1.0) and improvement["ci_low"] == pytest.approx(1.0)
    assert ("sgfd_sac", f"{IMPROVEMENT}_of_sgfd_sac") not in by_key
    # the intervals are the same on every call with the same seed (and leave numpy's global RNG alone)
    state = np.random.get_state()[1].copy()
    assert aggregate(scores, reference="sgfd_sac", reps=500) == rows
    assert np.array_equal(np.random.get_state()[1], state)
    assert aggregate(scores, reference="sgfd_sac", reps=500, seed=1) != rows
    # a tie is a coin flip
    tie = aggregate(score_rows(results({"sgfd_sac": {TASKS[0]: [5.0] * 3}, "sac": {TASKS[0]: [5.0] * 3}})), reps=200)
    assert next(row for row in tie if row["metric"].startswith(IMPROVEMENT))["value"] == pytest.approx(0.5)


def test_statistics_files_and_figures(tmp_path):
    rng = np.random.default_rng(1)
    returns = {algo: {task: list(level + 40 * rng.standard_normal(3)) for task in TASKS} for algo, level in
               (("sgfd_sac", 500), ("sac", 450))}  # fmt: skip
    markdown, files = write_statistics(results(returns), [], tmp_path, reference="sgfd_sac", reps=300)
    assert {path.name for path in files} >= {"scores.csv", "aggregate.csv", "aggregate.md"}
    assert len(read_csv(tmp_path / "scores.csv")) == 2 * 2 * 3
    aggregate_rows = read_csv(tmp_path / "aggregate.csv")
    assert list(aggregate_rows[0]) == ["split", "algo", "metric", "value", "ci_low", "ci_high"]
    assert len(aggregate_rows) == 2 * 3 + 1  # IQM, mean, gap per algo; P(SGFD > DR)
    assert "| SGFD | 3 |" in markdown and "P(SGFD > algo)" in markdown and "| DR | 3 |" in markdown
    assert markdown == (tmp_path / "aggregate.md").read_text()
    for name in ("aggregate_interpolation.png", "probability_of_improvement_interpolation.png"):
        assert (tmp_path / "plots" / name).stat().st_size > 10_000


def test_render_shows_each_interval_and_the_runs_it_rests_on():
    scores = score_rows(results({"sgfd_sac": {TASKS[0]: [100.0, 200.0]}, "sac": {TASKS[0]: [300.0, 400.0]}}))
    text = render_aggregate(aggregate(scores, reps=200), scores)
    line = next(line for line in text.splitlines() if line.startswith("| SGFD"))
    cells = [cell.strip() for cell in line.strip("|").split("|")]
    assert cells[1] == "2" and cells[3].startswith("0.150 [")  # mean of 0.1 and 0.2
    assert cells[5] == "–"  # no probability of improving on itself


def test_split_order_puts_train_first_then_each_benchmarks_modes_in_its_papers_order():
    from sgfd_zoo.report.statistics import split_sort_key

    modes = ["video_hard", "hard", "color_easy", "rotate_easy", "train", "easy", "color_video_hard", "medium"]
    assert sorted(modes, key=split_sort_key) == [
        "train", "rotate_easy", "color_easy", "video_hard", "color_video_hard", "easy", "medium", "hard",
    ]  # fmt: skip


def test_benchmark_layout_is_tasks_by_modes_with_the_iqm_of_each_mode():
    from sgfd_zoo.report.evaluate import render_benchmark_tables

    tasks = ("DMCGB/walker-walk-v0", "DMCGB/finger-spin-v0")
    returns = {
        "train": {task: [900.0, 800.0, 700.0] for task in tasks},
        "video_hard": {tasks[0]: [100.0, 200.0, 300.0], tasks[1]: [400.0, 500.0, 600.0]},
    }
    rows = [row for split, by_task in returns.items() for row in results({"sac": by_task}, split=split)]
    rows += results({"sac": {"SGFD/walker-walk-v0": [10.0]}}, split="test")  # not a benchmark id: left out
    text = render_benchmark_tables(rows, reps=300)
    lines = [line for line in text.splitlines() if line.startswith("|")]
    header = [cell.strip() for cell in lines[0].strip("|").split("|")]
    assert header == ["Task", "train", "video_hard"]
    body = {line.split("|")[1].strip(): [c.strip() for c in line.strip("|").split("|")[1:]] for line in lines[2:]}
    assert set(body) == {"walker-walk", "finger-spin", "**IQM**"}
    assert body["walker-walk"] == ["800.0 ± 81.6", "200.0 ± 81.6"]
    # The IQM over the 3 runs x 2 tasks of each mode, on return / 1000, as rliable computes it.
    matrix = np.array([[0.1, 0.4], [0.2, 0.5], [0.3, 0.6]])
    value, interval = body["**IQM**"][1].split(" [")
    assert float(value) == pytest.approx(metrics.aggregate_iqm(matrix), abs=5e-4)
    low, high = (float(x) for x in interval.rstrip("]").split(", "))
    assert low <= float(value) <= high and low < high
    assert "DMCGB: DR" in text and "SGFD" not in text
    assert render_benchmark_tables(results({"sac": {"SGFD/walker-walk-v0": [10.0]}}, split="test")) == ""


def test_a_split_played_on_a_stand_in_is_marked_in_the_aggregate_tables():
    scores = score_rows(results({"sgfd_sac": {TASKS[0]: [100.0, 200.0]}, "sac": {TASKS[0]: [300.0, 400.0]}}))
    rows = aggregate(scores, reps=200)
    split = rows[0]["split"]
    marked = render_aggregate(rows, scores, stand_in_splits={split})
    assert f"# {split} (stand-in):" in marked and "not the benchmark's numbers" in marked
    assert "(stand-in)" not in render_aggregate(rows, scores)


@pytest.mark.parametrize("shape", [(5, 3), (4, 1), (1, 2), (10, 5)])
def test_the_bootstraps_measures_equal_rliables_to_the_last_bit(shape):
    # rounded scores: ties within and between the algorithms, as a few seeds of a hard task give
    rng = np.random.default_rng(sum(shape))
    x, y = (np.round(rng.uniform(0, 1, size=shape), 1) for _ in range(2))
    assert interquartile_mean(x) == metrics.aggregate_iqm(x)
    assert probability_of_improvement(x, y) == metrics.probability_of_improvement(x, y)
    assert probability_of_improvement(x, x) == metrics.probability_of_improvement(x, x) == 0.5
    fewer = y[: max(shape[0] - 2, 1)]  # another number of runs
    assert probability_of_improvement(x, fewer) == metrics.probability_of_improvement(x, fewer)


def test_a_tables_title_counts_its_seeds():
    from sgfd_zoo.report.evaluate import over_seeds

    assert over_seeds([1, 1]) == "mean ± std over 1 seed"
    assert over_seeds([3, 3]) == "mean ± std over 3 seeds"
    assert over_seeds([2, 3]) == "mean ± std over 2-3 seeds"
