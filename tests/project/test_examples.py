"""The scripts in examples/ run end to end at toy size: they train, evaluate on unseen splits and report."""

from __future__ import annotations

import csv
import importlib.util
import json
import math
import re
import shlex
import sys
from pathlib import Path
from types import ModuleType

import pytest

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"


def load(name: str) -> ModuleType:
    """An example script imported as a module (examples/ is not a package)."""
    spec = importlib.util.spec_from_file_location(f"example_{name}", EXAMPLES / f"{name}.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module
    spec.loader.exec_module(module)
    return module


@pytest.mark.slow
def test_mt_state_trains_sgfd_and_evaluates_on_unseen_morphologies(capsys, tmp_path):
    example = load("mt_state_extrapolation")
    argv = ["--steps", "400", "--classifier-start", "250", "--eval-episodes", "1", "--progress", "0"]
    returns = example.main([*argv, "--record", str(tmp_path / "run.json")])
    assert list(returns) == ["train", "interpolation", "extrapolation"]
    for mean, std in returns.values():
        assert math.isfinite(mean) and mean >= 0 and std >= 0
    out = capsys.readouterr().out
    assert "ms per step" in out and "ms of CPU" in out
    assert "extrapolation: return" in out
    # live progress while it trains and while it evaluates
    assert "train sgfd MT-walker-walk-v0 seed 0: step 204: random actions done, updates start" in out
    assert re.search(r"train sgfd MT-walker-walk-v0 seed 0: step \d+/400 \(\d+%\), [\d.]+ steps/s, ETA", out)
    assert "evaluate sgfd MT-walker-walk-v0 seed 0 extrapolation: episode 1/1 return " in out
    # the record the docs' figures are copied from: the command, the machine, what it measured
    record = json.loads((tmp_path / "run.json").read_text())
    assert record["command"] == shlex.join(
        ["python", "examples/mt_state_extrapolation.py", *argv, "--record", str(tmp_path / "run.json")]
    )
    assert record["machine"]["torch_threads"] == 1 and record["eval_episodes"] == 1
    assert record["returns"] == {split: [round(m, 1), round(s, 1)] for split, (m, s) in returns.items()}


def test_mt_state_names_a_split_the_env_does_not_have(capsys):
    example = load("mt_state_extrapolation")
    with pytest.raises(SystemExit):
        example.main(["--steps", "10", "--splits", "test"])
    err = capsys.readouterr().err
    assert "--splits: 'test' is not a split of SGFD/MT-walker-walk-v0" in err


@pytest.mark.slow
def test_dmcgb_pixels_trains_on_train_and_evaluates_on_test_modes(capsys):
    example = load("dmcgb_pixels")
    returns = example.main(
        [
            *("--cpu-size", "--steps", "120", "--batch-size", "8", "--image-size", "32", "--progress", "0"),
            *("--eval-splits", "color_hard", "video_easy"),
        ]
    )
    assert list(returns) == ["train", "color_hard", "video_easy"]
    for mean, _ in returns.values():
        assert math.isfinite(mean) and mean >= 0
    out = capsys.readouterr().out
    # --cpu-size's other settings, the given ones kept; one torch thread unless --threads says otherwise
    assert "ted on DMCGB/walker-walk-v0 (train), 120 steps, batch 8, 32x32 pixels (fast rendering), device " in out
    assert "torch threads 1" in out
    assert "train ted: step 61: random actions done, updates start" in out
    assert "evaluating on train, color_hard, video_easy: 1 episode(s) each" in out
    assert "evaluate video_easy: episode 1/1 return " in out


def test_dmcgb_pixels_names_a_mode_the_benchmark_does_not_have(capsys):
    example = load("dmcgb_pixels")
    with pytest.raises(SystemExit):
        example.main(["--eval-splits", "extrapolation"])
    err = capsys.readouterr().err
    assert "--eval-splits: 'extrapolation' is not a test mode of DMCGB/walker-walk-v0" in err


@pytest.mark.slow
def test_compare_rliable_reports_iqm_with_intervals(tmp_path, capsys):
    example = load("compare_rliable")
    scores_csv = tmp_path / "scores.csv"
    iqm = example.main(
        [
            *("--tasks", "walker-walk", "--seeds", "0", "1", "--steps", "200", "--eval-episodes", "1"),
            *("--reps", "200", "--out", str(scores_csv)),
        ]
    )
    assert set(iqm) == {"SGFD", "DR"}
    assert all(0.0 <= value <= 1.0 for value in iqm.values())
    with scores_csv.open() as file:
        rows = list(csv.DictReader(file))
    runs = sorted((row["algo"], row["seed"]) for row in rows)
    assert runs == [("DR", "0"), ("DR", "1"), ("SGFD", "0"), ("SGFD", "1")]
    out = capsys.readouterr().out
    assert "IQM SGFD:" in out and "IQM   DR:" in out and "P(SGFD > DR):" in out
    assert "4 runs of 200 steps, 1 at a time, each in its own process" in out
    assert len(re.findall(r"\[\d/4\] (sgfd|sac) walker-walk seed [01]: extrapolation return", out)) == 4
