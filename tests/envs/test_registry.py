"""The id table is import-light and each id's entry point is its real builder: ``import sgfd_envs`` and
``gym.spec`` load no simulator and no OpenCV (gymnasium's own table imports no env code either), and the builder a
spec names makes the env ``gym.make`` makes."""

from __future__ import annotations

import importlib
import importlib.util
import os
import subprocess
import sys
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest

import sgfd_envs
from sgfd_envs.builders import env_kwargs_of
from sgfd_envs.registry import BUILDERS, task_entry

REPO = Path(__file__).resolve().parents[2]
HEAVY = ("cv2", "mujoco", "dm_control")


def test_import_and_every_spec_load_neither_the_simulator_nor_opencv():
    code = (
        "import os, sys, sgfd_envs, gymnasium as gym\n"
        "specs = [gym.spec(env_id) for env_id in sgfd_envs.ENV_IDS]\n"
        f"print(len(specs), sorted(m for m in {HEAVY!r} if m in sys.modules), os.environ.get('MUJOCO_GL'))\n"
    )
    # A fresh interpreter with MUJOCO_GL unset: importing sgfd_envs still picks EGL for the dm_control to come.
    env = {name: value for name, value in os.environ.items() if name != "MUJOCO_GL"}
    env["PYTHONPATH"] = os.pathsep.join([str(REPO), env.get("PYTHONPATH", "")])
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=REPO, env=env, check=True)
    backend = "egl" if sys.platform.startswith("linux") else "None"
    assert done.stdout.split() == [str(len(sgfd_envs.ENV_IDS)), "[]", backend]


def test_every_spec_names_its_kinds_builder_which_makes_the_env():
    made_kinds = set()
    for env_id in sgfd_envs.ENV_IDS:
        spec = gym.spec(env_id)
        module, name = spec.entry_point.split(":")
        builder = getattr(importlib.import_module(module), name)
        variation = task_entry(env_id).variation
        assert (module, name) == ("sgfd_envs.builders", BUILDERS[variation]) and callable(builder)
        assert builder.__name__ == name and spec.kwargs == {"env_id": env_id}
        if variation == "causal_world" and importlib.util.find_spec("causal_world") is None:
            with pytest.raises(ImportError, match="causalworld"):
                builder(**spec.kwargs)
            continue
        with builder(**spec.kwargs, obs_type="state") as built:
            observation = built.reset(seed=1)[0]
            if variation not in made_kinds:  # the first of its kind: the env gym.make makes
                with gym.make(env_id, obs_type="state") as made:
                    assert type(built) is type(made.unwrapped)
                    np.testing.assert_array_equal(observation, made.reset(seed=1)[0])
        made_kinds.add(variation)
    assert {"background", "morphology", "DMCGB", "DMCGB2", "DCS"} <= made_kinds


def test_a_builder_refuses_another_kinds_kwargs_in_one_line():
    assert env_kwargs_of("DCS/walker-walk-v0")[:3] == ("split", "domain", "dynamic")
    assert "setting" in env_kwargs_of("SGFD/CW-pushing-v0") and "skip_frame" in env_kwargs_of("SGFD/CW-pushing-v0")
    with pytest.raises(ValueError, match=r"^DMCGB2/walker-walk-v0 does not take 'dynamic': DMCGB2 ids take split, "):
        gym.make("DMCGB2/walker-walk-v0", dynamic=True)
    with pytest.raises(ValueError, match=r"SGFD/CW-picking-v0 does not take 'image_size': causal world ids take"):
        gym.make("SGFD/CW-picking-v0", image_size=84)
