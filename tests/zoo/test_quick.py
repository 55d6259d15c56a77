"""The main job as a user meets it: ``sgfd-zoo quick`` at any length, SGFD's classifier start, the learning curves
of a run evaluated once, and what ``sgfd-zoo evaluate`` says about unfinished runs and the tables it replaces."""

from __future__ import annotations

import contextlib
import io
import json
import shlex
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

from sgfd_cli import main as zoo_main
from sgfd_zoo import algos, quick
from sgfd_zoo.algos import classifier_start_warning
from sgfd_zoo.arguments import ZooError
from sgfd_zoo.report.plot import draw_env, load_curves
from sgfd_zoo.runs.folders import FINISHED_MARKER, RunFolder

REPO = Path(__file__).resolve().parents[2]
ENV_ID = "SGFD/MT-walker-walk-v0"
NAME = "SGFD-MT-walker-walk-v0"
TINY = ["--quick", "--num-threads", "1", "--no-progress", "--verbose", "0", "--save-freq", "100"]
TINY += ["-params", "learning_starts:50", "batch_size:16", "buffer_size:1000", "policy_kwargs:dict(net_arch=[16])"]


def zoo(args: list[str]) -> tuple[int, str, str]:
    """``sgfd-zoo`` in this process: exit code, stdout, stderr."""
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = zoo_main(args)
    return code, out.getvalue(), err.getvalue()


# -- SGFD's classifier start ------------------------------------------------------------------------------


def test_a_run_too_short_for_sgfds_classifier_says_it_is_plain_sac():
    warning = classifier_start_warning("sgfd_sac", {"classifier_start": 4000}, 3000)
    assert warning is not None and "3000 steps" in warning and "step 4000" in warning and "plain SAC" in warning
    assert "--classifier-start" in warning
    assert classifier_start_warning("sgfd_sac", {"classifier_start": 4000}, 4001) is None
    assert classifier_start_warning("sac", {}, 10) is None  # no classifier
    # the constructor's default when the yaml has none (100k)
    assert "step 100000" in classifier_start_warning("sgfd_sac_no_rff", {}, 50_000)
    # the authors' reading weights from the first update, with a classifier that then never trains
    official = classifier_start_warning("sgfd_sac_official", {"classifier_start": 4000, "reading": "official"}, 300)
    assert "never trains" in official and "plain SAC" not in official


def test_the_quick_jobs_length_moves_sgfds_classifier_start_in_proportion():
    assert quick.quick_setting("sgfd_sac", ENV_ID, "classifier_start") == 4000
    assert quick.quick_setting("sgfd_sac", ENV_ID, "n_timesteps") == 20000
    assert quick.scaled_classifier_start(["sgfd_sac", "sac"], ENV_ID, 3000) == 600
    assert quick.scaled_classifier_start(["sgfd_sac_official", "sac"], ENV_ID, quick.SHORT_STEPS) == 800
    assert quick.scaled_classifier_start(["sgfd_sac", "sac"], ENV_ID, 20000) is None  # the configuration's own
    assert quick.scaled_classifier_start(["sac"], ENV_ID, 3000) is None


def test_the_quick_settings_are_the_entry_rl_zoo3_reads_and_load_no_agent(tmp_path, monkeypatch):
    code = (
        "import json, sys\nfrom sgfd_zoo.quick import quick_setting\n"
        f"quick_setting('sgfd_sac', {ENV_ID!r}, 'n_timesteps')\n"
        "print(json.dumps([m for m in ('torch', 'stable_baselines3', 'rl_zoo3', 'optuna') if m in sys.modules]))"
    )
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120, cwd=REPO)
    assert result.returncode == 0, result.stderr[-2000:]
    assert json.loads(result.stdout.splitlines()[-1]) == []
    # rl-zoo3 takes the env id's entry whole (not merged into "default"), else "default"
    (tmp_path / "quick").mkdir()
    (tmp_path / "quick" / "sac.yml").write_text("default: {a: 1, b: 2}\nSome/id-v0: {a: 3}\n")
    monkeypatch.setattr(algos, "HYPERPARAMS_DIR", tmp_path)
    assert quick.quick_setting("sac", "Some/id-v0", "a") == 3
    assert quick.quick_setting("sac", "Some/id-v0", "b") is None
    assert quick.quick_setting("sac", "Other/id-v0", "b") == 2


def test_train_takes_the_classifier_start_for_sgfd_and_a_sweep_may_mix_in_sac(tmp_path):
    common = ["--env", ENV_ID, "-f", str(tmp_path), "-n", "120", "--eval-freq", "-1", *TINY]
    code, _, err = zoo(["train", "--algo", "sgfd_sac", *common])
    assert code == 0 and "warning: sgfd_sac: the run is 120 steps" in err and "plain SAC" in err
    code, _, err = zoo(["train", "--algo", "sgfd_sac", *common, "--classifier-start", "60"])
    assert code == 0 and "warning" not in err
    config = yaml.load((tmp_path / "sgfd_sac" / f"{NAME}_2" / NAME / "config.yml").read_text(), yaml.UnsafeLoader)
    assert dict(config)["classifier_start"] == 60
    code, _, err = zoo(["train", "--algo", "sac", *common, "--classifier-start", "60"])  # SAC has no classifier
    assert code == 0 and "warning" not in err
    code, _, err = zoo(["train", "--algo", "sgfd_sac", *common[:-1], "classifier_start:5", "--classifier-start", "60"])
    assert code == 2 and err.strip().endswith(
        "--classifier-start and --hyperparams classifier_start:... both set; give one"
    )
    code, _, err = zoo(["train", "--algo", "sgfd_sac", *common, "--classifier-start", "-1"])
    assert code == 2 and "--classifier-start" in err and len(err.strip().splitlines()) == 1


def test_the_quick_job_refuses_a_folder_of_runs_of_another_length(tmp_path):
    argv = ["train", "--algo", "sac", "--env", ENV_ID, "--seed", "0", "-f", str(tmp_path), "-n", "100", *TINY]
    code, _, err = zoo(argv)
    assert code == 0, err
    quick.check_run_lengths(tmp_path, ["sgfd_sac", "sac"], ENV_ID, 100)  # the same length: kept, continued
    with pytest.raises(ZooError, match=r"holds runs of another length \(sac seed 0: 100 steps\); this job trains 4000"):
        quick.check_run_lengths(tmp_path, ["sgfd_sac", "sac"], ENV_ID, 4000)


# -- curves and tables of a log folder --------------------------------------------------------------------


@pytest.fixture(scope="module")
def logs(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Two tiny SAC runs, each evaluated once (at its last step): seed 0 finished, seed 1 stopped after its last
    checkpoint (its final model and marker taken away, as a kill during the final save leaves it)."""
    folder = tmp_path_factory.mktemp("quick") / "logs"
    for seed in ("0", "1"):
        argv = ["train", "--algo", "sac", "--env", ENV_ID, "--seed", seed, "-f", str(folder), "-n", "200", *TINY]
        code, _, err = zoo([*argv, "--eval-freq", "200", "--eval-episodes", "1"])
        assert code == 0, err
    stopped = folder / "sac" / f"{NAME}_2"
    (stopped / f"{NAME}.zip").unlink()
    (stopped / FINISHED_MARKER).unlink()
    return folder


@pytest.mark.slow
def test_a_run_evaluated_once_plots_as_a_visible_point(logs):
    curves = load_curves(logs)
    figure = draw_env(ENV_ID, curves[ENV_ID])
    for ax in figure.axes:
        # one algorithm, one step: a marker (with its error bar), not a line of one point, which draws nothing
        (point,) = [line for line in ax.lines if line.get_marker() == "o"]
        assert list(point.get_xdata()) == [200]
    code, out, _ = zoo(["plot", "-f", str(logs)])
    assert code == 0 and f"{NAME}.png" in out


@pytest.mark.slow
def test_evaluate_names_unfinished_runs_with_the_command_that_continues_each_and_the_tables_it_replaces(logs):
    code, out, err = zoo(["evaluate", "-f", str(logs), "--n-episodes", "1", "--bootstrap-reps", "100"])
    assert code == 0, err
    lines = out.splitlines()
    assert lines[0].startswith("evaluate: 1 unfinished run is not in the tables")
    assert lines[1].startswith(f"  sac on {ENV_ID} seed 1 (checkpoint at step 200): sgfd-zoo train ")
    command = shlex.split(lines[1].split(": ", 1)[1])
    assert command[-3:] == ["--run-id", "2", "--resume"] and "replacing" not in out
    assert lines[-1].startswith(f"Wrote {logs / 'results.csv'}, ") and "replaced" not in lines[-1]

    code, out, err = zoo(command[1:])  # the printed command continues the run: it finishes
    assert code == 0, err
    assert RunFolder(logs / "sac" / f"{NAME}_2").finished

    code, out, err = zoo(["evaluate", "-f", str(logs), "--n-episodes", "1", "--bootstrap-reps", "100"])
    assert code == 0, err
    assert "unfinished" not in out
    assert "evaluate: replacing the tables of " in out and f"in {logs} (1 run) with these of 2 runs" in out
    wrote = out.splitlines()[-1]
    assert f"eplaced {logs / 'results.csv'}, {logs / 'results.md'}, {logs / 'scores.csv'}" in wrote
