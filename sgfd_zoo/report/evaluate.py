"""``sgfd-zoo evaluate``: every trained model of a log folder on every split, as the paper's tables and as
aggregate statistics with confidence intervals (:mod:`sgfd_zoo.report.statistics`); runs on a benchmark's ids (DMC-GB,
DMC-GB2, the Distracting Control Suite) also in that benchmark's layout, tasks x modes, with the IQM of each mode
(DMC-GB's and DMC-GB2's ``distracting_cs`` once per intensity). A split played on a built-in stand-in of the
benchmark's data (no ``data_dir``/``background_dir`` in the run's env kwargs) is marked in every table."""

from __future__ import annotations

import io
import json
import time
from collections import defaultdict
from pathlib import Path
from typing import Any

import numpy as np
from pytablewriter import MarkdownTableWriter

import sgfd_envs
from sgfd_envs.registry import BENCHMARK_KINDS, benchmark_of
from sgfd_zoo.algos import algo_sort_key, column_name
from sgfd_zoo.arguments import ZooArgumentParser, ZooError, check_at_least, check_env_id, printable, train_command
from sgfd_zoo.report.markdown import markdown_text
from sgfd_zoo.report.statistics import (
    MAX_RETURN,
    STAND_IN_MARK,
    STAND_IN_NOTE,
    aggregate,
    on_stand_in,
    read_csv,
    score_rows,
    split_sort_key,
    write_csv,
    write_statistics,
)
from sgfd_zoo.runs.fields import result_row
from sgfd_zoo.runs.files import UnreadableFile, read_json
from sgfd_zoo.runs.folders import RunFolder, find_runs
from sgfd_zoo.runs.safe import RefusedFile, refuse_links, refuse_links_inside, write_text

RESULT_FIELDS = ["algo", "env", "split", "seed", "mean_reward", "std_reward", "n_episodes", "stand_in", "run"]


# How a table marks a split played on a stand-in, and the note under it.
def evaluate_run(run: RunFolder, n_episodes: int, seed: int = 0) -> list[dict[str, Any]]:
    """Mean and std of the episode return of ``run``'s final model on each split of its env.

    The result is kept in the run's folder and reused while the model, ``n_episodes`` and ``seed`` are the
    same: evaluating a grown sweep evaluates only its new runs.
    """
    from stable_baselines3.common.evaluation import evaluate_policy

    from sgfd_zoo.vec_wrappers import wrap_like_training

    modes = sgfd_envs.evaluation_modes(run.env_id)
    key = {
        "n_episodes": n_episodes,
        "seed": seed,
        "model_mtime_ns": run.model_path.stat().st_mtime_ns,
        "modes": [label for label, _ in modes],
    }
    kept = _kept_evaluation(run.final_evaluation)
    if kept.get("key") == key and isinstance(kept.get("rows"), list):
        rows = [result_row(row, run.final_evaluation, run.algo, run.env_id) for row in kept["rows"]]
        return [{**row, "stand_in": bool(row.get("stand_in")), "run": str(run.path)} for row in rows]
    model = run.load_model()
    rows = []
    for label, mode_kwargs in modes:
        env_kwargs = {**run.env_kwargs, **mode_kwargs}
        env = sgfd_envs.make_domain_vec_env(run.env_id, seed=seed, **env_kwargs)
        env = wrap_like_training(env, run.frame_stack)
        rewards, _ = evaluate_policy(model, env, n_eval_episodes=n_episodes, return_episode_rewards=True)
        assert isinstance(rewards, list)  # return_episode_rewards: one return per episode
        env.close()
        rows.append(
            {
                "algo": run.algo,
                "env": run.env_id,
                "split": label,
                "seed": run.seed,
                "mean_reward": float(np.mean(rewards)),
                "std_reward": float(np.std(rewards)),
                "n_episodes": len(rewards),
                "stand_in": sgfd_envs.stand_in(run.env_id, **env_kwargs) is not None,
                "run": str(run.path),
            }
        )
    write_text(run.root, run.final_evaluation, json.dumps({"key": key, "rows": rows}, indent=1))
    return rows


def _kept_evaluation(path: Path) -> dict[str, Any]:
    """What an earlier ``evaluate`` kept in ``final_evaluation.json``; {} when there is none, or not one of those."""
    try:
        kept = read_json(path)
    except UnreadableFile:
        return {}
    return kept if isinstance(kept, dict) and all(isinstance(row, dict) for row in kept.get("rows") or []) else {}


def render_tables(results: list[dict[str, Any]]) -> str:
    """
    The paper's layout, one markdown table per split: tasks as rows, algorithms as columns (in the paper's
    order), ``mean ± std`` over seeds (of each seed's mean return), and a Total row summing the means.
    """
    by_cell: dict[tuple[str, str, str], list[float]] = defaultdict(list)
    stand_in_splits = {row["split"] for row in results if on_stand_in(row)}
    for row in results:
        by_cell[(row["split"], row["env"], row["algo"])].append(float(row["mean_reward"]))
        if not np.isfinite(by_cell[(row["split"], row["env"], row["algo"])][-1]):
            raise RefusedFile(f"{row.get('run', 'a run')}: refused: its {row['split']} return is not finite")
    splits = sorted({key[0] for key in by_cell}, key=split_sort_key)
    out = io.StringIO()
    for split in splits:
        envs = sorted({env for s, env, _ in by_cell if s == split})
        algos = sorted({algo for s, _, algo in by_cell if s == split}, key=algo_sort_key)
        totals = dict.fromkeys(algos, 0.0)
        matrix = []
        for env in envs:
            cells = [markdown_text(_task_name(env), pipes=False)]
            for algo in algos:
                values = by_cell.get((split, env, algo))
                if values is None:
                    cells.append("–")
                    continue
                totals[algo] += float(np.mean(values))
                cells.append(_mean_std(values))
            matrix.append(cells)
        matrix.append(["**Total**", *(f"**{totals[algo]:.1f}**" for algo in algos)])
        counts = [len(values) for (s, _, _), values in by_cell.items() if s == split]
        mark = STAND_IN_MARK if split in stand_in_splits else ""
        name = f"{markdown_text(split)}{mark} ({over_seeds(counts)})"
        headers = ["Task", *(markdown_text(column_name(algo), pipes=False) for algo in algos)]
        _write_table(out, name, headers, matrix, stand_in=bool(mark))
    return out.getvalue()


def _task_name(env_id: str) -> str:
    """``walker-walk`` for SGFD's ids; a benchmark's keep its name, ``DMCGB2/walker-walk``, as their tasks repeat."""
    name = env_id.rsplit("-v", 1)[0]
    return name if benchmark_of(env_id) else name.split("/", 1)[-1]


def render_benchmark_tables(results: list[dict[str, Any]], reps: int = 2000, seed: int = 0) -> str:
    """
    DMC-GB's layout for the runs on a benchmark's ids: per benchmark and algorithm a table with its tasks as rows
    and its modes as columns (``train`` first), ``mean ± std`` over seeds, and a last row with the IQM of each
    mode's normalised scores over the algorithm's runs and the benchmark's tasks, with its 95% stratified-bootstrap
    CI (rliable, :func:`sgfd_zoo.report.statistics.aggregate`). Empty when no run is on a benchmark id.

    :param results: rows of ``sgfd-zoo evaluate``
    :param reps: bootstrap replications
    :param seed: seeds the bootstrap
    """
    by_benchmark: dict[str, list[dict[str, Any]]] = defaultdict(list)
    for row in results:
        name = benchmark_of(row["env"])
        if name is not None:
            by_benchmark[name].append(row)
    out = io.StringIO()
    for name in (kind for kind in BENCHMARK_KINDS if kind in by_benchmark):
        rows = by_benchmark[name]
        iqm = {
            (row["split"], row["algo"]): row
            for row in aggregate(score_rows(rows), reps=reps, seed=seed)
            if row["metric"] == "IQM"
        }
        by_cell: dict[tuple[str, str, str], list[float]] = defaultdict(list)
        for row in rows:
            by_cell[(row["algo"], row["env"], row["split"])].append(float(row["mean_reward"]))
        modes = sorted({row["split"] for row in rows}, key=split_sort_key)
        stand_in_modes = {row["split"] for row in rows if on_stand_in(row)}
        headers = [markdown_text(mode, False) + (STAND_IN_MARK if mode in stand_in_modes else "") for mode in modes]
        for algo in sorted({row["algo"] for row in rows}, key=algo_sort_key):
            envs = sorted({env for a, env, _ in by_cell if a == algo})
            matrix = []
            for env in envs:
                cells = [markdown_text(env.split("/", 1)[1].rsplit("-v", 1)[0], pipes=False)]
                for mode in modes:
                    values = by_cell.get((algo, env, mode))
                    cells.append("–" if values is None else _mean_std(values))
                matrix.append(cells)
            aggregate_cells = ["**IQM**"]
            for mode in modes:
                cell = iqm.get((mode, algo))
                aggregate_cells.append(
                    "–" if cell is None else f"{cell['value']:.3f} [{cell['ci_low']:.3f}, {cell['ci_high']:.3f}]"
                )
            matrix.append(aggregate_cells)
            counts = [len(values) for (a, _, _), values in by_cell.items() if a == algo]
            title = (
                f"{name}: {markdown_text(column_name(algo))} ({over_seeds(counts)}; "
                f"IQM of return / {MAX_RETURN:g} over runs x tasks, 95% CI)"
            )
            _write_table(out, title, ["Task", *headers], matrix, stand_in=bool(stand_in_modes))
    return out.getvalue()


def _mean_std(values: list[float]) -> str:
    """A cell's ``mean ± std`` of the seeds' returns, one decimal each."""
    return f"{np.mean(values):.1f} ± {np.std(values):.1f}"


def _write_table(out: io.StringIO, name: str, headers: list[str], matrix: list[list[str]], stand_in: bool) -> None:
    """One markdown table into ``out``: its title, header and rows, the stand-in note where ``stand_in``, a blank line.

    :param out: where the tables are written
    :param name: the table's title
    :param headers: its column headers
    :param matrix: its rows of cells
    :param stand_in: whether a column played on a benchmark's built-in stand-in (the note follows the table)
    """
    writer = MarkdownTableWriter(table_name=name, headers=headers, value_matrix=matrix)
    writer.margin = 1
    out.write(writer.dumps())
    out.write(STAND_IN_NOTE if stand_in else "")
    out.write("\n")


def over_seeds(counts: list[int]) -> str:
    """A table title's "mean ± std over 3 seeds" (or "over 2-3 seeds" where cells hold different numbers of runs)."""
    seeds = str(min(counts)) if min(counts) == max(counts) else f"{min(counts)}-{max(counts)}"
    return f"mean ± std over {seeds} seed{'s' if max(counts) > 1 else ''}"


def write_results(results: list[dict[str, Any]], folder: Path, reps: int = 2000, seed: int = 0) -> tuple[Path, Path]:
    """``results.csv`` and ``results.md`` (the paper's tables, then the benchmarks' layout) in ``folder``."""
    csv_path, md_path = folder / "results.csv", folder / "results.md"
    write_csv(results, csv_path, RESULT_FIELDS)
    write_text(folder, md_path, render_tables(results) + render_benchmark_tables(results, reps, seed))
    return csv_path, md_path


def read_results(path: Path) -> list[dict[str, Any]]:
    """The rows of a ``results.csv`` as written (strings), within the limits of :mod:`sgfd_zoo.runs.bounded`; each
    is checked where it is used (:func:`~sgfd_zoo.runs.fields.result_row`)."""
    return read_csv(path)


# -- what the tables leave out and what they replace ---------------------------------------------------


def continue_command(run: RunFolder) -> str:
    """The ``sgfd-zoo train`` command that continues ``run`` from its checkpoint (or starts it again when it has
    none), rebuilt from checked fields (:func:`continue_flags`), never copied from the run's ``command.txt``; for a
    run that recorded no flags, or flags that do not pass the checks, what to add to the command that trained it."""
    resume = run.checkpoint is not None
    argv = run.train_argv()
    flags = None if argv is None else continue_flags(argv, run)
    if flags is None:
        return f"the command that trained it, with --run-id {run.run_id}{' --resume' if resume else ''}"
    return train_command(flags, run.run_id, resume)


#: The flags of a recorded command that name the run itself, and how each is rebuilt from the run's checked place.
_RUN_FLAGS = ("--algo", "--env", "--seed", "-f", "--log-folder", "--folder", "--run-id")


def continue_flags(argv: list[str], run: RunFolder) -> list[str] | None:
    """The flags that continue ``run``, from its recorded ``argv``: its algorithm, env, seed and log folder as its
    folder and ``args.yml`` give them (checked), then the recorded per-run flags if each passes the checks of a
    spec's flags (:func:`~sgfd_zoo.spec_flags.check_train_flags`: data only, no path, no code); None when one does
    not, or when the recorded algorithm, env or seed is not the run's."""
    from sgfd_zoo.arguments import flag_value, without_flags
    from sgfd_zoo.spec_flags import check_train_flags

    recorded = {"--algo": run.algo, "--env": run.env_id, "--seed": None if run.seed is None else str(run.seed)}
    if any(flag_value(argv, flag) not in (None, value) for flag, value in recorded.items()):
        return None
    rest = without_flags(argv, switches=["--resume"], options=_RUN_FLAGS)
    try:
        check_train_flags(rest, run.command_file)
    except RefusedFile:
        return None
    named = [item for flag, value in recorded.items() if value is not None for item in (flag, value)]
    return [*named, "-f", str(run.root), *rest]


def unfinished_report(runs: list[RunFolder]) -> list[str]:
    """Lines naming each unfinished run (the tables leave them out), where it stopped and the command that
    continues it."""
    if not runs:
        return []
    lines = [
        f"evaluate: {len(runs)} unfinished run{'s are' if len(runs) > 1 else ' is'} not in the tables (stopped, or "
        "still training); running again the sweep, quick or study that started them continues them all, or each:"
    ]
    for run in runs:
        checkpoint = run.checkpoint
        where = f"checkpoint at step {checkpoint.num_timesteps}" if checkpoint else "no checkpoint: from step 0"
        lines.append(f"  {run.algo} on {run.env_id} seed {run.seed} ({where}): {continue_command(run)}")
    return lines


def replaced_tables(folder: Path, n_runs: int) -> str | None:
    """A line saying that this evaluation replaces the tables an earlier one (``quick``, a sweep, ``evaluate``)
    wrote in ``folder``, when it holds some: when and from how many runs they were made."""
    previous = folder / "results.csv"
    if not previous.exists():
        return None
    written = time.strftime("%Y-%m-%d %H:%M", time.localtime(previous.stat().st_mtime))
    try:
        counted = _runs(len({row.get("run") for row in read_results(previous)}))
    except (OSError, ValueError, KeyError):
        counted = "unreadable"
    return (
        f"evaluate: replacing the tables of {written} in {folder} ({counted}) with these of {_runs(n_runs)}: "
        "results.*, scores.csv, aggregate.* and their figures in plots/"
    )


def _runs(count: int) -> str:
    return f"{count} run{'s' if count != 1 else ''}"


#: What ``evaluate`` writes in the log folder (and ``plots/`` with the figures).
TABLES = ("results.csv", "results.md", "scores.csv", "aggregate.csv", "aggregate.md")


def refuse_output_links(folder: Path, runs: list[RunFolder]) -> None:
    """Before any evaluation: a :class:`~sgfd_zoo.runs.safe.RefusedFile` when a file evaluate writes (the tables,
    the figures, each run's ``final_evaluation.json``) is a link, or lies in a linked folder."""
    for name in (*TABLES, "plots"):
        refuse_links(folder, folder / name)
    if (folder / "plots").is_dir():
        refuse_links_inside(folder / "plots", folder)
    for run in runs:
        run.refuse_links()


def _files_now(folder: Path) -> set[Path]:
    """The files of ``folder`` and ``folder/plots``."""
    return {path for where in (folder, folder / "plots") if where.is_dir() for path in where.iterdir()}


def main(argv: list[str]) -> int:
    parser = ZooArgumentParser(prog="sgfd-zoo evaluate", description=__doc__)
    parser.add_argument("-f", "--folder", required=True, type=Path, help="log folder of sgfd-zoo train")
    parser.add_argument("--algo", nargs="+", help="only these algorithm keys")
    parser.add_argument("--env", nargs="+", help="only these env ids")
    parser.add_argument("--n-episodes", type=int, default=10, help="episodes per split (spread over its domains)")
    parser.add_argument("--seed", type=int, default=0, help="seed of the evaluation envs and of the bootstrap")
    parser.add_argument(
        "--num-threads", type=int, default=1, help="torch threads (small-batch inference: more only contend)"
    )
    parser.add_argument(
        "--reference", default="sgfd_sac", help="the algorithm whose probability of improving on the others is shown"
    )
    parser.add_argument("--bootstrap-reps", type=int, default=2000, help="bootstrap replications of the CIs")
    args = parser.parse_args(argv)
    if not args.folder.is_dir():
        raise ZooError(f"--folder {args.folder} does not exist (train first: sgfd-zoo train -f {args.folder} ...)")
    check_at_least("--n-episodes", args.n_episodes, 1)
    check_at_least("--num-threads", args.num_threads, 1)
    check_at_least("--bootstrap-reps", args.bootstrap_reps, 100)
    for env_id in args.env or []:
        check_env_id(env_id)
    runs: list[RunFolder] = []
    unfinished: list[RunFolder] = []  # one scan of the folder, each run's marker read once
    for run in find_runs(args.folder, args.algo, args.env, finished=False):
        (runs if run.finished else unfinished).append(run)
    for line in unfinished_report(unfinished):
        print(printable(line))
    if not runs:
        raise ZooError(f"no finished run under {args.folder} (expected <algo>/<EnvName>_<id>/<EnvName>.zip)")
    refuse_output_links(args.folder, runs)
    replacing = replaced_tables(args.folder, len(runs))
    if replacing is not None:
        print(replacing)
    before = _files_now(args.folder)
    import torch as th

    th.set_num_threads(args.num_threads)
    results = []
    for run in runs:
        print(printable(f"Evaluating {run.algo} on {run.env_id} (seed {run.seed}): {run.path}"))
        results += evaluate_run(run, args.n_episodes, args.seed)
    csv_path, md_path = write_results(results, args.folder, args.bootstrap_reps, args.seed)
    markdown, files = write_statistics(results, runs, args.folder, args.reference, args.bootstrap_reps, args.seed)
    print()
    print(printable(md_path.read_text(), lines=True))
    print(printable(markdown, lines=True))
    written = [csv_path, md_path, *files]
    new = ", ".join(str(path) for path in written if path not in before)
    replaced = ", ".join(str(path) for path in written if path in before)
    said = [new and f"Wrote {new}", replaced and f"{'r' if new else 'R'}eplaced {replaced}"]
    print(printable("; ".join(filter(None, said))))
    return 0
