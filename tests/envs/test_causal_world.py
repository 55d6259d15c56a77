"""The Causal World ids (optional extra: pip install -e ".[causalworld]"): one block property per domain."""

from __future__ import annotations

import importlib.util
import json

import gymnasium as gym
import numpy as np
import pytest

import sgfd_envs
from sgfd_envs.causal_world import STATE_NAMES, VARIATIONS

CW_IDS = sgfd_envs.CAUSAL_WORLD_IDS


def test_ids_are_registered_with_the_mt_splits_without_causal_world():
    # Registration and the split table need no Causal World install.
    assert CW_IDS == ("SGFD/CW-picking-v0", "SGFD/CW-pushing-v0")
    for env_id in CW_IDS:
        assert env_id in gym.registry and env_id not in sgfd_envs.SGFD_IDS
        assert sgfd_envs.splits(env_id) == ("train", "interpolation", "extrapolation")
        assert [sgfd_envs.n_domains(env_id, split) for split in sgfd_envs.splits(env_id)] == [4, 1, 1]


def test_settings_span_causal_worlds_ranges():
    mass, size = VARIATIONS["picking"], VARIATIONS["pushing"]
    assert (mass.value(1), mass.value(10)) == (0.015, 0.1) and (size.value(1), size.value(10)) == (0.055, 0.095)
    assert np.all(np.diff([mass.value(s) for s in range(1, 11)]) > 0)
    np.testing.assert_array_equal(size.intervention(10)["tool_block"]["size"], [0.095] * 3)
    with pytest.raises(ValueError, match=r"setting must be an int in 1\.\.10"):
        mass.value(11)


@pytest.mark.skipif(importlib.util.find_spec("causal_world") is not None, reason="Causal World is installed")
def test_without_the_extra_making_an_id_names_the_install_command():
    with pytest.raises(ImportError, match=r'pip install -e "\.\[causalworld\]"'):
        gym.make("SGFD/CW-picking-v0")


@pytest.fixture(scope="module")
def causal_world():
    return pytest.importorskip("causal_world")


@pytest.mark.parametrize(("env_id", "task"), [("SGFD/CW-picking-v0", "picking"), ("SGFD/CW-pushing-v0", "pushing")])
def test_each_domain_sets_its_property_and_labels_its_steps(causal_world, env_id, task):
    variation = VARIATIONS[task]
    for split, domain, setting in (("train", 1, 2), ("extrapolation", 0, 10)):
        env = gym.make(env_id, split=split, domain=domain)
        try:
            unwrapped = env.unwrapped
            assert (unwrapped.split, unwrapped.domain, unwrapped.setting) == (split, domain, setting)
            assert unwrapped.varied_parameter == variation.parameter
            assert unwrapped.varied_value == variation.value(setting)
            assert env.observation_space.shape == (len(STATE_NAMES),) and env.observation_space.dtype == np.float32
            obs, info = env.reset(seed=0)
            assert info["domain"] == domain and obs.dtype == np.float32 and env.observation_space.contains(obs)
            # The simulator holds the domain's value, also after a reset (Causal World resets to its start state).
            stage = unwrapped.world._stage
            held = stage.get_object_state("tool_block", variation.variable)
            np.testing.assert_allclose(held, variation.value(setting))
            obs, reward, terminated, _, info = env.step(env.action_space.sample())
            assert info["domain"] == domain and np.isfinite(reward) and not terminated
        finally:
            env.close()


def test_size_shows_in_the_observation_and_episodes_truncate(causal_world):
    small = gym.make("SGFD/CW-pushing-v0", setting=1)
    large = gym.make("SGFD/CW-pushing-v0", setting=10)
    try:
        index = STATE_NAMES.index("tool_block_size[0]")
        assert small.reset(seed=0)[0][index] < large.reset(seed=0)[0][index]
        steps, truncated = 0, False
        while not truncated:
            _, _, terminated, truncated, _ = small.step(small.action_space.sample())
            assert not terminated
            steps += 1
            assert steps < 1000, "Causal World's time limit never came"
    finally:
        small.close()
        large.close()


def test_same_seed_same_states(causal_world):
    rollouts = []
    for _ in range(2):
        env = gym.make("SGFD/CW-picking-v0", domain=0)
        env.action_space.seed(5)
        states = [env.reset(seed=5)[0]]
        states += [env.step(env.action_space.sample())[0] for _ in range(20)]
        env.close()
        rollouts.append(np.array(states))
    np.testing.assert_array_equal(rollouts[0], rollouts[1])


def test_correlation_study_runs_on_causal_world(causal_world, tmp_path, capsys):
    from sgfd_cli import main as zoo_main

    out = tmp_path / "cw"
    assert (
        zoo_main(["correlation-study", "--env", "SGFD/CW-picking-v0", "--out", str(out), "--steps-per-domain", "128"])
        == 0
    )
    document = json.loads((out / "correlation.json").read_text())
    assert document["changed_feature"] == "s10 tool_block_mass"
    assert document["features"][3] == "s4 tool_block_cartesian_position[0]"
    assert document["n_batches"] == 4 and set(document["goals"]) == {
        "sgfd_below_global_below_raw",
        "sgfd_at_most_0.65_of_raw",
        "sgfd_ess_at_least_0.5_n",
    }
    for key in ("raw", "global", "sgfd"):
        assert 0 <= document[key]["mean_abs_corr"] <= 1 and 0 < document[key]["ess"] <= 1
    assert (out / "correlation.png").stat().st_size > 10_000
    assert "tool_block_mass" in capsys.readouterr().out


def test_observe_parameter_appends_the_scaled_block_property(causal_world):
    for setting, expected in ((1, -1.0), (10, 1.0)):
        env = gym.make("SGFD/CW-picking-v0", setting=setting, observe_parameter=True)
        try:
            obs, _ = env.reset(seed=0)
            assert env.observation_space.shape == (len(STATE_NAMES) + 1,)
            assert obs[-1] == pytest.approx(expected)
            assert env.step(env.action_space.sample())[0][-1] == pytest.approx(expected)
        finally:
            env.close()
