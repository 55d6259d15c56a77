"""The benchmark ids in the zoo: yaml entries for every agent, models built at paper scale, and a run trained and
evaluated in the benchmark's layout (tasks x modes with the IQM of each mode)."""

import subprocess
import sys
from argparse import Namespace

import pytest
import yaml

import sgfd_envs
from sgfd_envs.registry import task_entry
from sgfd_zoo.arguments import check_env_id
from sgfd_zoo.experiment import SGFDExperimentManager, hyperparams_file, register_algorithms
from sgfd_zoo.runs import RunFolder

BENCHMARK_IDS = [env_id for ids in sgfd_envs.BENCHMARK_IDS.values() for env_id in ids]
AGENTS = ("ambs", "dbc", "sac", "sgfd_sac", "sgfd_sac_moderate", "sgfd_sac_official", "sgfd_sac_plain", "sgqn", "ted")
# The benchmarks' training lengths in simulator steps (frames): DMC-GB 500k, DMC-GB2 1M, DCS 1M (as DMC-GB2).
TRAINING_FRAMES = {"DMCGB": 500_000, "DMCGB2": 1_000_000, "DCS": 1_000_000}


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
            steps = TRAINING_FRAMES[env_id.split("/")[0]] // task_entry(env_id).action_repeat
            assert entry["n_timesteps"] == steps and entry["buffer_size"] == steps
            assert {k: v for k, v in entry.items() if k not in ("n_timesteps", "buffer_size")} == {
                k: v for k, v in entries["default"].items() if k not in ("n_timesteps", "buffer_size")
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
        assert saved["n_timesteps"] == TRAINING_FRAMES[env_id.split("/")[0]] // task_entry(env_id).action_repeat
        assert model.replay_buffer.buffer_size == saved["buffer_size"]
    finally:
        model.env.close()


def zoo(*args):
    result = subprocess.run([sys.executable, "-m", "sgfd_zoo.cli", *args], capture_output=True, text=True, timeout=900)
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
    assert header == ["Task", "train", "color_easy", "color_hard", "video_easy", "video_hard"]
    assert lines[2].split("|")[1].strip() == "cartpole-swingup"
    assert lines[3].split("|")[1].strip() == "**IQM**"
    iqm_cells = [cell.strip() for cell in lines[3].strip("|").split("|")[1:]]
    assert all(cell.count("[") == 1 for cell in iqm_cells)
    # The quick configuration observes states, which no distraction changes: the same returns in every mode.
    returns = {cell.strip() for cell in lines[2].strip("|").split("|")[1:]}
    assert len(returns) == 1
