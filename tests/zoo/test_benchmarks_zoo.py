"""The benchmark ids in the zoo: yaml entries for every agent, models built at paper scale, and a run trained and
evaluated in the benchmark's layout (tasks x modes with the IQM of each mode)."""

import subprocess
import sys
from argparse import Namespace

import pytest
import yaml

import sgfd_envs
from sgfd_envs.registry import task_entry
from sgfd_zoo.algos import hyperparams_file
from sgfd_zoo.arguments import check_env_id
from sgfd_zoo.experiment import SGFDExperimentManager, register_algorithms
from sgfd_zoo.runs.folders import RunFolder

BENCHMARK_IDS = [env_id for ids in sgfd_envs.BENCHMARK_IDS.values() for env_id in ids]
AGENTS = ("ambs", "dbc", "sac", "sgfd_sac", "sgfd_sac_moderate", "sgfd_sac_official", "sgfd_sac_plain", "sgqn", "ted")


def training_steps(env_id):
    """Agent steps as each benchmark's code trained: DMC-GB's train.py 500k env.step calls, DMC-GB2 1M simulator
    steps at repeat 2 (500k), the DCS ids 1M simulator steps at their repeats (the zoo's choice)."""
    benchmark = env_id.split("/")[0]
    return 500_000 if benchmark in ("DMCGB", "DMCGB2") else 1_000_000 // task_entry(env_id).action_repeat


def test_the_zoo_accepts_the_benchmark_ids_and_names_their_runs():
    for env_id in BENCHMARK_IDS:
        assert check_env_id(env_id) == env_id
        run = RunFolder.at("logs", "sac", env_id, 3)
        assert RunFolder.parse(run.path) == run and run.env_id == env_id and run.run_id == 3


@pytest.mark.parametrize("quick", [False, True])
@pytest.mark.parametrize("agent", AGENTS)
def test_every_agent_has_an_entry_for_every_benchmark_id(agent, quick):
    entries = yaml.safe_load(hyperparams_file(agent, quick).read_text())
    for env_id in BENCHMARK_IDS:
        assert env_id in entries, f"{agent} {'quick' if quick else 'paper'}: no entry for {env_id}"
        entry = entries[env_id]
        if quick:
            assert entry == entries["default"]
        else:
            steps = training_steps(env_id)
            assert entry["n_timesteps"] == steps and entry["buffer_size"] == steps
            # the agent's settings, on the benchmarks' schedule (one env: an update per transition, no burst); the
            # code's reading keeps its own
            schedule = ("n_timesteps", "buffer_size", "train_freq", "gradient_steps", "callback")
            if agent != "sgfd_sac_official":
                assert (entry["train_freq"], entry["gradient_steps"], entry["callback"]) == (1, -1, [])
            assert {k: v for k, v in entry.items() if k not in schedule} == {
                k: v for k, v in entries["default"].items() if k not in schedule
            }


@pytest.mark.slow
@pytest.mark.parametrize("agent", ["sac", "sgfd_sac"])
@pytest.mark.parametrize("env_id", ["DMCGB/finger-spin-v0", "DMCGB2/walker-walk-v0", "DCS/cartpole-swingup-v0"])
def test_paper_scale_models_build_on_the_benchmark_ids(agent, env_id, tmp_path):
    register_algorithms()
    manager = SGFDExperimentManager(
        Namespace(), agent, env_id, str(tmp_path), eval_freq=-1, seed=0, verbose=0, device="cpu"
    )
    model, saved = manager.setup_experiment()
    try:
        assert model.n_envs == 1  # one training env: the undistracted split
        assert model.observation_space.shape == (9, 84, 84)
        assert saved["n_timesteps"] == training_steps(env_id)
        assert model.replay_buffer.buffer_size == saved["buffer_size"]
    finally:
        model.env.close()


def zoo(*args):
    result = subprocess.run([sys.executable, "-m", "sgfd_cli", *args], capture_output=True, text=True, timeout=900)
    assert result.returncode == 0, f"sgfd-zoo {' '.join(args)}:\n{result.stdout[-3000:]}\n{result.stderr[-3000:]}"
    return result


@pytest.mark.slow
def test_a_benchmark_run_trains_and_evaluates_in_the_benchmarks_layout(tmp_path):
    logs = tmp_path / "logs"
    for seed in ("0", "1"):
        zoo("train", "--algo", "sac", "--env", "DMCGB/cartpole-swingup-v0", "-f", str(logs), "--seed", seed,
            "--quick", "-n", "300", "--eval-freq", "-1", "--no-progress", "--verbose", "0")  # fmt: skip
    result = zoo("evaluate", "-f", str(logs), "--n-episodes", "1", "--bootstrap-reps", "200")
    table = result.stdout[result.stdout.index("# DMCGB: DR") :]
    lines = [line for line in table.splitlines() if line.startswith("|")]
    header = [cell.strip() for cell in lines[0].strip("|").split("|")]
    # Every test mode runs on a stand-in here (no data_dir, no DAVIS): marked so, and said under the table.
    intensities = ("0.025", "0.05", "0.1", "0.15", "0.2", "0.3", "0.4", "0.5")
    modes = ("color_easy", "color_hard", "video_easy", "video_hard", *(f"distracting_cs_{i}" for i in intensities))
    assert header == ["Task", "train", *(f"{mode} (stand-in)" for mode in modes)]
    assert "Marked (stand-in): played on sgfd_envs' procedural stand-ins" in table
    assert lines[2].split("|")[1].strip() == "cartpole-swingup"
    assert lines[3].split("|")[1].strip() == "**IQM**"
    iqm_cells = [cell.strip() for cell in lines[3].strip("|").split("|")[1:]]
    assert all(cell.count("[") == 1 for cell in iqm_cells)
    # The quick configuration observes states, which no distraction changes: the same returns in every mode.
    returns = {cell.strip() for cell in lines[2].strip("|").split("|")[1:]}
    assert len(returns) == 1


def test_tables_mark_the_splits_played_on_a_stand_in():
    from sgfd_zoo.report.evaluate import render_benchmark_tables, render_tables

    # as evaluate writes them (bools) and as they read back from csv (strings)
    marks = (("train", False), ("video_hard", True), ("color_hard", "False"), ("distracting_cs_0.1", "True"))
    rows = [
        {"algo": "sac", "env": "DMCGB/walker-walk-v0", "split": split, "seed": seed, "mean_reward": 100.0 + seed,
         "stand_in": stand_in}
        for seed in (0, 1)
        for split, stand_in in marks
    ]  # fmt: skip
    benchmark = render_benchmark_tables(rows, reps=100)
    header = next(
        line for line in benchmark.splitlines() if line.startswith("|") and line.split("|")[1].strip() == "Task"
    )
    assert [c.strip() for c in header.strip("|").split("|")] == [
        "Task", "train", "color_hard", "video_hard (stand-in)", "distracting_cs_0.1 (stand-in)"
    ]  # fmt: skip
    paper = render_tables(rows)
    assert "# video_hard (stand-in)" in paper and "# color_hard (mean" in paper
    assert paper.count("Marked (stand-in)") == 2
