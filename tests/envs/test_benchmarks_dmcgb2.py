"""DMC-GB2 (DMCGB2/ ids): camera poses inside each geometric mode's range, walked one per episode; a rolled camera
turns the picture, not the scene; colours in order from a seeded index; the video screen behind the robot;
hard farther from train than easy; the video texture's side and resize, the benchmark's or the fast path's."""

import cv2
import gymnasium as gym
import mujoco
import numpy as np
import pytest
from dm_control.utils import transformations

from sgfd_envs.benchmarks import dcs, dmcgb2
from sgfd_envs.benchmarks.dmcgb2 import EASY_SHIFT_DIVISOR, SHIFT_LIMITS, rotation_angles, shift_angles
from sgfd_envs.benchmarks.media import dmcgb_clips, procedural_colour_set
from sgfd_envs.benchmarks.scene import VideoTexture, video_texture

SIZE = 32


def test_rotation_angles_are_100_even_steps_over_the_range():
    hard, easy = rotation_angles("hard"), rotation_angles("easy")
    assert len(hard) == len(easy) == 100
    assert hard[0] == -180 and hard[-1] == pytest.approx(176.4) and np.allclose(np.diff(hard), 3.6)
    assert easy[0] == -90 and easy[-1] == pytest.approx(88.2)


@pytest.mark.parametrize("domain", sorted(SHIFT_LIMITS))
def test_shift_poses_walk_the_border_of_the_domains_rectangle(domain):
    max_a, min_a, max_b, min_b = SHIFT_LIMITS[domain]
    for difficulty, divisor in (("hard", 1.0), ("easy", EASY_SHIFT_DIVISOR)):
        poses = shift_angles(domain, difficulty)
        assert poses.shape == (100, 2)
        low, high = np.array([min_a, min_b]) / divisor, np.array([max_a, max_b]) / divisor
        assert np.all(poses >= low - 1e-12) and np.all(poses <= high + 1e-12)
        on_border = np.isclose(poses, low).any(axis=1) | np.isclose(poses, high).any(axis=1)
        assert on_border.all()
        np.testing.assert_allclose(poses[0], low)  # from the (min a, min b) corner
        np.testing.assert_allclose(poses[25], [high[0], low[1]])


def episode_rotations(env, seed, n_episodes):
    rotations, indices = [], []
    for episode in range(n_episodes):
        env.reset(seed=seed if episode == 0 else None)
        rotations.append(env.unwrapped.distraction.camera_rotation.copy())
        indices.append(env.unwrapped.distraction.pose_index)
    return rotations, indices


@pytest.mark.parametrize("mode", ["rotate_easy", "rotate_hard"])
def test_rotate_rolls_the_camera_about_its_axis_by_an_angle_of_the_mode(mode):
    limit = dmcgb2.ROTATION_LIMIT[mode.split("_")[1]]
    with gym.make("DMCGB2/finger-spin-v0", split=mode, obs_type="state") as env:
        rotations, indices = episode_rotations(env, seed=0, n_episodes=100)
        assert sorted(indices) == list(range(100))  # every pose once in 100 episodes, in a seeded order
        angles = []
        for rotation in rotations:
            np.testing.assert_allclose(rotation[2], [0, 0, 1], atol=1e-12)  # the viewing axis stays
            angles.append(np.degrees(np.arctan2(rotation[1, 0], rotation[0, 0])))
        angles = np.array(angles)
        assert np.all(np.abs(angles) <= limit + 1e-9) and angles.max() - angles.min() > limit
        assert episode_rotations(env, seed=0, n_episodes=5)[1] == indices[:5]
        assert episode_rotations(env, seed=1, n_episodes=5)[1] != indices[:5]


@pytest.mark.parametrize("mode", ["shift_easy", "shift_hard", "rotate_shift_hard"])
def test_shift_pans_and_tilts_the_camera_inside_the_rectangle(mode):
    difficulty = mode.rsplit("_", 1)[1]
    with gym.make("DMCGB2/cartpole-swingup-v0", split=mode, obs_type="state") as env:
        rotations, indices = episode_rotations(env, seed=3, n_episodes=10)
    poses = shift_angles("cartpole", difficulty)
    for rotation, index in zip(rotations, indices, strict=True):
        a, b = poses[index]
        expected = transformations.rotation_y_axis(np.radians(a)) @ transformations.rotation_x_axis(np.radians(b))
        if mode.startswith("rotate"):
            expected = expected @ transformations.rotation_z_axis(np.radians(rotation_angles(difficulty)[index]))
        np.testing.assert_allclose(rotation, expected, atol=1e-12)


def test_a_rolled_camera_turns_the_picture_and_leaves_the_scene():
    """At -180 degrees the picture is the train picture upside down: the camera moved, not the robot."""
    with (
        gym.make("DMCGB2/finger-spin-v0", split="rotate_hard", image_size=SIZE) as env,
        gym.make("DMCGB2/finger-spin-v0", image_size=SIZE) as train,
    ):
        observation, _ = env.reset(seed=0)
        train_observation, _ = train.reset(seed=0)
        while env.unwrapped.distraction.pose_index != 0:  # pose 0 is -180 degrees
            observation, _ = env.reset()
            train_observation, _ = train.reset()
        turned = np.abs(observation.astype(int) - train_observation[::-1, ::-1]).mean()
        unturned = np.abs(observation.astype(int) - train_observation).mean()
        assert turned < 2 and unturned > 10 * turned
        np.testing.assert_array_equal(env.unwrapped.physics.get_state(), train.unwrapped.physics.get_state())
        # The data the renderer saw is back to the camera's own pose.
        np.testing.assert_array_equal(env.unwrapped.physics.data.cam_xmat, train.unwrapped.physics.data.cam_xmat)


@pytest.mark.parametrize("mode", ["color_hard", "color_video_easy"])
def test_colours_follow_the_set_in_order_from_a_seeded_start(mode):
    colours = procedural_colour_set(mode.rsplit("_", 1)[1])
    with gym.make("DMCGB2/walker-stand-v0", split=mode, obs_type="state") as env:
        physics = env.unwrapped.physics
        material = mujoco.mj_name2id(physics.model.ptr, mujoco.mjtObj.mjOBJ_MATERIAL, "self")
        starts = []
        for seed in (0, 1, 2):
            indices = []
            for episode in range(4):
                env.reset(seed=seed if episode == 0 else None)
                indices.append(env.unwrapped.distraction.colour_index)
                np.testing.assert_allclose(physics.model.mat_rgba[material, :3], colours[indices[-1]]["self_rgb"])
            assert np.all(np.diff(indices) % 100 == 1)
            starts.append(indices[0])
        assert len(set(starts)) > 1


@pytest.mark.parametrize("mode", ["video_easy", "video_hard", "color_video_hard"])
def test_the_video_plays_on_a_screen_behind_the_walker(mode):
    side = dmcgb2.projector_texture_side(SIZE)
    with (
        gym.make("DMCGB2/walker-walk-v0", split=mode, image_size=SIZE) as env,
        gym.make("DMCGB2/walker-walk-v0", image_size=SIZE) as train,
    ):
        observations = [env.reset(seed=0)[0]]
        train_observations = [train.reset(seed=0)[0]]
        for _ in range(3):
            action = np.full(6, 0.5, dtype=np.float32)
            observations.append(env.step(action)[0])
            train_observations.append(train.step(action)[0])
        distraction = env.unwrapped.distraction
        physics = env.unwrapped.physics
        model = physics.model
        screen = mujoco.mj_name2id(model.ptr, mujoco.mjtObj.mjOBJ_TEXTURE, "video_screen")
        shown = model.tex_data[model.tex_adr[screen] : model.tex_adr[screen] + side * side * 3]
        clips = dmcgb_clips("video_" + mode.rsplit("_", 1)[1], side, None, interpolation=dmcgb2.cv2.INTER_AREA)
        np.testing.assert_array_equal(shown.reshape(side, side, 3), clips.clip(distraction.clip_index).frame(3))
        torso = physics.data.subtree_com[mujoco.mj_name2id(model.ptr, mujoco.mjtObj.mjOBJ_BODY, "torso")]
        position = distraction.screen_position()
        assert position[0] == pytest.approx(torso[0]) and position[2] == pytest.approx(torso[2] - 1.07)
        grid = mujoco.mj_name2id(model.ptr, mujoco.mjtObj.mjOBJ_MATERIAL, "grid")
        assert model.mat_rgba[grid, 3] == (0.0 if mode == "video_hard" else 1.0)
        # The background changes every step (the clip plays), and is not the train picture.
        assert all(not np.array_equal(a, b) for a, b in zip(observations, train_observations, strict=True))
        assert not np.array_equal(observations[1], observations[2])
        first_clip = distraction.clip_index
        env.reset()
        assert distraction.clip_index == (first_clip + 1) % 100 if "hard" in mode else (first_clip + 1) % 10


def distance_to_train(env_id, split, seeds=range(4)):
    distances = []
    with gym.make(env_id, split=split, image_size=SIZE) as env, gym.make(env_id, image_size=SIZE) as train:
        for seed in seeds:
            observation = env.reset(seed=seed)[0].astype(float)
            distances.append(np.abs(observation - train.reset(seed=seed)[0]).mean())
    return float(np.mean(distances))


@pytest.mark.slow
def test_hard_modes_are_farther_from_train_than_easy_ones():
    env_id = "DMCGB2/cheetah-run-v0"
    for family in ("rotate", "shift", "rotate_shift", "color", "video", "color_video"):
        easy, hard = (distance_to_train(env_id, f"{family}_{d}", seeds=range(3)) for d in ("easy", "hard"))
        if family.endswith("video"):
            # A video mode's difficulty is its clip set (and the floor), not a range: with the stand-in clips the
            # distance follows their colours, so only that both are far from train is checked.
            assert easy > 5 and hard > 5, family
        else:
            assert 0 < easy < hard, family


def test_the_video_texture_is_the_benchmarks_or_twice_the_image_then_halved_while_minified():
    # The benchmark's side and resize, the fast path's twice the observation's side by area (never above the
    # benchmark's); then halved while the halved side keeps texels_per_pixel texels per observation pixel.
    assert video_texture(256, cv2.INTER_CUBIC, 84, "benchmark", 1.5) == VideoTexture(256, cv2.INTER_CUBIC, 1)
    assert video_texture(256, cv2.INTER_CUBIC, 84, "benchmark", 1.6) == VideoTexture(256, cv2.INTER_CUBIC, 0)
    assert video_texture(256, cv2.INTER_CUBIC, 84, "fast", 1.5) == VideoTexture(168, cv2.INTER_AREA, 0)
    assert video_texture(256, cv2.INTER_CUBIC, 200, "fast", 0.5) == VideoTexture(256, cv2.INTER_AREA, 1)
    assert video_texture(100, cv2.INTER_CUBIC, 10, "benchmark", 1.0).side == 25  # halved while it divides by 2
    assert (dmcgb2.projector_texture_side(84), dmcgb2.projector_texture_side(84, "fast")) == (128, 168)
    assert (dcs.sky_texture_side(84), dcs.sky_texture_side(84, "fast"), dcs.sky_texture_side(32)) == (400, 168, 200)
    with pytest.raises(ValueError, match=r"render must be one of \('benchmark', 'fast'\), got 'quick'"):
        video_texture(256, cv2.INTER_CUBIC, 84, "quick", 1.5)
