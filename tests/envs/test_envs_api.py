"""sgfd_envs: registration, gymnasium/SB3 API conformance, episodes, seeding, labels, VecEnv helper."""

import os
import subprocess
import sys
import warnings

import gymnasium as gym
import mujoco
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env as gymnasium_check_env
from stable_baselines3.common.env_checker import check_env as sb3_check_env
from stable_baselines3.common.env_util import is_wrapped
from stable_baselines3.common.monitor import Monitor
from stable_baselines3.common.vec_env import DummyVecEnv, SubprocVecEnv

import sgfd_envs
from sgfd_envs import domains
from sgfd_envs.builders import (
    MorphologyWarning,
    StandInWarning,
    make_background_env,
    make_dmcgb_env,
    make_morphology_env,
)

BACKGROUND_IDS = [env_id for env_id in sgfd_envs.SGFD_IDS if "/MT-" not in env_id]
MT_IDS = [env_id for env_id in sgfd_envs.SGFD_IDS if "/MT-" in env_id]


@pytest.mark.parametrize(("preset", "expected"), [(None, "egl"), ("glfw", "glfw")])
def test_import_defaults_mujoco_gl_to_egl_and_respects_the_users_choice(preset, expected):
    environment = {key: value for key, value in os.environ.items() if key != "MUJOCO_GL"}
    if preset is not None:
        environment["MUJOCO_GL"] = preset
    # Importing sgfd_envs loads no dm_control; the dm_control loaded after it (by the first env made) takes the
    # backend it set (GLFW imports fine, it fails only at rendering).
    code = (
        "import sys, os, sgfd_envs; assert 'dm_control._render' not in sys.modules; "
        "from dm_control import _render; print(os.environ['MUJOCO_GL'], _render.BACKEND)"
    )
    result = subprocess.run([sys.executable, "-c", code], env=environment, capture_output=True, text=True, check=False)
    assert result.returncode == 0, result.stderr
    assert result.stdout.split() == [expected, expected]


def test_importing_dm_control_first_warns():
    environment = {key: value for key, value in os.environ.items() if key != "MUJOCO_GL"}
    code = "import dm_control.suite, sgfd_envs"
    result = subprocess.run(
        [sys.executable, "-W", "always", "-c", code], env=environment, capture_output=True, text=True, check=False
    )
    assert "Import sgfd_envs first or set MUJOCO_GL=egl" in result.stderr


def test_import_registers_the_ten_ids():
    assert len(sgfd_envs.SGFD_IDS) == 10
    assert len(BACKGROUND_IDS) == len(MT_IDS) == 5
    for env_id in sgfd_envs.SGFD_IDS:
        spec = gym.spec(env_id)
        assert spec.max_episode_steps == 500


@pytest.mark.parametrize("env_id", sgfd_envs.SGFD_IDS)
def test_default_make_is_training_domain_zero_in_pixels(env_id):
    with gym.make(env_id) as env:
        observation, info = env.reset(seed=0)
        assert observation.shape == (84, 84, 3) and observation.dtype == np.uint8
        assert env.observation_space.contains(observation)
        assert info["domain"] == 0
        unwrapped = env.unwrapped
        assert (unwrapped.split, unwrapped.domain, unwrapped.n_domains) == ("train", 0, 4)
        assert unwrapped.action_space.dtype == np.float32
        assert np.all(unwrapped.action_space.low == -1) and np.all(unwrapped.action_space.high == 1)


@pytest.mark.parametrize("env_id", sgfd_envs.SGFD_IDS)
@pytest.mark.parametrize("obs_type", ["pixels", "state"])
def test_gymnasium_and_sb3_checkers_pass_without_warnings(env_id, obs_type):
    # The checkers look at spaces and types, not at pixels: the fast render is enough.
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        with gym.make(env_id, obs_type=obs_type, render_mode="rgb_array", render="fast") as env:
            gymnasium_check_env(env.unwrapped)
        with gym.make(env_id, obs_type=obs_type, render="fast") as env:
            sb3_check_env(env, warn=True)
    # The warnings that are meant: the procedural backgrounds stand in for the paper's images; HiP-BMDP's finger
    # files change nothing the agent sees.
    meant = (StandInWarning, MorphologyWarning)
    messages = [str(warning.message) for warning in caught if not issubclass(warning.category, meant)]
    if obs_type == "state":
        # dm_control's state specs are unbounded; gymnasium flags any infinite Box bound.
        messages = [m for m in messages if "infinity" not in m]
    assert messages == []


def test_state_observation_is_dm_control_observation_flattened_in_order():
    with gym.make("SGFD/MT-finger-turn-v0", obs_type="state") as env:
        observation, _ = env.reset(seed=1)
        dm_observation = env.unwrapped._dm_env.task.get_observation(env.unwrapped.physics)
    expected = np.concatenate([np.ravel(value) for value in dm_observation.values()]).astype(np.float32)
    assert observation.dtype == np.float32
    assert observation.shape == (12,)  # position 4, velocity 3, touch 2, target 2, distance 1
    np.testing.assert_array_equal(observation, expected)


@pytest.mark.parametrize("env_id", ["SGFD/MT-walker-walk-v0", "SGFD/cheetah-run-v0"])
def test_episode_is_1000_control_steps_ending_in_truncation(env_id):
    with gym.make(env_id, obs_type="state") as env:
        env.reset(seed=0)
        control_timestep = env.unwrapped._dm_env.control_timestep()
        for step in range(1, 501):
            _, _, terminated, truncated, _ = env.step(env.action_space.sample())
            assert not terminated
            assert truncated == (step == 500)
        assert env.unwrapped.physics.data.time == pytest.approx(1000 * control_timestep, rel=1e-9)


def test_step_reward_is_the_sum_over_the_action_repeat():
    action = np.full(6, 0.3, dtype=np.float32)
    with gym.make("SGFD/walker-walk-v0", obs_type="state") as env:
        env.reset(seed=4)
        for _ in range(20):
            env.step(action)
        reference = domains.load("walker", "walk")
        reference.reset()
        physics = env.unwrapped.physics
        # Copy all of MjData (solver warm start included), not just qpos/qvel, for an exact replay.
        mujoco.mj_copyData(reference.physics.data.ptr, physics.model.ptr, physics.data.ptr)
        _, reward, *_ = env.step(action)
    expected = sum(reference.step(action).reward for _ in range(2))
    assert reward == pytest.approx(expected, rel=1e-12)
    assert reward > 0


def rollout(env, seed, n_steps):
    observation, _ = env.reset(seed=seed)
    observations, rewards = [observation], []
    rng = np.random.default_rng(123)
    for _ in range(n_steps):
        observation, reward, *_ = env.step(rng.uniform(-1, 1, env.action_space.shape).astype(np.float32))
        observations.append(observation)
        rewards.append(reward)
    return np.stack(observations), np.array(rewards)


@pytest.mark.parametrize("env_id", ["SGFD/walker-walk-v0", "SGFD/MT-cheetah-run-v0", "SGFD/finger-spin-v0"])
def test_reset_seed_reproduces_the_episode(env_id):
    with gym.make(env_id, image_size=48) as first, gym.make(env_id, image_size=48) as second:
        observations, rewards = rollout(first, seed=7, n_steps=15)
        again_observations, again_rewards = rollout(second, seed=7, n_steps=15)
        other_observations, _ = rollout(second, seed=8, n_steps=15)
    np.testing.assert_array_equal(observations, again_observations)
    np.testing.assert_array_equal(rewards, again_rewards)
    assert not np.array_equal(observations[0], other_observations[0])


def test_render_returns_the_current_frame():
    with gym.make("SGFD/walker-run-v0", render_mode="rgb_array", image_size=64) as env:
        env.reset(seed=0)
        observation, *_ = env.step(env.action_space.sample())
        np.testing.assert_array_equal(env.render(), observation)
    with gym.make("SGFD/MT-walker-run-v0", obs_type="state", render_mode="rgb_array", image_size=64) as env:
        env.reset(seed=0)
        frame = env.render()
        assert frame.shape == (64, 64, 3) and frame.dtype == np.uint8 and frame.std() > 0


@pytest.mark.parametrize("env_id", sgfd_envs.SGFD_IDS)
def test_info_carries_the_domain_label_at_reset_and_every_step(env_id):
    for split in sgfd_envs.splits(env_id):
        count = sgfd_envs.n_domains(env_id, split)
        domain = count - 1
        with gym.make(env_id, split=split, domain=domain, obs_type="state") as env:
            _, info = env.reset(seed=0)
            infos = [info] + [env.step(env.action_space.sample())[-1] for _ in range(3)]
            assert env.unwrapped.split == split and env.unwrapped.n_domains == count
        assert [info["domain"] for info in infos] == [domain] * 4
        if env_id in MT_IDS:
            assert {info["setting"] for info in infos} == {env.unwrapped.setting}
        else:
            assert all("setting" not in info for info in infos)


def test_splits_and_domain_counts():
    assert sgfd_envs.splits("SGFD/walker-walk-v0") == ("train", "test")
    assert sgfd_envs.test_splits("SGFD/walker-walk-v0") == ("test",)
    assert sgfd_envs.splits("SGFD/MT-walker-walk-v0") == ("train", "interpolation", "extrapolation")
    assert sgfd_envs.test_splits("SGFD/MT-finger-spin-v0") == ("interpolation", "extrapolation")
    assert sgfd_envs.n_domains("SGFD/walker-walk-v0") == 4
    assert sgfd_envs.n_domains("SGFD/walker-walk-v0", "test") == 1  # the paper's one unseen background
    assert sgfd_envs.n_domains("SGFD/walker-walk-v0", "test", test_domains=4) == 4
    assert [sgfd_envs.n_domains("SGFD/MT-cheetah-run-v0", s) for s in ("train", "interpolation", "extrapolation")] == [
        4,
        1,
        1,
    ]
    assert sgfd_envs.n_domains("SGFD/MT-cheetah-run-v0", split_settings={"train": (1, 2, 3)}) == 3
    assert sgfd_envs.n_domains("SGFD/MT-cheetah-run-v0", robots="scaled") == 4
    with pytest.raises(ValueError, match=r"robots must be one of \('hipbmdp', 'scaled'\) for MT ids, got 'big'"):
        sgfd_envs.n_domains("SGFD/MT-cheetah-run-v0", robots="big")


@pytest.mark.parametrize(
    "helper", [sgfd_envs.splits, sgfd_envs.test_splits, sgfd_envs.n_domains, sgfd_envs.make_domain_vec_env]
)
def test_helpers_reject_unknown_ids_listing_the_known_ones(helper):
    with pytest.raises(ValueError, match=r"env_id must be one of .*SGFD/MT-walker-walk-v0.*'walker-walk'"):
        helper("walker-walk")


def test_make_domain_vec_env_suggests_the_closest_id():
    with pytest.raises(ValueError, match=r"got 'SGFD/MT-walker-wlk-v0' \(did you mean SGFD/MT-walker-walk-v0\?\)$"):
        sgfd_envs.make_domain_vec_env("SGFD/MT-walker-wlk-v0")


def test_make_domain_vec_env_gives_one_monitored_sub_env_per_domain():
    venv = sgfd_envs.make_domain_vec_env("SGFD/MT-walker-walk-v0", obs_type="state")
    try:
        assert isinstance(venv, DummyVecEnv) and venv.num_envs == 4
        assert all(is_wrapped(env, Monitor) for env in venv.envs)
        assert [env.unwrapped.setting for env in venv.envs] == [2, 3, 5, 6]  # HiP-BMDP's files, the authors' split
        venv.reset()
        _, _, _, infos = venv.step(np.zeros((4, 6), dtype=np.float32))
        assert [info["domain"] for info in infos] == [0, 1, 2, 3]
        assert [info["setting"] for info in infos] == [2, 3, 5, 6]
    finally:
        venv.close()


def test_make_domain_vec_env_seeds_sub_env_i_with_seed_plus_i():
    def first_observations(seed):
        venv = sgfd_envs.make_domain_vec_env(
            "SGFD/finger-spin-v0", split="test", n_envs=6, seed=seed, obs_type="state", test_domains=4
        )
        try:
            observations = venv.reset()
            return observations, [env.unwrapped.domain for env in venv.envs], venv.envs[1].action_space.sample()
        finally:
            venv.close()

    observations, domains_of_envs, action = first_observations(seed=3)
    assert domains_of_envs == [0, 1, 2, 3, 0, 1]
    again, _, again_action = first_observations(seed=3)
    np.testing.assert_array_equal(observations, again)
    np.testing.assert_array_equal(action, again_action)
    shifted, _, shifted_action = first_observations(seed=4)
    # State observations do not show the background, so only the seed decides them.
    np.testing.assert_array_equal(observations[1], shifted[0])
    assert not np.array_equal(observations[0], shifted[0])
    assert not np.array_equal(action, shifted_action)


def test_make_domain_vec_env_works_with_subprocesses():
    venv = sgfd_envs.make_domain_vec_env(
        "SGFD/cheetah-run-v0", split="train", n_envs=2, vec_env_cls=SubprocVecEnv, image_size=32
    )
    try:
        observations = venv.reset()
        assert observations.shape == (2, 32, 32, 3)
        _, _, _, infos = venv.step(np.zeros((2, 6), dtype=np.float32))
        assert [info["domain"] for info in infos] == [0, 1]
    finally:
        venv.close()


def test_make_domain_vec_env_rejects_bad_arguments():
    with pytest.raises(ValueError, match="split must be one of"):
        sgfd_envs.make_domain_vec_env("SGFD/walker-walk-v0", split="interpolation")
    with pytest.raises(ValueError, match="n_envs must be a positive int"):
        sgfd_envs.make_domain_vec_env("SGFD/walker-walk-v0", n_envs=0)
    with pytest.raises(ValueError, match="sets domain= itself"):
        sgfd_envs.make_domain_vec_env("SGFD/walker-walk-v0", domain=1)


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"split": "val"}, r"split must be one of \('train', 'test'\)"),
        ({"domain": 4}, r"domain must be an int in 0..3 for split 'train', got 4"),
        ({"domain": -1}, r"domain must be an int in 0..3"),
        ({"split": "test", "domain": 1}, r"domain must be an int in 0..0 for split 'test', got 1"),
        ({"split": "train", "domain": 1.0}, r"domain must be an int in 0..3 for split 'train'"),
        ({"backgrounds": "video"}, r"backgrounds must be one of \('still', 'moving'\) for background ids"),
        ({"compositing": "depth"}, r"compositing must be one of \('colour_key', 'matte'\)"),
        ({"background_channels": "BGR"}, r"background_channels must be one of \('bgr', 'rgb'\)"),
        ({"robots": "scaled"}, r"robots must be one of \('hipbmdp', 'dm_control'\) for background ids"),
        ({"test_domains": 5}, r"test_domains must be None or an int in 1..4, got 5"),
        ({"test_domains": 0}, r"test_domains must be None or an int in 1..4, got 0"),
        ({"obs_type": "rgb"}, r"obs_type must be one of \('pixels', 'state'\)"),
        ({"image_size": 0}, r"image_size must be a positive int"),
        ({"image_size": 32.5}, r"image_size must be a positive int, got 32.5"),
        ({"frame_budget": 0}, r"frame_budget must be a positive int"),
    ],
)
def test_background_ids_reject_bad_arguments(kwargs, message):
    with pytest.raises(ValueError, match=message):
        gym.make("SGFD/walker-walk-v0", **kwargs)


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"split": "test"}, r"split must be one of \('train', 'interpolation', 'extrapolation'\)"),
        ({"split": "extrapolation", "domain": 1}, r"domain must be an int in 0..0 for split 'extrapolation'"),
        ({"setting": 0}, r"setting must be an int in 1..10, got 0"),
        ({"setting": 11}, r"setting must be an int in 1..10, got 11"),
        ({"setting": "3"}, r"setting must be an int in 1..10, got '3'"),
        ({"setting": 3, "split": "train"}, r"either setting= or split=/domain="),
        ({"split_settings": {"test": (1,)}}, r"split_settings: unknown split 'test'"),
        ({"split_settings": {"train": ()}}, r"split_settings\['train'\] must be a non-empty sequence"),
        ({"split_settings": {"train": (1, 12)}}, r"setting must be an int in 1..10, got 12"),
        ({"split_settings": {"train": (1, 1)}}, r"repeats a setting"),
        ({"robots": "dm_control"}, r"robots must be one of \('hipbmdp', 'scaled'\) for MT ids"),
        ({"frame_lag": 2}, r"frame_lag must be True or False, got 2"),
    ],
)
def test_mt_ids_reject_bad_arguments(kwargs, message):
    with pytest.raises(ValueError, match=message):
        gym.make("SGFD/MT-walker-walk-v0", **kwargs)


def test_entry_points_refuse_ids_of_the_other_kind():
    with pytest.raises(ValueError, match=r"env_id must be a background id, one of \('SGFD/walker-walk-v0'"):
        make_background_env("SGFD/MT-walker-walk-v0")
    with pytest.raises(ValueError, match=r"env_id must be a morphology id, one of \('SGFD/MT-walker-walk-v0'"):
        make_morphology_env("SGFD/walker-walk-v0")
    # the one builder of both DMC-GB benchmarks names the ids of both, and of nothing else
    with pytest.raises(ValueError, match=r"env_id must be a DMCGB or DMCGB2 id, one of \('DMCGB/") as refused:
        make_dmcgb_env("DCS/walker-walk-v0")
    listed = str(refused.value).split(", got ")[0]
    assert "'DMCGB2/walker-walk-v0'" in listed and "'DCS/" not in listed


def test_variation_specific_kwargs_are_refused_by_the_other_kind():
    with pytest.raises(ValueError, match=r"SGFD/walker-walk-v0 does not take 'setting': background ids take split, "):
        gym.make("SGFD/walker-walk-v0", setting=3)
    with pytest.raises(ValueError, match=r"does not take 'background_dir': morphology ids take .*observe_parameter"):
        gym.make("SGFD/MT-walker-walk-v0", background_dir="/tmp")
    with pytest.raises(ValueError, match="does not take 'observe_parameter'"):
        gym.make("SGFD/cheetah-run-v0", observe_parameter=True)


@pytest.mark.parametrize("action", [[float("nan")] * 6, [0.0] * 5, [0.0, float("inf"), 0, 0, 0, 0]])
def test_a_non_finite_or_misshapen_action_is_refused_by_name(action):
    env = gym.make("SGFD/MT-walker-walk-v0", obs_type="state")
    env.reset(seed=0)
    with pytest.raises(ValueError, match=r"action must be a finite array of shape \(6,\)"):
        env.unwrapped.step(np.asarray(action, dtype=np.float32))
    env.close()


def test_observe_parameter_appends_the_scaled_parameter_and_only_on_states():
    values = {}
    for setting in (1, 3, 10):
        env = gym.make("SGFD/MT-walker-walk-v0", setting=setting, obs_type="state", observe_parameter=True)
        plain = gym.make("SGFD/MT-walker-walk-v0", setting=setting, obs_type="state")
        obs, _ = env.reset(seed=1)
        plain_obs, _ = plain.reset(seed=1)
        assert env.observation_space.shape == (plain.observation_space.shape[0] + 1,)
        assert env.observation_space.contains(obs)
        np.testing.assert_array_equal(obs[:-1], plain_obs)
        step_obs, *_ = env.step(np.zeros(6, dtype=np.float32))
        assert step_obs[-1] == obs[-1]  # constant within the episode
        values[setting] = float(obs[-1])
        env.close()
        plain.close()
    # HiP-BMDP's left foot: half-length 0.08 m in file 1, 0.1 m (dm_control's) in file 3, 0.17 m in file 10
    assert values[1] == pytest.approx(-1.0) and values[10] == pytest.approx(1.0)
    assert values[3] == pytest.approx(2 * (0.1 - 0.08) / (0.17 - 0.08) - 1, abs=1e-6)
    with pytest.raises(ValueError, match="observe_parameter=True needs obs_type='state'"):
        gym.make("SGFD/MT-walker-walk-v0", observe_parameter=True)
    with pytest.raises(ValueError, match="observe_parameter must be True or False"):
        gym.make("SGFD/MT-walker-walk-v0", obs_type="state", observe_parameter="yes")


def test_observe_parameter_gives_each_training_domain_its_own_value_in_a_vec_env():
    venv = sgfd_envs.make_domain_vec_env("SGFD/MT-cheetah-run-v0", obs_type="state", observe_parameter=True)
    try:
        obs = venv.reset()
        assert venv.get_attr("setting") == [2, 3, 5, 6]
        assert np.all(np.diff(obs[:, -1]) > 0) and np.all(np.abs(obs[:, -1]) <= 1)
    finally:
        venv.close()


def test_make_domain_vec_env_without_stable_baselines3_says_how_to_install_it(monkeypatch):
    # An environments-only install has no SB3: None in sys.modules makes its import fail as a missing one does.
    monkeypatch.setitem(sys.modules, "stable_baselines3.common", None)
    monkeypatch.setitem(sys.modules, "stable_baselines3.common.vec_env", None)
    with pytest.raises(
        ModuleNotFoundError, match=r"make_domain_vec_env needs stable-baselines3 .*: pip install stable-baselines3, or"
    ) as error:
        sgfd_envs.make_domain_vec_env("SGFD/MT-walker-walk-v0", obs_type="state")
    assert "sb3-sgfd" not in str(error.value)  # a name no package index has
