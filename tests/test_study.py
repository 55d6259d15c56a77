"""``sgfd-zoo study SPEC``: a checked spec, its sweep, and the compact results written next to it."""

from __future__ import annotations

import contextlib
import csv
import io
from pathlib import Path

import pytest
import yaml

from zoo.cli import main as zoo_main

pytestmark = pytest.mark.ray

ENV_ID = "SGFD/MT-walker-walk-v0"
TINY_PARAMS = ("-params", "learning_starts:100", "classifier_start:200")
SPEC = {
    "name": "tiny",
    "description": "a test",
    "algos": ["sgfd_sac", "sgfd_sac_no_saliency"],  # both SGFD: the classifier_start flag fits both
    "envs": [ENV_ID],
    "seeds": [0],
    "train": [*("--quick", "-n", "400", "--eval-freq", "200", "--eval-episodes", "1"), *TINY_PARAMS],
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
            "diagnostics.csv",
            "evaluations_train.npz",
            "evaluations_interpolation.npz",
            "evaluations_extrapolation.npz",
        }
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
