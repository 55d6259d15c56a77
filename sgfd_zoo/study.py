"""
``sgfd-zoo study SPEC``: a study from a spec file checked into the repository (``studies/<name>/spec.yml``).

It runs the spec's sweep (algorithms x envs x seeds with its training flags; resumable: run the same command
again to continue), evaluates every run on every split, and writes the compact results next to the spec: a
record of each finished run (``runs/``: its evaluations during training, logged SGFD figures and final
evaluation; :class:`sgfd_zoo.runs.records.RunRecord`), and, computed from all the records, the paper-style tables
(``results.*``), the aggregate statistics (``scores.csv``, ``aggregate.*``), their figures and the diagnostics
of SGFD's weights over training (``plots/``, ``diagnostics.md``), with the exact command and the package
versions. Models, replay buffers and checkpoints stay in the log folder. A recorded cell is not trained again:
committed, the records let a session on another machine (without the log folder) continue the study.
``--plan`` trains nothing: it prints the runs still to train and what they cost on a GPU, at the rates of the latest
device check (:mod:`sgfd_zoo.sweep.cost`).

A spec (yaml):

    name: mt-state
    description: what the study asks
    algos: [sgfd_sac, sac]
    envs: [SGFD/MT-walker-walk-v0]
    seeds: [0, 1, 2, 3, 4]
    train: [--quick, -n, "30000", --eval-freq, "5000"]   # flags of every run's sgfd-zoo train
    n_episodes: 10                                          # final evaluation, per split
    reference: sgfd_sac                                     # whose probability of improvement is reported
"""

from __future__ import annotations

import argparse
import csv
import functools
import re
import shlex
import sys
from collections.abc import Sequence
from importlib import metadata
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from sgfd_zoo.algos import SGFD_ALGOS, algo_sort_key, column_name
from sgfd_zoo.arguments import ZooArgumentParser, ZooError, check_at_least, checked_names, has_flag, printable
from sgfd_zoo.report import evaluate
from sgfd_zoo.report.markdown import markdown_text
from sgfd_zoo.report.statistics import write_statistics
from sgfd_zoo.runs import provenance
from sgfd_zoo.runs.bounded import read_text
from sgfd_zoo.runs.fields import result_row
from sgfd_zoo.runs.folders import RunFolder, env_name, find_runs
from sgfd_zoo.runs.records import RunRecord, find_records
from sgfd_zoo.runs.safe import (
    RefusedFile,
    load_yaml,
    make_folder,
    redact,
    refuse_links,
    refuse_links_inside,
    save_figure,
    write_text,
)
from sgfd_zoo.spec_flags import check_train_flags
from sgfd_zoo.sweep.cost import cost_lines, plan_runs
from sgfd_zoo.sweep.plan import gpu_fraction

SPEC_KEYS = {"name", "description", "algos", "envs", "seeds", "train", "n_episodes", "reference"}
TOP_SALIENCY = "sgfd/top_saliency_feature"  # the index of the most salient feature, per logged step
# Logged figures kept per run (the rest of progress.csv stays in the log folder).
DIAGNOSTICS = (
    "sgfd/classifier_accuracy",
    "sgfd/weight_ess",
    "sgfd/weight_min",
    "sgfd/weight_max",
    "sgfd/decorrelation_loss_before",
    "sgfd/decorrelation_loss_after",
    TOP_SALIENCY,
    "train/critic_loss",
    "train/actor_loss",
    "train/ent_coef",
)


#: The type of each key of a spec, the type of its items where it is a list (None: not a list), and what it is
#: said to be, as :func:`read_spec` checks them before reading its values.
SPEC_TYPES: dict[str, tuple[type, type | tuple[type, ...] | None, str]] = {
    "name": (str, None, "a plain name"),
    "description": (str, None, "a line of text"),
    "algos": (list, str, "a list of algorithm keys"),
    "envs": (list, str, "a list of env ids"),
    "seeds": (list, int, "a list of integers >= 0"),
    "train": (list, (str, int, float), "a list of flags and values"),
    "n_episodes": (int, None, "an integer >= 1"),
    "reference": (str, None, "one of its algos"),
}


def read_spec(path: Path) -> dict[str, Any]:
    """The spec at ``path``, checked: known keys, each of its type, algorithm keys and env ids, seeds, a list of
    train flags; read within the limits of :mod:`sgfd_zoo.runs.bounded`."""
    if not path.is_file():
        raise ZooError(f"SPEC {path} is not a file (a study's spec.yml, e.g. studies/mt-state/spec.yml)")
    try:
        spec = load_yaml(read_text(path, "MAX_YAML_BYTES"), f"SPEC {path}") or {}  # a tag naming code: refused
    except yaml.YAMLError as error:
        raise ZooError(f"SPEC {path}: not a spec ({str(error).splitlines()[0]})") from None
    if not isinstance(spec, dict):
        raise ZooError(f"SPEC {path}: expected a mapping of {', '.join(sorted(SPEC_KEYS))}")
    unknown = sorted(str(key) for key in set(spec) - SPEC_KEYS)
    if unknown:
        raise ZooError(f"SPEC {path}: unknown key(s) {unknown}; a spec has {', '.join(sorted(SPEC_KEYS))}")
    for key in ("name", "algos", "envs", "seeds"):
        if not spec.get(key):
            raise ZooError(f"SPEC {path}: {key} is required")
    _check_spec_types(spec, path)
    if not isinstance(spec["name"], str) or not re.fullmatch(r"[A-Za-z0-9][A-Za-z0-9._-]*", spec["name"]):
        raise RefusedFile(
            f"SPEC {path}: name {spec['name']!r} must be a plain name (letters, digits, '.', '_', '-'): it names the "
            "study's log folder, logs/studies/<name>"
        )
    spec["algos"] = checked_names("algos", spec["algos"], list(SGFD_ALGOS))
    import sgfd_envs

    spec["envs"] = checked_names("envs", spec["envs"], list(sgfd_envs.ENV_IDS))
    if not all(isinstance(seed, int) and seed >= 0 for seed in spec["seeds"]):
        raise ZooError(f"SPEC {path}: seeds must be integers >= 0, got {spec['seeds']}")
    spec["train"] = check_train_flags([str(flag) for flag in spec.get("train") or []], path)
    spec.setdefault("n_episodes", 10)
    check_at_least("n_episodes", spec["n_episodes"], 1)
    spec.setdefault("reference", spec["algos"][0])
    if spec["reference"] not in spec["algos"]:
        raise ZooError(f"SPEC {path}: reference {spec['reference']!r} is not one of its algos {spec['algos']}")
    return spec


def _check_spec_types(spec: dict[str, Any], path: Path) -> None:
    """A ZooError naming the key when a spec's value is not of its type (:data:`SPEC_TYPES`), or a list's item is
    not a plain value of its kind (``algos: [[...]]``)."""
    for key, (kind, item_kind, what) in SPEC_TYPES.items():
        value = spec.get(key)
        if value is None:
            continue
        wrong = not isinstance(value, kind) or isinstance(value, bool)
        if not wrong and item_kind is not None:
            wrong = not all(isinstance(item, item_kind) and not isinstance(item, bool) for item in value)
        if wrong:
            raise ZooError(f"SPEC {path}: {key} must be {what}, got {value!r}"[:400])


def sweep_arguments(spec: dict[str, Any], folder: Path) -> list[str]:
    """The ``sgfd-zoo sweep`` arguments of a spec."""
    argv = ["--algos", *spec["algos"], "--envs", *spec["envs"], "--seeds", *map(str, spec["seeds"])]
    argv += ["-f", str(folder), "--n-episodes", str(spec["n_episodes"]), "--reference", spec["reference"]]
    return [*argv, *spec["train"], "--no-progress", "--verbose", "0"]


def export(spec: dict[str, Any], folder: Path, out: Path, command: str) -> list[Path]:
    """Record the finished runs of the log folder ``folder`` in ``out/runs`` (the spec's folder), then write the
    study's tables, statistics and figures from every record there: those of this log folder and those an
    earlier session left."""
    results_file = folder / "results.csv"
    rows_by_run: dict[str, list[dict[str, Any]]] = {}
    for row in evaluate.read_results(results_file) if results_file.exists() else []:
        rows_by_run.setdefault(str(row.get("run")), []).append(row)
    recorded = {(r.algo, r.env_id, r.seed): r for r in find_records(out / "runs", spec["algos"], spec["envs"])}
    for run in find_runs(folder, spec["algos"], spec["envs"]):
        if str(run.path) not in rows_by_run:
            continue  # not evaluated: recorded by the next export
        rows = [result_row(row, results_file, run.algo, run.env_id) for row in rows_by_run[str(run.path)]]
        record = record_of(run, out / "runs", recorded)
        record.write(run, rows, functools.partial(write_diagnostics, run))
        recorded[(run.algo, run.env_id, run.seed)] = record
    records = study_records(spec, out)
    for record in records:  # every file of every record read (and refused, if it must be) before one is written
        read_whole(record)
    results = [{**row, "run": str(record.path.relative_to(out))} for record in records for row in record.final_rows]
    written = list(evaluate.write_results(results, out))
    written += write_statistics(results, records, out, spec["reference"])[1]
    written += diagnostics_figures(records, out / "plots", root=out)
    written += [write_text(out, out / "diagnostics.md", diagnostics_summary(records))]
    written += [write_text(out, out / "command.txt", redact(command) + "\n")]
    return [*written, write_text(out, out / "versions.txt", versions())]


def read_whole(record: RunRecord) -> None:
    """Read every file of ``record`` the tables and figures read, so that one refused stops the export before it
    writes anything: its final evaluation, configuration, evaluations and logged figures."""
    _ = record.final_rows, record.accuracy_threshold
    for split in {row["split"] for row in record.final_rows}:
        record.evaluations(split)
    for key in DIAGNOSTICS:
        record.log(key)


def refuse_output_links(out: Path) -> None:
    """Before anything runs: a :class:`~sgfd_zoo.runs.safe.RefusedFile` when a file the export writes next to the
    spec (tables, figures, records, command, versions) is a link or lies in a linked folder: a committed link
    would take the write elsewhere."""
    for name in (*evaluate.TABLES, "diagnostics.md", "command.txt", "versions.txt", "plots", "runs"):
        refuse_links(out, out / name)
        if (out / name).is_dir():
            refuse_links_inside(out / name, out)


def record_of(run: RunFolder, runs: Path, recorded: dict[tuple[str, str, int | None], RunRecord]) -> RunRecord:
    """Where the finished log run ``run`` is recorded under the study's ``runs`` folder: the record made
    from this run when there is one (an export again, or one cut short); else a record of its own, named as
    the run unless an earlier record holds that name (a fresh log folder numbers its runs from 1 again): then
    the next free id.

    :param run: a finished run of the log folder
    :param runs: the study's ``runs`` folder
    :param recorded: the records by (algo, env id, seed)
    """
    cell = recorded.get((run.algo, run.env_id, run.seed)) if run.seed is not None else None
    if cell is not None:
        # a record from before records named their run: the folder name was its only link
        made_from = cell.made_from(run)
        if made_from or (made_from is None and cell.path.name == run.path.name):
            return cell
        raise ZooError(f"{run.path} (seed {run.seed}) is already recorded as {cell.path}: remove one of them")
    others = find_records(runs, [run.algo], [run.env_id])
    for other in others:
        if other.made_from(run):  # an export of this run that was cut short
            return other
    record = RunRecord(runs / run.algo / run.path.name)
    if not record.path.exists():
        return record
    return RunRecord(runs / run.algo / f"{env_name(run.env_id)}_{max(other.run_id for other in others) + 1}")


def study_records(spec: dict[str, Any], out: Path) -> list[RunRecord]:
    """The whole records of the spec's cells in ``out/runs`` (a record without its final evaluation is a run
    whose export was cut short: its cell is trained again)."""
    records = [record for record in find_records(out / "runs", spec["algos"], spec["envs"]) if record.complete]
    return [record for record in records if record.seed in spec["seeds"]]


def write_diagnostics(run: RunFolder, path: Path) -> Path:
    """The run's logged SGFD and loss figures over training, one row per logged step."""
    columns = {key: dict(zip(*run.log(key), strict=True)) for key in DIAGNOSTICS}
    columns = {key: values for key, values in columns.items() if values}
    steps = sorted({step for values in columns.values() for step in values})
    with path.open("w", newline="") as handle:
        writer = csv.writer(handle)
        writer.writerow(["timesteps", *columns])
        for step in steps:
            writer.writerow([step, *(f"{values[step]:.6g}" if step in values else "" for values in columns.values())])
    return path


def diagnostics_figures(runs: Sequence[RunFolder | RunRecord], out: Path, root: Path | None = None) -> list[Path]:
    """Per env: the classifier's accuracy, the weights' ESS and their range over training, per algorithm
    (mean over seeds, and each seed faintly), saved in ``out`` (no link in it below ``root``, its parent by
    default)."""
    from matplotlib.figure import Figure

    from sgfd_zoo.report.plot import mean_and_band

    panels: tuple[tuple[str, str], ...] = (("sgfd/classifier_accuracy", "classifier accuracy"),)
    panels += (("sgfd/weight_ess", "weights' ESS / n"),)
    panels += (("sgfd/weight_max", "largest weight"), ("sgfd/weight_min", "smallest weight"))
    panels += ((TOP_SALIENCY, "top-saliency feature (each seed)"),)
    written = []
    for env_id in sorted({run.env_id for run in runs}):
        fig = Figure(figsize=(4 * len(panels), 3.2), layout="constrained")
        axes = fig.subplots(1, len(panels))
        drawn = False
        for ax, (key, title) in zip(axes, panels, strict=True):
            for algo in sorted({run.algo for run in runs if run.env_id == env_id}, key=algo_sort_key):
                curves = [run.log(key) for run in runs if run.env_id == env_id and run.algo == algo]
                curves = [curve for curve in curves if len(curve[0]) > 0]
                if not curves:
                    continue
                legend: str | None = f"{column_name(algo)} ({len(curves)})"
                if key == TOP_SALIENCY:  # an index: a mean over seeds would name no feature
                    color: str | None = None
                    for run_steps, values in curves:
                        (dots,) = ax.plot(run_steps, values, ".", color=color, alpha=0.5, label=legend)
                        color, legend = dots.get_color(), None
                else:
                    steps, mean, _ = mean_and_band(curves)
                    (line,) = ax.plot(steps, mean, marker=".", label=legend)
                    for run_steps, values in curves:
                        ax.plot(run_steps, values, color=line.get_color(), alpha=0.15, linewidth=0.8)
                drawn = True
            ax.set_title(title, fontsize=9)
            ax.set_xlabel("environment steps", fontsize=8)
            ax.grid(alpha=0.3)
        if not drawn:
            continue
        axes[0].legend(fontsize=7)
        fig.suptitle(
            f"{env_id}: SGFD's classifier and weights over training (mean over seeds, seeds faint)", fontsize=9
        )
        root = out.parent if root is None else root
        written.append(save_figure(fig, root, make_folder(root, out) / f"diagnostics_{env_name(env_id)}.png", dpi=100))
    return written


def diagnostics_summary(runs: Sequence[RunFolder | RunRecord]) -> str:
    """Markdown, per env and algorithm (mean ± std over seeds): when the classifier first reached its threshold,
    the weights' ESS and range once it had, the feature most often the most salient (and in what share of all
    the seeds' logs), and the returns of the last evaluation during training (``--eval-episodes`` episodes, not
    the final evaluation of ``results.md``)."""
    lines = [
        "| env | algo | seeds | classifier ready at step | ESS / n | smallest weight | largest weight | "
        "top-saliency feature (share of logs) | train return, last eval in training | "
        "extrapolation return, last eval in training |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for env_id in sorted({run.env_id for run in runs}):
        for algo in sorted({run.algo for run in runs if run.env_id == env_id}, key=algo_sort_key):
            group = [run for run in runs if run.env_id == env_id and run.algo == algo]
            ready: list[float] = []
            ess: list[float] = []
            low: list[float] = []
            high: list[float] = []
            for run in group:
                steps, accuracy = run.log("sgfd/classifier_accuracy")
                threshold = run.accuracy_threshold
                if len(steps) and (accuracy >= threshold).any():
                    ready.append(float(steps[np.argmax(accuracy >= threshold)]))
                for key, values in (("sgfd/weight_ess", ess), ("sgfd/weight_min", low), ("sgfd/weight_max", high)):
                    logged = run.log(key)[1]
                    if len(logged):
                        values.append(float(logged.mean()))
            finals = {split: [_final_return(run, split) for run in group] for split in ("train", "extrapolation")}
            top = np.concatenate([_features(run) for run in group])
            cells = [_mean_std(ready, "{:.0f}"), _mean_std(ess), _mean_std(low), _mean_std(high), _modal_share(top)]
            cells += [_mean_std([v for v in finals[split] if v is not None], "{:.1f}") for split in finals]
            names = f"| {markdown_text(env_id.split('/')[-1])} | {markdown_text(column_name(algo))} | {len(group)} | "
            lines.append(names + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def _final_return(run: RunFolder | RunRecord, split: str) -> float | None:
    evaluations = run.evaluations(split)
    return None if evaluations is None or not len(evaluations["results"]) else float(evaluations["results"][-1].mean())


def _features(run: RunFolder | RunRecord) -> np.ndarray:
    """The logged indices of the most salient feature, whole (the logger averages them over its interval: a mean
    of 14 and 15 is 14.5, counted as 14); refused, naming the run, when one is negative or beyond 2**53."""
    values = run.log(TOP_SALIENCY)[1]
    if not ((values >= 0) & (values < 2**53)).all():
        raise RefusedFile(f"{run.path}: refused: its {TOP_SALIENCY} values are not all feature indices (>= 0)")
    return values.astype(np.int64)


def _modal_share(values: np.ndarray) -> str:
    """The most frequent value and its share of ``values``, e.g. ``24 (93%)`` (the smallest of those tied); ``–``
    when empty. Counted by value, so that a large index costs nothing."""
    if not len(values):
        return "–"
    found, counts = np.unique(values, return_counts=True)
    return f"{found[counts.argmax()]} ({counts.max() / len(values):.0%})"


def _mean_std(values: list[float], form: str = "{:.2f}") -> str:
    if not values:
        return "–"
    return f"{form.format(np.mean(values))} ± {form.format(np.std(values))}"


def versions() -> str:
    """What exported the tables (each run's own ``versions.txt`` says what trained it): the source and the
    package versions, the CPUs, and rliable's version."""
    try:
        rliable = f"rliable=={metadata.version('rliable')}"
    except metadata.PackageNotFoundError:
        rliable = "rliable: not installed"
    threads = "torch threads per run: 1 (sweep --cpus-per-run 1)"
    header = "# what exported these tables; a record's versions.txt, where it has one, says what trained its run\n"
    return header + provenance.versions() + f"cpu count {_cpus()}\n{threads}\n{rliable}\n"


def _cpus() -> int:
    import os

    return os.cpu_count() or 1


def plan_lines(spec: dict[str, Any], out: Path, gpus: int, gpus_per_run: float | None) -> list[str]:
    """What ``sgfd-zoo study SPEC --plan`` prints: the spec's runs, those recorded already, and what the others cost
    (:func:`sgfd_zoo.sweep.cost.cost_lines`).

    :param spec: the checked spec
    :param out: the spec's folder (its records)
    :param gpus: the GPUs the wall time is for
    :param gpus_per_run: ``--gpus-per-run``; None: the packing rule's
    """
    recorded = {(record.algo, record.env_id, record.seed) for record in study_records(spec, out)}
    runs = plan_runs(spec["algos"], spec["envs"], spec["seeds"], spec["train"], spec["n_episodes"])
    todo = [run for run in runs if (run.algo, run.env_id, run.seed) not in recorded]
    scale = "the quick configuration" if has_flag(spec["train"], "--quick") else "the zoo's paper settings"
    head = (
        f"study {spec['name']}: {len(spec['algos'])} algos x {len(spec['envs'])} envs x {len(spec['seeds'])} seeds "
        f"= {len(runs)} runs at {scale}, {len(runs) - len(todo)} recorded in {out / 'runs'}, {len(todo)} to train"
    )
    return [head, *cost_lines(todo, gpus, gpus_per_run)]


def main(argv: list[str]) -> int:
    parser = ZooArgumentParser(
        prog="sgfd-zoo study", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("spec", type=Path, help="the study's spec.yml; results go to its folder")
    parser.add_argument("-f", "--folder", type=Path, help="log folder of the runs (default: logs/studies/<name>)")
    parser.add_argument("--export-only", action="store_true", help="no training: evaluate and export what is there")
    parser.add_argument("--progress-interval", type=float, default=60.0, help="seconds between progress blocks")
    parser.add_argument(
        "--gpus-per-run",
        metavar="FRACTION",
        help="each run's share of a GPU, as sgfd-zoo sweep takes it (0.25: 4 runs on a GPU; default: where there is "
        "a GPU, the packing rule's, see sgfd_zoo.sweep.plan.packing)",
    )
    parser.add_argument(
        "--plan",
        action="store_true",
        help="train nothing: print the runs still to train, the updates each, and their GPU-hours and wall time at "
        "the rates of the latest device check (sgfd_zoo/sweep/device_rates.csv)",
    )
    parser.add_argument("--gpus", type=int, help="with --plan: the GPUs the wall time is for (default: 1)")
    args, extra = parser.parse_known_args(argv)
    if extra:
        raise ZooError(f"unknown option(s) {extra}: training flags belong in the spec's train list")
    gpus_per_run = gpu_fraction(args.gpus_per_run)
    if args.gpus is not None and not args.plan:
        raise ZooError("--gpus sizes the --plan's wall time; a study trains on the GPUs Ray finds")
    check_at_least("--gpus", args.gpus, 1)
    spec = read_spec(args.spec)
    folder = (args.folder or Path("logs/studies") / spec["name"]).resolve()
    out = args.spec.parent
    if args.plan:
        print("\n".join(plan_lines(spec, out, args.gpus or 1, gpus_per_run)))
        return 0
    refuse_output_links(out)
    from sgfd_zoo.sweep import command as sweep  # here: a plan imports no training stack (torch, Ray)

    # The command that trains and exports (an --export-only pass records the study's own command, not itself).
    command = shlex.join(["sgfd-zoo", "study", *(arg for arg in argv if arg != "--export-only")])
    sweep_argv = [*sweep_arguments(spec, folder), "--progress-interval", str(args.progress_interval)]
    sweep_argv += [] if args.gpus_per_run is None else ["--gpus-per-run", args.gpus_per_run]
    recorded = {(record.algo, record.env_id, record.seed) for record in study_records(spec, out)}
    if args.export_only:
        log_runs = find_runs(folder, spec["algos"], spec["envs"])
        if not recorded and not log_runs:
            raise ZooError(f"--export-only: no finished run under {folder} and none recorded in {out / 'runs'}")
        if log_runs:
            evaluate_argv = ["-f", str(folder), "--algo", *spec["algos"], "--env", *spec["envs"]]
            evaluate.main([*evaluate_argv, "--n-episodes", str(spec["n_episodes"]), "--reference", spec["reference"]])
        status = 0
    else:
        print(
            f"study {spec['name']}: {len(spec['algos'])} algos x {len(spec['envs'])} envs x {len(spec['seeds'])} seeds"
            f" ({len(recorded)} recorded in {out / 'runs'} already)"
        )
        status = sweep.main(sweep_argv, recorded=recorded)
    written = export(spec, folder, out, command)
    print(f"study {spec['name']}: wrote {len(written)} files to {out}")
    if (out / "aggregate.md").exists():
        print(printable(read_text(out / "aggregate.md"), lines=True))
    finished = len(study_records(spec, out))
    total = len(spec["algos"]) * len(spec["envs"]) * len(spec["seeds"])
    if finished < total:
        print(f"study {spec['name']}: {finished} of {total} runs recorded; run the same command to continue")
    return status if finished == total or status else 1


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
