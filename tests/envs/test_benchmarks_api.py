"""The benchmark ids (DMCGB/, DMCGB2/, DCS/) as gymnasium ids: the table, the checkers, dm_control's own tasks and
rewards, and a distraction that never changes the task (same seed, same physics and rewards, in every split)."""

import math
import pickle
import warnings
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
from dm_control import suite
from gymnasium.utils.env_checker import check_env as gymnasium_check_env
from stable_baselines3.common.env_checker import check_env as sb3_check_env

import sgfd_envs
from sgfd_envs.builders import StandInWarning
from sgfd_envs.registry import task_entry

BENCHMARK_IDS = [env_id for ids in sgfd_envs.BENCHMARK_IDS.values() for env_id in ids]
# The hardest split of each benchmark, where every part of its distraction is on.
HARDEST = {"DMCGB": "video_hard", "DMCGB2": "color_video_hard", "DCS": "hard"}


def benchmark(env_id):
    return env_id.split("/")[0]


def test_the_ids_are_each_benchmarks_tasks_in_our_naming():
    assert sgfd_envs.BENCHMARK_IDS["DMCGB"] == (
        "DMCGB/walker-walk-v0",
        "DMCGB/walker-stand-v0",
        "DMCGB/cartpole-swingup-v0",
        "DMCGB/ball_in_cup-catch-v0",
        "DMCGB/finger-spin-v0",
    )
    assert sgfd_envs.BENCHMARK_IDS["DMCGB2"] == (
        "DMCGB2/walker-walk-v0",
        "DMCGB2/walker-stand-v0",
        "DMCGB2/cheetah-run-v0",
        "DMCGB2/finger-spin-v0",
        "DMCGB2/cartpole-swingup-v0",
        "DMCGB2/ball_in_cup-catch-v0",
    )
    assert sorted(sgfd_envs.BENCHMARK_IDS["DCS"]) == [
        "DCS/ball_in_cup-catch-v0",
        "DCS/cartpole-swingup-v0",
        "DCS/cheetah-run-v0",
        "DCS/finger-spin-v0",
        "DCS/reacher-easy-v0",
        "DCS/walker-walk-v0",
    ]
    assert len(sgfd_envs.SGFD_IDS) == 10 and all(i.startswith("SGFD/") for i in sgfd_envs.SGFD_IDS)
    every_id = (*sgfd_envs.SGFD_IDS, *sgfd_envs.CAUSAL_WORLD_IDS, *BENCHMARK_IDS)
    assert every_id == sgfd_envs.ENV_IDS
    for env_id in BENCHMARK_IDS:
        assert env_id in gym.registry


def test_splits_are_train_then_the_benchmarks_modes_with_one_domain_each():
    assert sgfd_envs.splits("DMCGB/walker-walk-v0") == ("train", "color_easy", "color_hard", "video_easy", "video_hard")
    assert sgfd_envs.splits("DMCGB2/cheetah-run-v0") == (
        "train",
        "rotate_easy",
        "rotate_hard",
        "shift_easy",
        "shift_hard",
        "rotate_shift_easy",
        "rotate_shift_hard",
        "color_easy",
        "color_hard",
        "video_easy",
        "video_hard",
        "color_video_easy",
        "color_video_hard",
    )
    assert sgfd_envs.splits("DCS/reacher-easy-v0") == ("train", "easy", "medium", "hard")
    # distracting_cs takes an intensity: evaluated once per intensity, named as DMC-GB2 names it.
    intensities = (0.025, 0.05, 0.1, 0.15, 0.2, 0.3, 0.4, 0.5)
    for env_id in ("DMCGB/walker-walk-v0", "DMCGB2/cheetah-run-v0"):
        modes = sgfd_envs.evaluation_modes(env_id)
        assert [label for label, _ in modes[: len(sgfd_envs.splits(env_id))]] == list(sgfd_envs.splits(env_id))
        assert modes[-8:] == tuple(
            (f"distracting_cs_{i:g}", {"split": "distracting_cs", "intensity": i}) for i in intensities
        )
        assert sgfd_envs.n_domains(env_id, "distracting_cs") == 1
    assert [label for label, _ in sgfd_envs.evaluation_modes("DCS/reacher-easy-v0")] == list(
        sgfd_envs.splits("DCS/reacher-easy-v0")
    )
    assert sgfd_envs.test_splits("DCS/reacher-easy-v0") == ("easy", "medium", "hard")
    for env_id in BENCHMARK_IDS:
        assert all(sgfd_envs.n_domains(env_id, split) == 1 for split in sgfd_envs.splits(env_id))
    with pytest.raises(ValueError, match=r"split must be one of \('train', 'easy', 'medium', 'hard'\) for DCS ids"):
        sgfd_envs.n_domains("DCS/reacher-easy-v0", "video_hard")


@pytest.mark.parametrize(
    ("env_id", "action_repeat"),
    [
        ("DMCGB/walker-walk-v0", 4),
        ("DMCGB/finger-spin-v0", 2),
        ("DMCGB/cartpole-swingup-v0", 4),
        ("DMCGB2/cartpole-swingup-v0", 2),
        ("DMCGB2/finger-spin-v0", 2),
        ("DCS/cartpole-swingup-v0", 8),
        ("DCS/walker-walk-v0", 2),
        ("DCS/reacher-easy-v0", 4),
    ],
)
def test_action_repeat_and_episode_length_in_agent_steps(env_id, action_repeat):
    assert task_entry(env_id).action_repeat == action_repeat
    assert gym.spec(env_id).max_episode_steps == math.ceil(1000 / action_repeat)
    with gym.make(env_id, obs_type="state") as env:
        assert env.unwrapped.action_repeat == action_repeat
        env.reset(seed=0)
        steps = 0
        truncated = terminated = False
        while not (terminated or truncated):
            *_, terminated, truncated, _ = env.step(env.action_space.sample())
            steps += 1
        # 1000 simulator steps per episode, the dm_control suite's, whatever the repeat.
        assert steps == 1000 // action_repeat and truncated and not terminated
        assert env.unwrapped.physics.data.time == pytest.approx(1000 * env.unwrapped._dm_env.control_timestep())


@pytest.mark.slow
@pytest.mark.parametrize("env_id", ["DMCGB/walker-walk-v0", "DMCGB2/cheetah-run-v0", "DCS/reacher-easy-v0"])
def test_gymnasium_and_sb3_checkers_pass_on_the_hardest_split(env_id):
    split = HARDEST[benchmark(env_id)]
    kwargs = {"dynamic": True} if benchmark(env_id) == "DCS" else {}
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        # The checkers look at spaces and types, not at pixels: the fast render is enough.
        with gym.make(env_id, split=split, image_size=24, render_mode="rgb_array", render="fast", **kwargs) as env:
            gymnasium_check_env(env.unwrapped)
        with gym.make(env_id, split=split, image_size=24, render="fast", **kwargs) as env:
            sb3_check_env(env, warn=True)
    # SB3 advises 36x36 and larger images for its CNN; these tiny ones keep the suite fast. The stand-in's warning
    # is meant.
    messages = [
        str(w.message)
        for w in caught
        if "minimal resolution" not in str(w.message) and not issubclass(w.category, StandInWarning)
    ]
    assert messages == []


@pytest.mark.slow
@pytest.mark.parametrize("obs_type", ["pixels", "state"])
def test_checkers_pass_with_either_observation(obs_type):
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        with gym.make(
            "DMCGB/ball_in_cup-catch-v0", split="color_hard", obs_type=obs_type, image_size=40, render="fast"
        ) as env:
            gymnasium_check_env(env.unwrapped)
            sb3_check_env(env, warn=True)
    messages = [
        str(w.message)
        for w in caught
        if "infinity" not in str(w.message) and not issubclass(w.category, StandInWarning)
    ]
    assert messages == []


def rollout(env_id, split, seed=3, n_steps=3, **kwargs):
    """Physics states, rewards, pixel observations (the fast render: only whether they differ matters) of a fixed
    action sequence."""
    with gym.make(env_id, split=split, image_size=16, render="fast", **kwargs) as env:
        observation, info = env.reset(seed=seed)
        physics = env.unwrapped.physics
        rng = np.random.default_rng(0)
        states, rewards, observations = [physics.get_state().copy()], [], [observation]
        for _ in range(n_steps):
            observation, reward, *_, info = env.step(rng.uniform(-1, 1, env.action_space.shape).astype(np.float32))
            states.append(physics.get_state().copy())
            rewards.append(reward)
            observations.append(observation)
        assert info["domain"] == 0
    return np.array(states), np.array(rewards), np.array(observations)


@pytest.mark.slow
@pytest.mark.parametrize("env_id", BENCHMARK_IDS)
def test_a_distraction_never_changes_the_task(env_id):
    """One seed gives the same physics and rewards in every split, while the pictures differ."""
    states, rewards, observations = rollout(env_id, "train")
    variants = [(split, {}) for split in sgfd_envs.test_splits(env_id)]
    if benchmark(env_id) == "DCS":
        variants += [(split, {"dynamic": True}) for split in sgfd_envs.test_splits(env_id)]
    if benchmark(env_id) in ("DMCGB", "DMCGB2"):
        variants += [("distracting_cs", {"intensity": 0.025}), ("distracting_cs", {"intensity": 0.5})]
    for split, kwargs in variants:
        split_states, split_rewards, split_observations = rollout(env_id, split, **kwargs)
        np.testing.assert_array_equal(split_states, states, err_msg=f"{split} {kwargs}")
        np.testing.assert_array_equal(split_rewards, rewards, err_msg=f"{split} {kwargs}")
        assert not np.array_equal(split_observations, observations), f"{split} {kwargs} shows the train picture"


# Every part of every benchmark's distraction, dynamic where DCS can be.
RESUMED = [
    ("DMCGB/walker-walk-v0", "color_hard", {}),
    ("DMCGB/finger-spin-v0", "video_hard", {}),
    ("DMCGB2/walker-walk-v0", "rotate_shift_hard", {}),
    ("DMCGB2/cheetah-run-v0", "color_video_hard", {}),
    ("DCS/walker-walk-v0", "hard", {"dynamic": True}),
    ("DCS/reacher-easy-v0", "medium", {"render": "fast"}),
    ("DMCGB/cartpole-swingup-v0", "distracting_cs", {"intensity": 0.2, "render": "fast"}),
    ("DMCGB2/finger-spin-v0", "distracting_cs", {"intensity": 0.5}),
]


@pytest.mark.parametrize(("env_id", "split", "kwargs"), RESUMED)
def test_an_env_restored_from_its_state_continues_as_the_unbroken_one_bit_for_bit(env_id, split, kwargs):
    """What a checkpoint holds of an env (``get_training_state``), set on a fresh env that has been elsewhere:
    the same pictures, rewards and episode ends from then on, across new episodes (6 steps each), whose colours,
    clips, camera poses and videos are drawn again."""

    def make(seed):
        return sgfd_envs.make_domain_vec_env(env_id, split, seed=seed, image_size=16, max_episode_steps=6, **kwargs)

    unbroken, restored = make(4), make(9)
    actions = np.random.default_rng(0).uniform(-1, 1, (24, 1, *unbroken.action_space.shape)).astype(np.float32)
    unbroken.reset()
    for action in actions[:8]:
        unbroken.step(action)
    state = pickle.loads(pickle.dumps(unbroken.env_method("get_training_state")))
    restored.reset()
    for action in actions[:3]:
        restored.step(action)
    restored.env_method("set_training_state", state[0], indices=[0])
    pictures = set()
    for step, action in enumerate(actions[8:]):
        expected, got = unbroken.step(action), restored.step(action)
        for name, a, b in zip(("observation", "reward", "done"), expected[:3], got[:3], strict=True):
            np.testing.assert_array_equal(b, a, err_msg=f"{name} at step {8 + step}")
        if expected[2][0]:
            terminal = [info["terminal_observation"] for info in (expected[3][0], got[3][0])]
            np.testing.assert_array_equal(terminal[1], terminal[0], err_msg=f"last picture at step {8 + step}")
        pictures.add(expected[0].tobytes())
    assert len(pictures) > 10  # the distraction moves: the comparison is of different pictures
    unbroken.close()
    restored.close()


# The tasks the SGFD ids did not have: their rewards must be dm_control's to the bit.
NEW_TASKS = [("cartpole", "swingup"), ("ball_in_cup", "catch"), ("reacher", "easy"), ("walker", "stand")]


@pytest.mark.parametrize(("domain", "task"), NEW_TASKS)
def test_rewards_and_states_equal_dm_control_suites(domain, task):
    env_id = next(i for i in BENCHMARK_IDS if f"/{domain}-{task}-" in i)
    repeat = task_entry(env_id).action_repeat
    # reset(seed=5) seeds the task with the first draw of gymnasium's np_random(5), numpy's default_rng(5).
    task_seed = int(np.random.default_rng(5).integers(2**31))
    reference = suite.load(domain, task, task_kwargs={"random": task_seed})
    rng = np.random.default_rng(1)
    with gym.make(env_id, obs_type="state") as env:
        observation, _ = env.reset(seed=5)
        physics = env.unwrapped.physics
        reference.reset()
        np.testing.assert_array_equal(physics.get_state(), reference.physics.get_state())
        for _ in range(30):
            action = rng.uniform(-1, 1, env.action_space.shape)
            observation, reward, *_ = env.step(action.astype(np.float32))
            expected = sum(reference.step(action.astype(np.float32)).reward for _ in range(repeat))
            assert reward == expected
        dm_observation = reference.task.get_observation(reference.physics)
        # Also the model: dm_control's, element for element.
        for field in ("body_mass", "geom_size", "dof_damping", "actuator_gear"):
            np.testing.assert_array_equal(getattr(physics.model, field), getattr(reference.physics.model, field))
    np.testing.assert_array_equal(
        observation, np.concatenate([np.ravel(v) for v in dm_observation.values()]).astype(np.float32)
    )


def test_the_benchmark_ids_work_with_make_domain_vec_env():
    venv = sgfd_envs.make_domain_vec_env("DMCGB2/finger-spin-v0", split="rotate_hard", image_size=24, seed=2)
    try:
        assert venv.num_envs == 1
        observations = venv.reset()
        assert observations.shape == (1, 24, 24, 3)
        _, _, _, infos = venv.step(np.zeros((1, 2), dtype=np.float32))
        assert infos[0]["domain"] == 0
        assert venv.envs[0].unwrapped.split == "rotate_hard"
    finally:
        venv.close()


@pytest.mark.parametrize(
    ("env_id", "kwargs", "error", "message"),
    [
        ("DMCGB/walker-walk-v0", {"split": "rotate_hard"}, ValueError, r"split must be one of \('train', 'color_easy'"),
        ("DMCGB/walker-walk-v0", {"domain": 1}, ValueError, r"domain must be an int in 0..0 for split 'train'"),
        ("DMCGB/walker-walk-v0", {"dynamic": True}, ValueError, r"does not take 'dynamic': DMCGB ids"),
        ("DMCGB/walker-walk-v0", {"split": "distracting_cs"}, ValueError, r"intensity must be one of \(0.025, 0.05,"),
        ("DMCGB/walker-walk-v0", {"split": "distracting_cs", "intensity": 0.33}, ValueError, r"got 0.33"),
        ("DMCGB2/walker-walk-v0", {"intensity": 0.1}, ValueError, r"intensity is for split='distracting_cs' only"),
        ("DCS/walker-walk-v0", {"intensity": 0.1}, ValueError, r"does not take 'intensity': DCS ids"),
        ("DMCGB/walker-walk-v0", {"render": "pretty"}, ValueError, r"render must be one of \('benchmark', 'fast'\)"),
        ("DMCGB/walker-walk-v0", {"data_dir": "/nowhere"}, FileNotFoundError, r"data_dir '/nowhere' is not an"),
        ("DMCGB2/walker-walk-v0", {"split": "hard"}, ValueError, r"split must be one of \('train', 'rotate_easy'"),
        ("DMCGB2/walker-walk-v0", {"image_size": 0}, ValueError, r"image_size must be a positive int"),
        ("DCS/walker-walk-v0", {"dynamic": "yes"}, ValueError, r"dynamic must be True or False, got 'yes'"),
        ("DCS/walker-walk-v0", {"distractions": ("blur",)}, ValueError, r"distractions must be a non-empty subset"),
        ("DCS/walker-walk-v0", {"distractions": ()}, ValueError, r"distractions must be a non-empty subset"),
        ("DCS/walker-walk-v0", {"background_videos": "val"}, ValueError, r"background_videos must be one of"),
        ("DCS/walker-walk-v0", {"data_dir": "/tmp"}, ValueError, r"does not take 'data_dir': DCS ids take"),
        ("DCS/walker-walk-v0", {"background_dir": "/nowhere"}, FileNotFoundError, r"background_dir '/nowhere'"),
        ("DCS/walker-walk-v0", {"obs_type": "rgb"}, ValueError, r"obs_type must be one of"),
    ],
)
def test_bad_arguments_are_refused_by_name(env_id, kwargs, error, message):
    with pytest.raises(error, match=message):
        gym.make(env_id, **kwargs)


@pytest.mark.slow
def test_the_demo_draws_every_task_of_a_benchmark_in_every_split():
    from sgfd_envs.demo import benchmark_grid

    grid = benchmark_grid("DCS", steps=1, image_size=16)
    # 6 tasks x 4 splits, each tile 168 px under a 34 px caption
    assert grid.shape == (6 * (34 + 168), 4 * 168, 3)
    with pytest.raises(ValueError, match="benchmark must be one of"):
        benchmark_grid("DMCGB3")


def test_a_stand_in_is_named_once_flagged_in_info_and_known_without_an_env(tmp_path, monkeypatch):
    from sgfd_envs import building

    monkeypatch.setattr(building, "_WARNED", set())
    assert sgfd_envs.stand_in("DMCGB/walker-walk-v0", "train") is None
    assert "data_dir=" in sgfd_envs.stand_in("DMCGB/walker-walk-v0", "video_hard")
    assert sgfd_envs.stand_in("DMCGB/walker-walk-v0", "video_hard", data_dir=tmp_path) is None
    assert "background_dir=" in sgfd_envs.stand_in("DMCGB2/walker-walk-v0", "distracting_cs", intensity=0.1)
    assert "background_dir=" in sgfd_envs.stand_in("DCS/walker-walk-v0", "easy")
    assert sgfd_envs.stand_in("DCS/walker-walk-v0", "easy", distractions=("camera",)) is None
    assert "Kinetics" in sgfd_envs.stand_in("SGFD/walker-walk-v0", "test")
    assert sgfd_envs.stand_in("SGFD/MT-walker-walk-v0", "extrapolation") is None
    with pytest.warns(StandInWarning, match=r"DMCGB2/finger-spin-v0 split='color_hard': .* give data_dir=") as caught:
        first = gym.make("DMCGB2/finger-spin-v0", split="color_hard", obs_type="state")
    assert [Path(warning.filename).name for warning in caught] == [Path(__file__).name]  # the user's line
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # once per process: the second env of that stand-in is quiet
        second = gym.make("DMCGB/walker-walk-v0", split="video_easy", obs_type="state")
        train = gym.make("DMCGB/walker-walk-v0", obs_type="state")
    for env, flagged in ((first, True), (second, True), (train, False)):
        _, info = env.reset(seed=0)
        assert info["stand_in"] is flagged
        assert env.step(env.action_space.sample())[-1]["stand_in"] is flagged
        env.close()
    with pytest.warns(StandInWarning) as caught:  # through SB3's vector env: still the line that asked for it
        sgfd_envs.make_domain_vec_env("DCS/walker-walk-v0", split="easy", obs_type="state").close()
    assert [Path(warning.filename).name for warning in caught] == [Path(__file__).name]
