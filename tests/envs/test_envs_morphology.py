"""sgfd_envs MT ids, the package's own family of scaled robots (``robots="scaled"``): the ten morphology settings
change what the camera sees and the physics, and every robot stays a sane, simulable robot whose task can still be
done. HiP-BMDP's robots, the MT ids' default: tests/envs/test_paper_tasks.py."""

# First: importing sgfd_envs picks MuJoCo's headless OpenGL backend, which must precede dm_control.
import sgfd_envs  # noqa: F401

# isort: split

import itertools

import gymnasium as gym
import mujoco
import numpy as np
import pytest
from dm_control import suite
from dm_control.suite import walker as dm_walker

from sgfd_envs import domains
from sgfd_envs.domains import walker
from sgfd_envs.morphology import PACKAGE_SPLIT_SETTINGS, SETTINGS

ROBOT_TASKS = [("walker", "walk"), ("walker", "run"), ("cheetah", "run"), ("finger", "spin"), ("finger", "turn")]
# The body whose mass the varied length changes, per robot.
VARIED_BODY = {"walker": "torso", "cheetah": "torso", "finger": "distal"}
MT_ID = {"walker": "SGFD/MT-walker-walk-v0", "cheetah": "SGFD/MT-cheetah-run-v0", "finger": "SGFD/MT-finger-spin-v0"}


def scale(robot, setting):
    return domains.morphology(robot).scale(setting)


def test_settings_table():
    assert PACKAGE_SPLIT_SETTINGS == {"train": (1, 2, 4, 5), "interpolation": (3,), "extrapolation": (10,)}
    expected = {
        "walker": ("torso_length", [0.48, 0.54, 0.6, 0.66, 0.72, 0.78, 0.84, 0.9, 0.96, 1.02]),
        "cheetah": ("torso_length", [0.8, 0.9, 1.0, 1.1, 1.2, 1.3, 1.4, 1.5, 1.6, 1.7]),
        "finger": ("distal_length", [0.136, 0.148, 0.16, 0.172, 0.184, 0.196, 0.208, 0.22, 0.232, 0.244]),
    }
    for robot, (parameter, values) in expected.items():
        morphology = domains.morphology(robot)
        assert morphology.parameter == parameter
        assert [morphology.value(k) for k in SETTINGS] == pytest.approx(values, abs=1e-9)
        assert morphology.scale(3) == 1.0


@pytest.mark.parametrize(
    ("split", "domain", "setting"),
    [
        ("train", 0, 1),
        ("train", 1, 2),
        ("train", 2, 4),
        ("train", 3, 5),
        ("interpolation", 0, 3),
        ("extrapolation", 0, 10),
    ],
)
def test_split_and_domain_pick_the_setting_and_label_the_env(split, domain, setting):
    with gym.make("SGFD/MT-finger-turn-v0", split=split, domain=domain, obs_type="state", robots="scaled") as env:
        _, info = env.reset(seed=0)
        unwrapped = env.unwrapped
        assert (unwrapped.split, unwrapped.domain, unwrapped.setting) == (split, domain, setting)
        assert info == {"domain": domain, "setting": setting, "stand_in": False}
        assert unwrapped.morphology_parameter == "distal_length"
        assert unwrapped.morphology_value == pytest.approx(0.16 * scale("finger", setting))
        # A capsule's compiled size is (radius, half length).
        assert 2 * unwrapped.physics.named.model.geom_size["distal", 1] == pytest.approx(unwrapped.morphology_value)


def test_setting_kwarg_and_split_override():
    with gym.make("SGFD/MT-cheetah-run-v0", setting=7, obs_type="state") as env:
        unwrapped = env.unwrapped
        assert (unwrapped.setting, unwrapped.split, unwrapped.domain, unwrapped.n_domains) == (7, None, 0, 1)
        assert env.reset(seed=0)[1] == {"domain": 0, "setting": 7, "stand_in": False}
    with gym.make("SGFD/MT-cheetah-run-v0", domain=2, split_settings={"train": (6, 7, 8)}, obs_type="state") as env:
        assert (env.unwrapped.setting, env.unwrapped.n_domains) == (8, 3)
    with gym.make(
        "SGFD/MT-cheetah-run-v0", split="extrapolation", split_settings={"train": (6, 7, 8)}, obs_type="state"
    ) as env:
        assert env.unwrapped.setting == 10  # splits left out of split_settings keep their defaults


@pytest.mark.parametrize(("robot", "task"), ROBOT_TASKS)
def test_setting_three_is_the_unmodified_dm_control_robot(robot, task):
    ours = domains.load(robot, task, scale(robot, 3)).physics.model.ptr
    reference = suite.load(robot, "turn_easy" if task == "turn" else task).physics.model.ptr
    compared = 0
    for field in dir(reference):
        value = getattr(reference, field)
        if not field.startswith("_") and isinstance(value, np.ndarray) and value.dtype.kind in "fiu":
            np.testing.assert_allclose(getattr(ours, field), value, rtol=1e-12, atol=1e-12, err_msg=field)
            compared += 1
    assert compared > 100


@pytest.mark.parametrize("robot", ["walker", "cheetah", "finger"])
def test_every_setting_changes_mass_inertia_kinematics_and_dynamics(robot):
    task = "spin" if robot == "finger" else "run"
    physics_by_setting = [domains.load(robot, task, scale(robot, k)).physics for k in SETTINGS]
    body = VARIED_BODY[robot]
    masses = [physics.named.model.body_mass[body] for physics in physics_by_setting]
    assert np.all(np.diff(masses) > 0), masses
    accelerations = []
    for physics in physics_by_setting:
        # The same joint configuration, velocity and control for every setting.
        with physics.reset_context():
            physics.data.qpos[:] = physics.model.qpos0 + 0.1
            physics.data.qvel[:] = 0.5
        physics.data.ctrl[:] = 0.5
        mujoco.mj_forward(physics.model.ptr, physics.data.ptr)
        accelerations.append(physics.data.qacc.copy())
    for first, second in itertools.pairwise(range(len(SETTINGS))):
        a, b = physics_by_setting[first].model, physics_by_setting[second].model
        assert not np.allclose(a.body_inertia, b.body_inertia)
        assert not (np.allclose(a.body_pos, b.body_pos) and np.allclose(a.geom_pos, b.geom_pos))
        assert not np.allclose(accelerations[first], accelerations[second])


@pytest.mark.parametrize("robot", ["walker", "cheetah", "finger"])
def test_every_setting_changes_what_the_camera_sees(robot):
    frames = []
    for setting in SETTINGS:
        with gym.make(
            MT_ID[robot], setting=setting, obs_type="state", render_mode="rgb_array", image_size=48, robots="scaled"
        ) as env:
            env.reset(seed=0)
            physics = env.unwrapped.physics
            with physics.reset_context():
                physics.data.qpos[:] = physics.model.qpos0
                if robot == "finger":
                    # Point the finger down, clear of the spinner, which would hide a longer tip.
                    physics.named.data.qpos["proximal"] = -1.0
            frames.append(env.render())
    for first, second in itertools.combinations(range(len(SETTINGS)), 2):
        assert not np.array_equal(frames[first], frames[second]), (first + 1, second + 1)


@pytest.mark.parametrize(("robot", "task"), ROBOT_TASKS)
def test_every_setting_simulates_stably_under_random_actions(robot, task):
    rng = np.random.default_rng(0)
    for setting in SETTINGS:
        env = domains.load(robot, task, scale(robot, setting))
        env.task.random.seed(setting)
        env.reset()
        low, high = env.action_spec().minimum, env.action_spec().maximum
        for _ in range(100):
            reward = env.step(rng.uniform(low, high)).reward
            assert 0.0 <= reward <= 1.0
        assert np.all(np.isfinite(env.physics.state()))
        assert np.all(np.abs(env.physics.data.qvel) < 1e3)


@pytest.mark.parametrize("setting", SETTINGS)
def test_walker_standing_pose_touches_the_floor_and_earns_the_stand_height(setting):
    walker_scale = scale("walker", setting)
    env = domains.load("walker", "walk", walker_scale)
    physics = env.physics
    with physics.reset_context():
        physics.data.qpos[:] = 0  # joints straight at the torso's initial height
    foot_bottoms = [
        physics.named.data.geom_xpos[foot, "z"] - physics.named.model.geom_size[foot, 0]
        for foot in ("right_foot", "left_foot")
    ]
    assert foot_bottoms == pytest.approx([0.0, 0.0], abs=1e-9)
    # Same 0.1 m slack below the standing torso height as dm_control's 1.3 m walker with its 1.2 threshold.
    assert physics.torso_height() - walker.stand_height(walker_scale) == pytest.approx(0.1)
    assert walker.stand_height(1.0) == pytest.approx(1.2)


def test_walker_reward_equals_dm_controls_for_the_unmodified_robot():
    ours = domains.load("walker", "run", 1.0)
    reference = dm_walker.PlanarWalker(move_speed=8)
    ours.task.random.seed(0)
    ours.reset()
    rng = np.random.default_rng(0)
    for _ in range(30):
        time_step = ours.step(rng.uniform(-1, 1, 6))
        assert time_step.reward == pytest.approx(reference.get_reward(ours.physics), rel=1e-12)


def fingertip_reaches_spinner(physics, hinge_angle):
    """Whether some finger pose puts the fingertip in contact with a spinner held at hinge_angle."""
    fingertip = physics.model.name2id("fingertip", "geom")
    spinner_caps = {physics.model.name2id(name, "geom") for name in ("cap1", "cap2")}
    (proximal_low, proximal_high), (distal_low, distal_high) = physics.named.model.jnt_range[["proximal", "distal"]]
    for proximal, distal in itertools.product(
        np.linspace(proximal_low, proximal_high, 41), np.linspace(distal_low, distal_high, 41)
    ):
        with physics.reset_context():
            physics.named.data.qpos[["proximal", "distal", "hinge"]] = proximal, distal, hinge_angle
        pairs = zip(physics.data.contact.geom1, physics.data.contact.geom2, strict=True)
        if any(fingertip in (a, b) and {a, b} & spinner_caps for a, b in pairs):
            return True
    return False


@pytest.mark.parametrize("setting", SETTINGS)
def test_finger_tip_can_touch_a_spinner_resting_at_any_angle(setting):
    physics = domains.load("finger", "spin", scale("finger", setting)).physics
    # Vertical (0) is the hardest: the spinner's near side is farthest from the finger's base.
    for hinge_angle in (0.0, np.pi / 4, np.pi / 2):
        assert fingertip_reaches_spinner(physics, hinge_angle), hinge_angle


def test_a_shorter_distal_link_than_setting_one_could_not_touch_a_vertical_spinner():
    # Why the finger's scales start at 0.85, not 0.8: the check above would fail at 0.8.
    assert not fingertip_reaches_spinner(domains.load("finger", "spin", 0.8).physics, 0.0)


@pytest.mark.parametrize("setting", [1, 3, 10])
def test_cheetah_lands_on_its_feet_on_the_ground_after_reset(setting):
    env = domains.load("cheetah", "run", scale("cheetah", setting))
    env.task.random.seed(setting)
    env.reset()  # dm_control lets the cheetah settle for 200 steps
    physics = env.physics
    ground = physics.model.name2id("ground", "geom")
    contacts = physics.data.contact
    touching = {
        physics.model.id2name(int(b if a == ground else a), "geom")
        for a, b in zip(contacts.geom1, contacts.geom2, strict=True)
        if ground in (a, b)
    }
    assert touching, "the cheetah floats"
    assert physics.named.data.xpos["torso", "z"] > 0
