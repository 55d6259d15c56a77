"""Files saved by an earlier version load with today's code: each agent's model (the same actions), its replay
buffer (the same transitions, and it samples), and a zoo run's checkpoint (`--resume` continues it).

The files in tests/data/legacy/0.1.0 were written by tests/data/legacy/make_legacy_files.py at version 0.1.0,
when SGFD_SAC lived in ``sb3_sgfd.sac``, the policies in ``sb3_sgfd.policies``, the buffer in
``sb3_sgfd.buffers.replay`` and the zoo was the package ``zoo``."""

from __future__ import annotations

import json
import pickle
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from stable_baselines3 import SAC

from sb3_sgfd import AMBS, DBC, SGFD_SAC, SGQN, TED, DomainReplayBuffer
from sgfd_zoo.runs.folders import RunFolder

LEGACY = Path(__file__).parents[1] / "data" / "legacy" / "0.1.0"
ALGOS = {
    "sac": SAC,
    "sgfd_sac": SGFD_SAC,
    "sgfd_sac_official": SGFD_SAC,
    "sgfd_sac_ready": SGFD_SAC,
    "sgfd_sac_ambs": SGFD_SAC,
    "ambs": AMBS,
    "dbc": DBC,
    "ted": TED,
    "sgqn": SGQN,
}


@pytest.mark.parametrize("name", list(ALGOS))
def test_a_model_saved_by_version_0_1_0_loads_and_acts_as_it_did(name):
    model = ALGOS[name].load(LEGACY / f"{name}.zip", device="cpu")
    observation = np.load(LEGACY / f"{name}_observation.npy")
    action, _ = model.predict(observation, deterministic=True)
    expected = json.loads((LEGACY / "predictions.json").read_text())[name]
    np.testing.assert_allclose(action, expected, rtol=0, atol=1e-6)


def test_sgfd_settings_of_a_version_0_1_0_model_are_its_own():
    paper = SGFD_SAC.load(LEGACY / "sgfd_sac.zip", device="cpu")
    official = SGFD_SAC.load(LEGACY / "sgfd_sac_official.zip", device="cpu")
    assert paper.sgfd.reading == "paper" and paper.sgfd.reweight_ess_penalty == 0.35
    assert official.sgfd.reading == "official" and official.sgfd.reweight_ess_penalty == 5
    assert official.sgfd.classifier_interval == 4 and official.sgfd.reweight_memory == 0.9
    assert paper.sgfd.classifier_start == official.sgfd.classifier_start == 60
    assert type(official.weighting).__name__ == "OfficialWeighting"


def test_the_weighting_state_of_a_version_0_1_0_model_is_restored():
    # what version 0.1.0 saved as the weighting's extra state: the official reading's memory after 9 updates,
    # the paper reading's flag (its classifier had reached the threshold in sgfd_sac_ready, not in sgfd_sac)
    memory = SGFD_SAC.load(LEGACY / "sgfd_sac_official.zip", device="cpu").weighting.memory
    assert memory.updates == 9
    assert memory.features is not None and memory.features.shape == (16, 25)
    assert memory.logits is not None and memory.logits.shape == (16,)
    assert SGFD_SAC.load(LEGACY / "sgfd_sac_ready.zip", device="cpu").weighting.ready.item() is True
    assert SGFD_SAC.load(LEGACY / "sgfd_sac.zip", device="cpu").weighting.ready.item() is False


@pytest.mark.parametrize("name", ["sac", "sgfd_sac", "sgfd_sac_official", "ambs", "ted"])
def test_a_replay_buffer_saved_by_version_0_1_0_loads_and_samples(name):
    with open(LEGACY / f"{name}_buffer.pkl", "rb") as handle:
        buffer = pickle.load(handle)
    assert isinstance(buffer, DomainReplayBuffer) and buffer.size() > 0
    batch = buffer.sample(8)
    assert batch.observations.shape[0] == 8 and batch.domains is not None
    model = ALGOS[name].load(LEGACY / f"{name}.zip", device="cpu")
    model.load_replay_buffer(LEGACY / f"{name}_buffer.pkl")
    assert model.replay_buffer.size() == buffer.size()


@pytest.mark.slow
def test_a_zoo_run_checkpointed_by_version_0_1_0_resumes(tmp_path):
    folder = tmp_path / "logs"
    shutil.copytree(LEGACY / "train_folder", folder)
    command = LEGACY / "train_folder" / "sgfd_sac" / "SGFD-MT-walker-walk-v0_1" / "SGFD-MT-walker-walk-v0"
    flags = (command / "command.txt").read_text().split(" train ", 1)[1].split()
    flags[flags.index("-f") + 1] = str(folder)
    flags[flags.index("-n") + 1] = "600"
    result = subprocess.run(
        [sys.executable, "-m", "sgfd_cli", "train", *flags, "--resume"], capture_output=True, text=True, timeout=600
    )
    assert result.returncode == 0, result.stderr[-2000:]
    assert "300" in result.stdout + result.stderr  # it continued from the checkpoint at 300 steps
    run = folder / "sgfd_sac" / "SGFD-MT-walker-walk-v0_1"
    assert (run / "finished.json").exists()
    assert SGFD_SAC.load(run / "SGFD-MT-walker-walk-v0.zip", device="cpu").num_timesteps == 600
    # it went on on the envs it trained on (this package's scaled robots, the MT ids' only family at 0.1.0), and
    # says so now (sgfd_envs.families)
    resumed = RunFolder(run)
    assert resumed.args["env_family"] == {"robots": "scaled"} and resumed.config["env_kwargs"]["robots"] == "scaled"
