"""sgfd_envs background ids: exact compositing, background sources, user folders and their errors, in the family the
ids made before version 0.3.0 (moving backgrounds behind dm_control's robots by coverage: :data:`EARLIER`), one
keyword each away from the paper's (tests/envs/test_paper_tasks.py)."""

# First: importing sgfd_envs picks MuJoCo's headless OpenGL backend, which must precede dm_control.
import sgfd_envs

# isort: split

from pathlib import Path

import cv2
import gymnasium as gym
import mujoco
import numpy as np
import pytest
from dm_control import suite

from bench.benchmark_methods import interior
from sgfd_envs.backgrounds import (
    PROCEDURAL_SEEDS,
    ImageBackground,
    ProceduralBackground,
    VideoBackground,
    fit_frame,
    make_background,
)
from sgfd_envs.families import EARLIER_FAMILY

# The earlier family of the background ids; with a folder, its files decide the test domains.
EARLIER = EARLIER_FAMILY["background"]
EARLIER_WITH_FOLDER = {key: value for key, value in EARLIER.items() if key != "test_domains"}


def plane_pixels(physics, segmentation):
    planes = np.flatnonzero(physics.model.geom_type == mujoco.mjtGeom.mjGEOM_PLANE)
    return (segmentation[..., 1] == mujoco.mjtObj.mjOBJ_GEOM) & np.isin(segmentation[..., 0], planes)


def start_index(source, observation, background_mask):
    """The frame index of ``source`` shown behind the robot in ``observation``."""
    matches = [
        t
        for t in range(source.n_frames)
        if np.array_equal(source.frame(t)[background_mask], observation[background_mask])
    ]
    assert len(matches) == 1, matches
    return matches[0]


@pytest.mark.parametrize("env_id", ["SGFD/walker-walk-v0", "SGFD/cheetah-run-v0", "SGFD/finger-turn-v0"])
def test_compositing_puts_the_background_behind_the_robot_as_a_multisampled_render_would(env_id):
    domain, size = 1, 84
    source = make_background("train", domain, size, size)
    with gym.make(env_id, domain=domain, **EARLIER) as env:
        observation, _ = env.reset(seed=0)
        rng = np.random.default_rng(0)
        for _ in range(10):
            observation, *_ = env.step(rng.uniform(-1, 1, env.action_space.shape).astype(np.float32))
        physics = env.unwrapped.physics
        # dm_control's own Camera, an independent render path: the env moved the floor to a group the default
        # scene option does not draw; the skybox off too. What is left is the robot, over black.
        robot_only = physics.render(size, size, camera_id=0, render_flag_overrides={"skybox": False}).astype(int)
        segmentation = physics.render(size, size, camera_id=0, segmentation=True)[..., 0]
    inside, outside = interior(segmentation != -1), interior(segmentation == -1)
    assert inside.sum() > 50 and outside.sum() > 0.5 * size * size
    # Where the robot covers the whole pixel it stays exactly as dm_control rendered it (shadows included); the
    # pixel-centre segmentation misses the odd thin gap that one of the 4 samples sees through.
    assert np.mean(np.all(observation[inside] == robot_only[inside], axis=-1)) > 0.99
    first = start_index(source, observation, outside)
    frame = source.frame(first).astype(int)
    np.testing.assert_array_equal(observation[outside], frame[outside])
    # Every pixel is the robot's weighted colour plus (1 - coverage) of the background, coverage a share of the
    # 4 samples: exactly so where nothing was drawn, within a level of rounding elsewhere.
    candidates = [robot_only + (4 - k) * frame / 4 for k in range(5)]
    error = np.min([np.abs(observation - c).max(axis=-1) for c in candidates], axis=0)
    assert error.max() <= 2.0
    edges = ~inside & ~outside
    assert np.any(np.abs(observation[edges] - robot_only[edges]).max(axis=-1) > 10)  # blended, not cut


def test_background_starts_at_a_seeded_random_frame_and_advances_one_frame_per_step():
    source = make_background("test", 2, 64, 64)
    starts = []
    for seed in (0, 0, 1):
        with gym.make("SGFD/finger-spin-v0", split="test", domain=2, image_size=64, **EARLIER) as env:
            observation, _ = env.reset(seed=seed)
            physics = env.unwrapped.physics
            background = interior(physics.render(64, 64, camera_id=0, segmentation=True)[..., 0] == -1)
            first = start_index(source, observation, background)
            for step in range(1, 4):
                observation, *_ = env.step(np.zeros(2, dtype=np.float32))
                background = interior(physics.render(64, 64, camera_id=0, segmentation=True)[..., 0] == -1)
                np.testing.assert_array_equal(observation[background], source.frame(first + step)[background])
        starts.append(first)
    assert starts[0] == starts[1] != starts[2]


def test_the_prior_colour_rule_eats_robot_pixels_and_misses_background_ones():
    """Evidence for the depth mask: DBC's rule (blue > green and blue > red) on dm_control's default render."""
    env = suite.load("finger", "spin", task_kwargs={"random": 0})
    env.reset()
    physics = env.physics
    frame = physics.render(84, 84, camera_id=0).astype(np.int64)
    segmentation = physics.render(84, 84, camera_id=0, segmentation=True)
    floor_or_sky = plane_pixels(physics, segmentation) | (segmentation[..., 0] == -1)
    red, green, blue = frame[..., 0], frame[..., 1], frame[..., 2]
    colour_rule = (blue > green) & (blue > red)
    eaten = ~floor_or_sky & colour_rule
    eaten_geoms = {physics.model.id2name(int(i), "geom") for i in np.unique(segmentation[..., 0][eaten])}
    assert {"proximal_decoration", "spinner_decoration"} <= eaten_geoms
    # The skybox's white stars fail the rule and would stay in the observation.
    assert np.sum(floor_or_sky & ~colour_rule) > 0


def test_procedural_sources_are_deterministic_moving_and_looping():
    source = ProceduralBackground(seed=5, height=40, width=48, n_frames=200)
    again = ProceduralBackground(seed=5, height=40, width=48, n_frames=200)
    frames = np.stack([source.frame(t) for t in range(200)])
    assert frames.shape == (200, 40, 48, 3) and frames.dtype == np.uint8
    np.testing.assert_array_equal(frames, np.stack([again.frame(t) for t in range(200)]))
    assert all(not np.array_equal(frames[t], frames[t + 1]) for t in range(199))
    np.testing.assert_array_equal(source.frame(200), frames[0])
    # Natural-looking: neighbouring frames are close (smooth motion), the texture is not flat.
    assert np.abs(frames[1:].astype(int) - frames[:-1]).mean() < 40
    assert frames.std() > 20
    grey = ProceduralBackground(seed=5, height=40, width=48, grayscale=True).frame(3)
    assert np.array_equal(grey[..., 0], grey[..., 1]) and np.array_equal(grey[..., 1], grey[..., 2])


def test_every_domain_has_its_own_background_and_test_backgrounds_are_unseen():
    assert set(PROCEDURAL_SEEDS["train"]).isdisjoint(PROCEDURAL_SEEDS["test"])
    sources = {
        (split, domain): make_background(split, domain, 32, 32) for split in ("train", "test") for domain in range(4)
    }
    samples = {
        key: np.stack([source.frame(t) for t in range(0, 1000, 50)]).astype(np.int64) for key, source in sources.items()
    }
    keys = list(samples)
    for i, first in enumerate(keys):
        for second in keys[i + 1 :]:
            # No frame of one source appears in another, and on average they differ clearly.
            assert np.abs(samples[first] - samples[second]).mean() > 10, (first, second)
            assert not any(np.array_equal(a, b) for a in samples[first] for b in samples[second])


def test_state_observations_do_not_depend_on_the_background():
    observations = []
    for split in ("train", "test"):
        with gym.make("SGFD/walker-run-v0", split=split, obs_type="state") as env:
            observations.append(env.reset(seed=3)[0])
    np.testing.assert_array_equal(*observations)


# --- user folders ---------------------------------------------------------------------------------


def write_video(path: Path, n_frames: int, tint: int, size=(64, 48)) -> None:
    """A small video whose frames differ from each other and from other tints."""
    fourcc = cv2.VideoWriter_fourcc(*("mp4v" if path.suffix == ".mp4" else "MJPG"))
    writer = cv2.VideoWriter(str(path), fourcc, 10, size)
    assert writer.isOpened()
    width, height = size
    for t in range(n_frames):
        frame = np.zeros((height, width, 3), dtype=np.uint8)
        frame[...] = (40 * tint % 256, 255 - 30 * tint % 256, 100)
        frame[:, (4 * t) % width : (4 * t) % width + 8] = (255, 255, 255)
        writer.write(frame)
    writer.release()


def decoded_frames(path: Path, size: int, grayscale: bool = False) -> list[np.ndarray]:
    capture = cv2.VideoCapture(str(path))
    frames = []
    while True:
        ok, frame = capture.read()
        if not ok:
            return frames
        frames.append(fit_frame(frame, size, size, grayscale))


@pytest.fixture
def video_folder(tmp_path):
    folder = tmp_path / "kinetics"
    folder.mkdir()
    for i in range(6):
        write_video(folder / f"clip{i}{'.mp4' if i % 2 else '.avi'}", n_frames=12, tint=i)
    (folder / "README.txt").write_text("not a video")
    return folder


def test_flat_video_folder_gives_four_training_sources_and_the_rest_for_testing(video_folder):
    env_id = "SGFD/walker-walk-v0"
    assert sgfd_envs.n_domains(env_id, "train", background_dir=video_folder) == 4
    assert sgfd_envs.n_domains(env_id, "test", background_dir=video_folder) == 2
    expected = decoded_frames(video_folder / "clip5.mp4", 48)
    assert len(expected) == 12
    with gym.make(
        env_id, split="test", domain=1, background_dir=video_folder, image_size=48, **EARLIER_WITH_FOLDER
    ) as env:
        observation, _ = env.reset(seed=0)
        physics = env.unwrapped.physics
        background = interior(physics.render(48, 48, camera_id=0, segmentation=True)[..., 0] == -1)
        matches = [t for t, frame in enumerate(expected) if np.array_equal(frame[background], observation[background])]
        assert len(matches) == 1
        for step in range(1, 14):  # past the end of the 12-frame clip: it wraps around
            observation, *_ = env.step(np.zeros(6, dtype=np.float32))
            background = interior(physics.render(48, 48, camera_id=0, segmentation=True)[..., 0] == -1)
            np.testing.assert_array_equal(observation[background], expected[(matches[0] + step) % 12][background])


def test_video_frame_budget_and_grayscale(video_folder):
    path = video_folder / "clip0.avi"
    assert VideoBackground(path, 32, 32).n_frames == 12
    budgeted = VideoBackground(path, 32, 32, frame_budget=5)
    assert budgeted.n_frames == 5
    np.testing.assert_array_equal(budgeted.frame(5), budgeted.frame(0))
    np.testing.assert_array_equal(budgeted.frame(4), decoded_frames(path, 32)[4])
    grey = VideoBackground(path, 32, 32, grayscale=True).frame(2)
    assert np.array_equal(grey[..., 0], grey[..., 2]) and grey.std() > 0
    with gym.make(
        "SGFD/cheetah-run-v0", background_dir=video_folder, grayscale=True, image_size=32, **EARLIER_WITH_FOLDER
    ) as env:
        observation, _ = env.reset(seed=0)
        physics = env.unwrapped.physics
        background = interior(physics.render(32, 32, camera_id=0, segmentation=True)[..., 0] == -1)
    assert np.array_equal(observation[background][:, 0], observation[background][:, 1])


def test_frames_are_centre_cropped_to_the_observation_shape():
    wide = np.zeros((100, 300, 3), dtype=np.uint8)
    wide[:, 100:200] = (0, 255, 0)  # BGR green in the centre third, black sides
    fitted = fit_frame(wide, 84, 84, grayscale=False)
    assert fitted.shape == (84, 84, 3)
    assert np.all(fitted == (0, 255, 0))


def test_train_test_subfolders_and_images(tmp_path):
    for split, count in (("train", 3), ("test", 2)):
        (tmp_path / split).mkdir()
        for i in range(count):
            image = np.full((30, 40, 3), (50 * i, 80, 200 - 60 * i), dtype=np.uint8)
            image[::5] = 255
            assert cv2.imwrite(str(tmp_path / split / f"picture{i}.png"), image)
    assert sgfd_envs.n_domains("SGFD/finger-spin-v0", "train", background_dir=tmp_path) == 3
    assert sgfd_envs.n_domains("SGFD/finger-spin-v0", "test", background_dir=tmp_path) == 2
    expected = ImageBackground(tmp_path / "test" / "picture1.png", 40, 40).frame(0)
    with gym.make(
        "SGFD/finger-spin-v0", split="test", domain=1, background_dir=tmp_path, image_size=40, **EARLIER_WITH_FOLDER
    ) as env:
        observations = [env.reset(seed=0)[0]] + [env.step(np.zeros(2, dtype=np.float32))[0] for _ in range(3)]
        physics = env.unwrapped.physics
        background = interior(physics.render(40, 40, camera_id=0, segmentation=True)[..., 0] == -1)
    np.testing.assert_array_equal(observations[-1][background], expected[background])
    venv = sgfd_envs.make_domain_vec_env("SGFD/finger-spin-v0", background_dir=tmp_path, image_size=40)
    try:
        assert venv.num_envs == 3
    finally:
        venv.close()


# --- bad folders ----------------------------------------------------------------------------------


def test_missing_folder_is_refused(tmp_path):
    with pytest.raises(FileNotFoundError, match=r"background_dir .*nowhere.* is not an existing folder"):
        gym.make("SGFD/walker-walk-v0", background_dir=tmp_path / "nowhere")
    (tmp_path / "file.mp4").write_bytes(b"")
    with pytest.raises(FileNotFoundError, match="is not an existing folder"):
        sgfd_envs.n_domains("SGFD/walker-walk-v0", background_dir=tmp_path / "file.mp4")


def test_empty_or_too_small_folders_are_refused(tmp_path, video_folder):
    empty = tmp_path / "empty"
    empty.mkdir()
    (empty / "notes.txt").write_text("no media here")
    with pytest.raises(ValueError, match=r"background_dir .*empty.* holds 0 videos/images \(\.mp4, .*needs at least 5"):
        gym.make("SGFD/walker-walk-v0", background_dir=empty)
    for path in sorted(video_folder.glob("clip*"))[4:]:
        path.unlink()
    with pytest.raises(ValueError, match="holds 4 videos/images"):
        sgfd_envs.make_domain_vec_env("SGFD/walker-walk-v0", background_dir=video_folder)


def test_half_split_folders_are_refused(tmp_path):
    (tmp_path / "train").mkdir()
    write_video(tmp_path / "train" / "a.avi", 3, tint=1)
    with pytest.raises(ValueError, match="has train/ but no test/"):
        gym.make("SGFD/walker-walk-v0", background_dir=tmp_path)
    (tmp_path / "test").mkdir()
    with pytest.raises(ValueError, match=r"background_dir .*test.* holds no video or image"):
        gym.make("SGFD/walker-walk-v0", background_dir=tmp_path)


def test_unreadable_media_are_refused_naming_the_file(video_folder):
    (video_folder / "clip0.avi").write_bytes(b"this is not a video" * 100)
    with pytest.raises(ValueError, match=r"background_dir: OpenCV could not read any frame of the video .*clip0\.avi"):
        gym.make("SGFD/walker-walk-v0", background_dir=video_folder, **EARLIER_WITH_FOLDER)
    (video_folder / "clip1.mp4").unlink()
    (video_folder / "clip1.png").write_bytes(b"not a png")
    with pytest.raises(ValueError, match=r"background_dir: OpenCV could not read the image .*clip1\.png"):
        gym.make("SGFD/walker-walk-v0", domain=1, background_dir=video_folder, **EARLIER_WITH_FOLDER)


def test_domain_range_follows_the_users_folder(video_folder):
    with pytest.raises(ValueError, match=r"domain must be an int in 0..1 for split 'test', got 2"):
        gym.make("SGFD/walker-walk-v0", split="test", domain=2, background_dir=video_folder)
