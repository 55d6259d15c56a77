"""The Distracting Control Suite (DCS/ ids): the camera inside the difficulty's sphere around its start and looking
at the robot, colours within +-scale of dm_control's, the sky showing a frame of the difficulty's videos (one per
episode when static, moving one frame per simulator step when dynamic), the floor's alpha per domain, DAVIS read
from a folder, hard farther from train than easy."""

import cv2
import gymnasium as gym
import mujoco
import numpy as np
import pytest

from sgfd_envs.backgrounds import halve
from sgfd_envs.benchmarks import dcs
from sgfd_envs.benchmarks.dcs import DAVIS_VIDEOS, DIFFICULTY_SCALE, to_spherical
from sgfd_envs.benchmarks.media import davis_clips

SIZE = 32


def test_difficulties_and_video_lists_are_dcss():
    assert DIFFICULTY_SCALE == {"easy": 0.1, "medium": 0.2, "hard": 0.3}
    assert dcs.DIFFICULTY_VIDEOS == {"easy": 4, "medium": 8, "hard": None}
    assert len(DAVIS_VIDEOS["train"]) == 60 and len(DAVIS_VIDEOS["validation"]) == 30
    assert not set(DAVIS_VIDEOS["train"]) & set(DAVIS_VIDEOS["validation"])
    assert DAVIS_VIDEOS["train"][:4] == ("bear", "bmx-bumps", "boat", "boxing-fisheye")


def camera_poses(env, n_steps, tracking):
    """(position, orientation) the renderer uses after reset and after each agent step; the position relative
    to the robot's centre of mass for a tracking camera."""
    camera = env.unwrapped.distraction.camera
    data = env.unwrapped.physics.data
    poses = []
    for step in range(n_steps + 1):
        if step:
            env.step(np.zeros(env.action_space.shape, dtype=np.float32))
        position, orientation = camera.pose()
        poses.append((position - data.subtree_com[1] if tracking else position, orientation))
    return poses


@pytest.mark.parametrize(
    ("env_id", "difficulty"), [("DCS/cartpole-swingup-v0", "hard"), ("DCS/walker-walk-v0", "easy")]
)
@pytest.mark.parametrize("dynamic", [False, True])
def test_the_camera_stays_in_the_difficultys_sphere_and_looks_at_the_robot(env_id, difficulty, dynamic):
    scale = DIFFICULTY_SCALE[difficulty]
    with gym.make(env_id, split=difficulty, dynamic=dynamic, distractions=("camera",), obs_type="state") as env:
        for seed in range(3):
            env.reset(seed=seed)
            physics = env.unwrapped.physics
            camera = env.unwrapped.distraction.camera
            tracking = int(physics.model.cam_mode[0]) == int(mujoco.mjtCamLight.mjCAMLIGHT_TRACKCOM)
            centre = physics.data.subtree_com[1].copy() if tracking else np.zeros(3)
            start = to_spherical(physics.data.cam_xpos[0] - centre)
            poses = camera_poses(env, n_steps=6, tracking=tracking)
            for position, orientation in poses:
                radius, azimuth, polar = to_spherical(position)
                assert start[0] * (1 - 0.5 * scale) - 1e-9 <= radius <= start[0] * (1 + 1.5 * scale) + 1e-9
                assert abs(azimuth - start[1]) <= np.pi / 2 * scale + 1e-9
                assert abs(polar - start[2]) <= np.pi / 2 * scale + 1e-9 and polar <= np.pi / 2 + 1e-9
                np.testing.assert_allclose(orientation @ orientation.T, np.eye(3), atol=1e-9)
                # The roll stays within +-pi/2 s: the image's up axis leans at most that far from level.
                up = orientation[:, 1]
                right = orientation[:, 0]
                assert abs(np.arcsin(np.clip(right[2], -1, 1))) <= np.pi / 2 * scale + 1e-6
                assert up[2] > 0
            moved = [np.linalg.norm(poses[i + 1][0] - poses[i][0]) for i in range(len(poses) - 1)]
            if not dynamic and not tracking:
                assert max(moved) < 1e-9  # a static camera keeps its pose for the whole episode
        # A fixed camera looks at the point it looked at before it moved.
        if not tracking:
            position, orientation = camera.pose()
            target = camera._initial_target
            view = -orientation[:, 2]
            np.testing.assert_allclose(view, (target - position) / np.linalg.norm(target - position), atol=1e-3)
        starts = []
        for seed in (10, 11):
            env.reset(seed=seed)
            starts.append(camera.pose()[0])
        assert not np.allclose(*starts)  # a new pose each episode


@pytest.mark.parametrize("dynamic", [False, True])
def test_colours_stay_within_scale_of_dm_controls(dynamic):
    scale = DIFFICULTY_SCALE["medium"]
    with gym.make(
        "DCS/finger-spin-v0", split="medium", dynamic=dynamic, distractions=("colour",), obs_type="state"
    ) as env:
        colour = env.unwrapped.distraction.colour
        original = colour.original.copy()
        seen = []
        for episode in range(2):
            env.reset(seed=0 if episode == 0 else None)
            for _ in range(4):
                rgb = colour.current.copy()
                assert np.all(rgb >= np.clip(original - scale, 0, 1) - 1e-12)
                assert np.all(rgb <= np.clip(original + scale, 0, 1) + 1e-12)
                seen.append(rgb)
                env.step(np.zeros(2, dtype=np.float32))
        within_episode = [not np.array_equal(seen[i], seen[i + 1]) for i in range(3)]
        assert all(within_episode) if dynamic else not any(within_episode)
        assert not np.array_equal(seen[0], seen[4])  # new colours each episode


def sky_bytes(physics, side):
    model = physics.model
    index = mujoco.mj_name2id(model.ptr, mujoco.mjtObj.mjOBJ_TEXTURE, "skybox")
    return model.tex_data[model.tex_adr[index] : model.tex_adr[index] + side * side * 3].reshape(side, side, 3)


@pytest.mark.parametrize("dynamic", [False, True])
def test_the_sky_shows_a_frame_of_the_difficultys_videos(dynamic):
    texture = dcs.sky_texture(SIZE)
    side = texture.side
    clips = davis_clips(DAVIS_VIDEOS["train"][:4], "train", texture.resize_side, None, halvings=texture.halvings)
    with gym.make(
        "DCS/cartpole-swingup-v0", split="easy", dynamic=dynamic, distractions=("background",), image_size=SIZE
    ) as env:
        physics = env.unwrapped.physics
        background = env.unwrapped.distraction.background
        videos = set()
        for episode in range(6):
            env.reset(seed=0 if episode == 0 else None)
            videos.add(background.video_index)
            frames = [background.frame_index]
            np.testing.assert_array_equal(sky_bytes(physics, side), clips.clip(background.video_index).frame(frames[0]))
            for _ in range(3):
                env.step(np.zeros(1, dtype=np.float32))
                frames.append(background.frame_index)
            shown = clips.clip(background.video_index).frame(frames[-1])
            np.testing.assert_array_equal(sky_bytes(physics, side), shown)
            moves = np.abs(np.diff(frames))
            if dynamic:  # cartpole repeats each action 8 times: 8 frames per agent step, or fewer at a turn
                assert np.all(moves <= 8) and moves.sum() > 0
            else:
                assert not moves.any()
        assert videos <= {0, 1, 2, 3} and len(videos) > 1
        grid = mujoco.mj_name2id(physics.model.ptr, mujoco.mjtObj.mjOBJ_MATERIAL, "grid")
        assert physics.model.mat_rgba[grid, 3] == pytest.approx(0.3)


@pytest.mark.parametrize(("env_id", "alpha"), [("DCS/reacher-easy-v0", 0.0), ("DCS/cheetah-run-v0", 1.0)])
def test_the_floors_alpha_is_dcss_per_domain(env_id, alpha):
    with gym.make(env_id, split="hard", obs_type="state") as env:
        env.reset(seed=0)
        model = env.unwrapped.physics.model
        grid = mujoco.mj_name2id(model.ptr, mujoco.mjtObj.mjOBJ_MATERIAL, "grid")
        assert model.mat_rgba[grid, 3] == alpha


def distance_to_train(env_id, split, seeds, **kwargs):
    distances = []
    with gym.make(env_id, split=split, image_size=SIZE, **kwargs) as env, gym.make(env_id, image_size=SIZE) as train:
        for seed in seeds:
            observation = env.reset(seed=seed)[0].astype(float)
            distances.append(np.abs(observation - train.reset(seed=seed)[0]).mean())
    return float(np.mean(distances))


@pytest.mark.slow
@pytest.mark.parametrize("distraction", ["camera", "colour"])
def test_harder_is_farther_from_train(distraction):
    distances = [
        distance_to_train("DCS/ball_in_cup-catch-v0", split, range(8), distractions=(distraction,))
        for split in ("easy", "medium", "hard")
    ]
    assert 0 < distances[0] < distances[1] < distances[2]


# --- DAVIS ---------------------------------------------------------------------------------------------


@pytest.fixture
def davis(tmp_path):
    """DAVIS's layout (JPEGImages/480p/<video>/00000.jpg ...) for the validation list, tiny distinctive frames."""
    root = tmp_path / "DAVIS" / "JPEGImages" / "480p"
    for v, name in enumerate(DAVIS_VIDEOS["validation"]):
        (root / name).mkdir(parents=True)
        for t in range(3):
            frame = np.zeros((48, 85, 3), dtype=np.uint8)  # DAVIS's 16:9
            frame[:, : 10 + 20 * t] = (8 * v, 80, 250 - 8 * v)
            assert cv2.imwrite(str(root / name / f"{t:05d}.jpg"), frame)
    return tmp_path / "DAVIS"


def test_davis_frames_are_read_from_the_folder_and_resized_whole(davis):
    texture = dcs.sky_texture(SIZE)
    side = texture.side
    folder = davis / "JPEGImages" / "480p"
    with gym.make(
        "DCS/finger-spin-v0", split="hard", background_dir=davis, background_videos="validation", image_size=SIZE
    ) as env:
        env.reset(seed=0)
        background = env.unwrapped.distraction.background
        name = DAVIS_VIDEOS["validation"][background.video_index]
        image = cv2.imread(str(folder / name / f"{background.frame_index:05d}.jpg"))
        # DCS's 800 x 800 sky, the frame resized bilinearly as its tf.image.resize does, then the mip level read.
        resized = cv2.resize(image, (800, 800), interpolation=cv2.INTER_LINEAR)
        expected = cv2.cvtColor(halve(resized, texture.halvings), cv2.COLOR_BGR2RGB)
        assert texture.halvings == 2 and side == 200
        np.testing.assert_array_equal(sky_bytes(env.unwrapped.physics, side), expected)
    # The 480p folder itself works as well.
    with gym.make("DCS/finger-spin-v0", split="easy", background_dir=folder, background_videos="validation") as env:
        env.reset(seed=0)


def test_missing_davis_videos_are_named(davis):
    with pytest.raises(FileNotFoundError, match=r"lacks 4 of the 4 DAVIS train videos this split uses \(bear, "):
        gym.make("DCS/finger-spin-v0", split="easy", background_dir=davis)
    with pytest.raises(FileNotFoundError, match=r"background_dir .* is not an existing folder"):
        gym.make("DCS/finger-spin-v0", split="easy", background_dir=davis / "nowhere")


# --- DMC-GB's distracting_cs (on DMCGB and DMCGB2 ids) -------------------------------------------------------


# DMC-GB's distracting_cs table as its code publishes it (src/env/distracting_control/suite_utils.py,
# DIFFICULTY_NUM_VIDEOS): intensity -> how many of DAVIS's training videos the background draws from (None: all).
DMCGB_VIDEOS_PER_INTENSITY = {0.025: 2, 0.05: 2, 0.1: 4, 0.15: 6, 0.2: 8, 0.3: None, 0.4: None, 0.5: None}


def test_distracting_cs_is_dmc_gbs_table_of_intensities_and_videos():
    for env_id in ("DMCGB/walker-walk-v0", "DMCGB2/finger-spin-v0"):
        for intensity, videos in DMCGB_VIDEOS_PER_INTENSITY.items():
            with gym.make(env_id, split="distracting_cs", intensity=intensity, obs_type="state") as env:
                distraction = env.unwrapped.distraction
                assert distraction.scale == intensity and distraction.update_every == 2
                assert len(distraction.background._clips) == (videos or 60)
                assert distraction.background.dynamic and distraction.camera.max_velocity == 0.4 * intensity
                assert distraction.colour.step_std == 0.03 * intensity
                assert distraction.camera.angle_delta == np.pi / 2 * intensity


@pytest.mark.parametrize("env_id", ["DMCGB/walker-walk-v0", "DMCGB2/walker-walk-v0"])
def test_distracting_cs_moves_every_second_simulator_step(env_id):
    """Walker repeats each action 4 times (DMC-GB) or 2 (DMC-GB2): the walks move 2 or 1 times per agent step; a
    reset draws them anew (the camera, as DMC-GB's, takes one walk step there) and restarts the count."""
    repeat = 4 if env_id.startswith("DMCGB/") else 2
    with gym.make(env_id, split="distracting_cs", intensity=0.2, obs_type="state") as env:
        env.reset(seed=0)
        distraction = env.unwrapped.distraction
        camera, colour, background = distraction.camera, distraction.colour, distraction.background
        calls = {"camera": 0, "colour": 0, "background": 0}
        for name, part in (("camera", camera), ("colour", colour), ("background", background)):
            advance = part.advance

            def counted(*args, name=name, advance=advance):
                calls[name] += 1
                return advance(*args)

            part.advance = counted
        for step in range(1, 4):
            env.step(np.zeros(env.action_space.shape, dtype=np.float32))
            assert calls == dict.fromkeys(calls, step * repeat // 2)
        env.reset()
        env.step(np.zeros(env.action_space.shape, dtype=np.float32))
        expected = 3 * repeat // 2 + repeat // 2
        assert calls == {"camera": expected + 1, "colour": expected, "background": expected}
