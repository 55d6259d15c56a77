"""``sgfd-zoo study SPEC``: a checked spec, its sweep, and the compact results written next to it."""

from __future__ import annotations

import contextlib
import csv
import io
import shutil
from pathlib import Path

import pytest
import yaml

from sgfd_cli import main as zoo_main
from sgfd_zoo.runs import provenance

pytestmark = pytest.mark.ray

ENV_ID = "SGFD/MT-walker-walk-v0"
TINY_PARAMS = ("-params", "learning_starts:100", "classifier_start:200")
SPEC = {
    "name": "tiny",
    "description": "a test",
    "algos": ["sgfd_sac", "sgfd_sac_no_saliency"],  # both SGFD: the classifier_start flag fits both
    "envs": [ENV_ID],
    "seeds": [0],
    "train": [*("--quick", "-n", "400", "--eval-freq", "400", "--eval-episodes", "1"), *TINY_PARAMS],
    "n_episodes": 1,
}


def write_spec(folder: Path, **changes: object) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / "spec.yml"
    path.write_text(yaml.safe_dump({**SPEC, **changes}))
    return path


@pytest.mark.parametrize(
    ("changes", "message"),
    [
        ({"algos": ["sgfd"]}, "algos: 'sgfd' is unknown (did you mean sgfd_sac?)"),
        ({"envs": ["SGFD/MT-walker-wlk-v0"]}, "envs: 'SGFD/MT-walker-wlk-v0' is unknown"),
        ({"seeds": [-1]}, "seeds must be integers >= 0"),
        ({"budget": 3}, "unknown key(s) ['budget']"),
        ({"name": None}, "name is required"),
    ],
)
def test_a_bad_spec_is_refused_in_one_line(tmp_path, capsys, changes, message):
    assert zoo_main(["study", str(write_spec(tmp_path, **changes)), "-f", str(tmp_path / "logs")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and message in err[0]
    assert not (tmp_path / "logs").exists()


@pytest.mark.slow
def test_a_study_trains_evaluates_and_writes_its_compact_results_next_to_its_spec(tmp_path):
    spec = write_spec(tmp_path / "studies" / "tiny")
    logs = tmp_path / "logs"
    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        assert zoo_main(["study", str(spec), "-f", str(logs)]) == 0
    study = spec.parent
    for name in ("results.csv", "results.md", "scores.csv", "aggregate.csv", "aggregate.md", "versions.txt"):
        assert (study / name).stat().st_size > 0, name
    assert (study / "command.txt").read_text().startswith(f"sgfd-zoo study {spec} -f {logs}")
    assert "torch==2.13.0" in (study / "versions.txt").read_text()
    with (study / "scores.csv").open() as handle:
        assert len(list(csv.DictReader(handle))) == 2 * 3  # two runs x three splits
    for algo in ("sgfd_sac", "sgfd_sac_no_saliency"):
        run = study / "runs" / algo / "SGFD-MT-walker-walk-v0_1"
        assert {path.name for path in run.iterdir()} == {
            "config.yml",
            "args.yml",
            "versions.txt",
            "source.txt",
            "diagnostics.csv",
            "final_evaluation.csv",
            "evaluations_train.npz",
            "evaluations_interpolation.npz",
            "evaluations_extrapolation.npz",
        }
        # what trained it, as the run wrote it when it started
        trained_by = (run / "versions.txt").read_text()
        assert trained_by.startswith("=== from step 0, ") and provenance.source() in trained_by
    with (study / "runs" / "sgfd_sac" / "SGFD-MT-walker-walk-v0_1" / "diagnostics.csv").open() as handle:
        columns = next(csv.reader(handle))
    assert {"timesteps", "sgfd/classifier_accuracy", "train/critic_loss"} <= set(columns)
    plots = {path.name for path in (study / "plots").iterdir()}
    assert {"aggregate_train.png", "diagnostics_SGFD-MT-walker-walk-v0.png"} <= plots
    assert (study / "plots" / "diagnostics_SGFD-MT-walker-walk-v0.png").stat().st_size > 10_000
    # no model, buffer or checkpoint next to the spec
    assert not [path for path in study.rglob("*") if path.suffix in (".zip", ".pkl")]
    # again: nothing left to train, the export is redone
    again = io.StringIO()
    with contextlib.redirect_stdout(again):
        assert zoo_main(["study", str(spec), "-f", str(logs)]) == 0
    assert "0 trained, 2 already finished" in again.getvalue()
    # an export-only pass records the study's command, not its own
    command = (study / "command.txt").read_text()
    with contextlib.redirect_stdout(io.StringIO()):
        assert zoo_main(["study", str(spec), "-f", str(logs), "--export-only"]) == 0
    assert (study / "command.txt").read_text() == command
    # on another machine (no log folder, the study's records committed): nothing is trained again, and the
    # tables are the same, computed from the records
    tables = {name: (study / name).read_text() for name in ("results.csv", "scores.csv", "aggregate.csv")}
    shutil.rmtree(logs)
    fresh = io.StringIO()
    with contextlib.redirect_stdout(fresh):
        assert zoo_main(["study", str(spec), "-f", str(logs)]) == 0
    assert "(2 recorded in" in fresh.getvalue() and "0 trained, 2 already finished" in fresh.getvalue()
    assert {name: (study / name).read_text() for name in tables} == tables
    with (study / "results.csv").open() as handle:
        assert {row["run"] for row in csv.DictReader(handle)} == {
            "runs/sgfd_sac/SGFD-MT-walker-walk-v0_1",
            "runs/sgfd_sac_no_saliency/SGFD-MT-walker-walk-v0_1",
        }


def write_logged_run(folder: Path, algo: str, config: dict[str, object], logged: dict[str, list[float]]) -> None:
    """A run folder with only what the diagnostics read: its config and a progress.csv logged every 1000 steps."""
    run = folder / algo / "SGFD-MT-walker-walk-v0_1"
    (run / "SGFD-MT-walker-walk-v0").mkdir(parents=True)
    (run / "SGFD-MT-walker-walk-v0" / "config.yml").write_text(yaml.safe_dump(config))
    n_rows = len(next(iter(logged.values())))
    with (run / "progress.csv").open("w", newline="") as handle:
        writer = csv.writer(handle)
        writer.writerow(["time/total_timesteps", *logged])
        for row in range(n_rows):
            writer.writerow([1000 * (row + 1), *(values[row] for values in logged.values())])


def test_the_diagnostics_read_each_runs_own_threshold_and_name_the_most_salient_feature(tmp_path):
    from sgfd_zoo.runs.folders import find_runs
    from sgfd_zoo.study import diagnostics_summary

    logged = {"sgfd/classifier_accuracy": [0.25, 0.85, 0.95], "sgfd/top_saliency_feature": [24, 24, 3]}
    write_logged_run(tmp_path, "sgfd_sac", {"classifier_start": 0}, logged)  # the paper reading: 0.9
    write_logged_run(tmp_path, "sgfd_sac_official", {"reading": "official"}, logged)  # the code's: 0.8
    write_logged_run(tmp_path, "sgfd_sac_moderate", {"accuracy_threshold": 0.2}, logged)  # its own
    rows = {
        cells[1]: cells
        for line in diagnostics_summary(find_runs(tmp_path, finished=False)).splitlines()[2:]
        for cells in [[cell.strip() for cell in line.strip("|").split("|")]]
    }
    assert {name: cells[3] for name, cells in rows.items()} == {
        "SGFD": "3000 ± 0",
        "SGFD (code)": "2000 ± 0",
        "SGFD moderate": "1000 ± 0",
    }
    assert {cells[7] for cells in rows.values()} == {"24 (67%)"}


def write_record(study: Path, algo: str, seed: int, splits: tuple[str, ...]) -> Path:
    """A run record with only its final evaluation (on ``splits``) and two logged steps."""
    record = study / "runs" / algo / f"SGFD-MT-walker-walk-v0_{seed + 1}"
    record.mkdir(parents=True)
    with (record / "final_evaluation.csv").open("w", newline="") as handle:
        writer = csv.writer(handle)
        writer.writerow(["algo", "env", "split", "seed", "mean_reward", "std_reward", "n_episodes"])
        for split in splits:
            writer.writerow([algo, ENV_ID, split, seed, 100.0 * (seed + 1), 1.5, 10])
    (record / "diagnostics.csv").write_text("timesteps,sgfd/weight_ess\n1000,0.9\n2000,\n3000,0.7\n")
    return record


def test_a_record_without_its_whole_final_evaluation_is_trained_again_and_a_whole_one_is_not(tmp_path):
    from sgfd_zoo.runs.records import RunRecord
    from sgfd_zoo.study import read_spec, study_records
    from sgfd_zoo.sweep import command as sweep

    spec = read_spec(write_spec(tmp_path / "study", seeds=[0, 1, 2]))
    whole = write_record(tmp_path / "study", "sgfd_sac", 0, ("train", "interpolation", "extrapolation"))
    write_record(tmp_path / "study", "sgfd_sac", 1, ("train", "interpolation"))  # its export was cut short
    write_record(tmp_path / "study", "sgfd_sac", 7, ("train", "interpolation", "extrapolation"))  # not the spec's
    record = RunRecord(whole)
    assert [row["mean_reward"] for row in record.final_rows] == [100.0] * 3 and record.seed == 0
    steps, ess = record.log("sgfd/weight_ess")
    assert steps.tolist() == [1000, 3000] and ess.tolist() == [0.9, 0.7]
    assert record.log("sgfd/weight_max")[0].size == 0

    records = study_records(spec, tmp_path / "study")
    assert [(r.algo, r.seed) for r in records] == [("sgfd_sac", 0)]
    recorded = {(r.algo, r.env_id, r.seed) for r in records}
    jobs, done, _ = sweep.plan(tmp_path / "logs", spec["algos"], spec["envs"], spec["seeds"], recorded)
    assert done == [("sgfd_sac", ENV_ID, 0)]
    assert [(job.algo, job.seed) for job in jobs] == [
        ("sgfd_sac_no_saliency", 0), ("sgfd_sac", 1), ("sgfd_sac_no_saliency", 1),
        ("sgfd_sac", 2), ("sgfd_sac_no_saliency", 2),
    ]  # fmt: skip


def write_log_run(logs: Path, algo: str, run_id: int, seed: int) -> Path:
    """A log run folder with only what names its cell: rl-zoo3's args.yml."""
    run = logs / algo / f"SGFD-MT-walker-walk-v0_{run_id}"
    (run / "SGFD-MT-walker-walk-v0").mkdir(parents=True)
    (run / "SGFD-MT-walker-walk-v0" / "args.yml").write_text(yaml.safe_dump({"seed": seed}))
    return run


def test_a_fresh_log_folders_run_never_overwrites_an_earlier_sessions_record_of_another_seed(tmp_path):
    from sgfd_zoo.arguments import ZooError
    from sgfd_zoo.runs.folders import RunFolder
    from sgfd_zoo.runs.records import RunRecord, find_records
    from sgfd_zoo.study import record_of

    study, runs = tmp_path / "study", tmp_path / "study" / "runs"
    for seed in (0, 1):  # an earlier session's records (from before records named their run): _1 and _2
        write_record(study, "sgfd_sac", seed, ("train", "interpolation", "extrapolation"))

    def cells() -> dict:
        return {(r.algo, r.env_id, r.seed): r for r in find_records(runs)}

    # this session's log folder numbers its runs from 1 again: seed 3 is run _1, seed 4 run _2
    seed3 = RunFolder(write_log_run(tmp_path / "logs", "sgfd_sac", 1, 3))
    record = record_of(seed3, runs, cells())
    assert record.path.name == "SGFD-MT-walker-walk-v0_3"
    record.path.mkdir()
    record.source_file.write_text(f"{seed3.path.resolve()}\n")
    assert record_of(seed3, runs, cells()) == record  # exported again: the same record, even before it is whole
    seed4 = RunFolder(write_log_run(tmp_path / "logs", "sgfd_sac", 2, 4))
    assert record_of(seed4, runs, cells()).path.name == "SGFD-MT-walker-walk-v0_4"
    # an old record of the same cell and the same name is this run's (what exports did before names were kept)
    seed0 = RunFolder(write_log_run(tmp_path / "old-logs", "sgfd_sac", 1, 0))
    assert record_of(seed0, runs, cells()) == RunRecord(runs / "sgfd_sac" / "SGFD-MT-walker-walk-v0_1")
    # a second run of a recorded cell is refused, naming both
    again = RunFolder(write_log_run(tmp_path / "other-logs", "sgfd_sac", 5, 1))
    with pytest.raises(ZooError, match=r"v0_5 \(seed 1\) is already recorded as .*SGFD-MT-walker-walk-v0_2"):
        record_of(again, runs, cells())


def test_an_unreadable_final_evaluation_is_named(tmp_path):
    from sgfd_zoo.runs.files import UnreadableFile
    from sgfd_zoo.runs.records import RunRecord

    record = RunRecord(write_record(tmp_path, "sac", 0, ("train",)))
    record.final_evaluation.write_text("algo,env,split,seed\nsac,x,train,zero\n")
    with pytest.raises(UnreadableFile, match=r"final_evaluation\.csv is unreadable"):
        _ = record.final_rows
