"""Writes the files that tests/agents/test_legacy_files.py loads: a model and a replay buffer of every agent, and a
zoo run folder with a checkpoint, as one version of the code saved them.

The files under ``0.1.0/`` were written by this script at commit f8368d4, before the algorithms moved to one
folder each and the zoo became ``sgfd_zoo``. The test loads them with today's code: a model, buffer or
checkpoint saved by an earlier version must keep loading.

    MUJOCO_GL=egl python tests/data/legacy/make_legacy_files.py OUT_FOLDER [AGENT ...]

Naming agents writes only their files (adding their actions to ``predictions.json``) and no zoo run. The
``sgfd_sac_ready`` files were added so, later, by this script run on the code of commit f8368d4
(``git archive f8368d4 | tar -x -C SRC``, then from SRC with ``PYTHONPATH=SRC``).
"""

from __future__ import annotations

import importlib.util
import json
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
from stable_baselines3 import SAC
from stable_baselines3.common.vec_env import VecFrameStack, VecTransposeImage

import sgfd_envs
from sb3_sgfd import AMBS, DBC, SGFD_SAC, SGQN, TED, DomainReplayBuffer, MlpPolicy

ENV_ID = "SGFD/MT-walker-walk-v0"
STATES = dict(learning_starts=50, batch_size=16, seed=0, buffer_size=400, policy_kwargs=dict(net_arch=[16, 16]))
PIXELS = dict(
    STATES,
    policy_kwargs=dict(net_arch=[16, 16], features_extractor_kwargs=dict(features_dim=8, n_filters=4, n_layers=2)),
    replay_buffer_kwargs=dict(frame_stack=2),
)
OVERLAYS = np.random.default_rng(0).integers(0, 256, size=(2, 24, 24, 3), dtype=np.uint8)


def state_env():
    return sgfd_envs.make_domain_vec_env(ENV_ID, obs_type="state", observe_parameter=True, seed=0)


def pixel_env():
    return VecTransposeImage(VecFrameStack(sgfd_envs.make_domain_vec_env(ENV_ID, image_size=24, seed=0), 2))


AGENTS = {
    "sac": lambda: SAC(MlpPolicy, state_env(), replay_buffer_class=DomainReplayBuffer, **STATES),
    "sgfd_sac": lambda: SGFD_SAC("MlpPolicy", state_env(), classifier_start=60, **STATES),
    "sgfd_sac_official": lambda: SGFD_SAC("MlpPolicy", state_env(), reading="official", classifier_start=60, **STATES),
    # the paper's reading once its classifier reached the threshold: its saved state has ready=True
    "sgfd_sac_ready": lambda: SGFD_SAC("MlpPolicy", state_env(), classifier_start=60, accuracy_threshold=0.1, **STATES),
    "sgfd_sac_ambs": lambda: SGFD_SAC(
        "AMBSPolicy", pixel_env(), representation="ambs", classifier_start=60, augmentation_views=2, **PIXELS
    ),
    "ambs": lambda: AMBS("CnnPolicy", pixel_env(), representation_kwargs=dict(hidden_dim=16), **PIXELS),
    "dbc": lambda: DBC("CnnPolicy", pixel_env(), representation_kwargs=dict(hidden_dim=16), **PIXELS),
    "ted": lambda: TED(
        "CnnPolicy", pixel_env(), **{**PIXELS, "replay_buffer_kwargs": dict(frame_stack=2, same_episode_negatives=True)}
    ),
    "sgqn": lambda: SGQN("CnnPolicy", pixel_env(), representation_kwargs=dict(overlay_images=OVERLAYS), **PIXELS),
}


def main(out: Path, names: list[str]) -> None:
    out.mkdir(parents=True, exist_ok=True)
    predictions = json.loads((out / "predictions.json").read_text()) if names else {}
    for name in names or AGENTS:
        model = AGENTS[name]().learn(120)
        model.save(out / f"{name}.zip")
        model.save_replay_buffer(out / f"{name}_buffer.pkl")
        observation = model.get_env().reset()
        action, _ = model.predict(observation, deterministic=True)
        np.save(out / f"{name}_observation.npy", observation)
        predictions[name] = action.tolist()
        model.get_env().close()
    (out / "predictions.json").write_text(json.dumps(predictions, indent=1) + "\n")
    if names:
        return
    # a zoo run killed after its first checkpoint, to be resumed by today's code
    logs = out / "train_folder"
    # the zoo of the checkout this runs from (``zoo.cli`` before the rename, ``sgfd_cli`` now)
    zoo = "zoo.cli" if importlib.util.find_spec("zoo") is not None else "sgfd_cli"
    command = [
        sys.executable,
        "-m",
        zoo,
        "train",
        "--algo",
        "sgfd_sac",
        "--env",
        ENV_ID,
        "--quick",
        "--seed",
        "0",
        "-n",
        "3000",
        "--save-freq",
        "300",
        "--eval-freq",
        "300",
        "--eval-episodes",
        "1",
        "-f",
        str(logs),
        "--hyperparams",
        "learning_starts:50",
        "batch_size:16",
        "buffer_size:1000",
        "classifier_start:100",
        "policy_kwargs:dict(net_arch=[16,16])",
    ]
    process = subprocess.Popen(command)
    while process.poll() is None:
        indexes = list(logs.glob("sgfd_sac/*/checkpoint.json"))
        if indexes and "300" in indexes[0].read_text():
            process.send_signal(signal.SIGKILL)
            break
        time.sleep(0.05)
    process.wait()


if __name__ == "__main__":
    main(Path(sys.argv[1]), sys.argv[2:])
