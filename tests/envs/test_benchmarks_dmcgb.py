"""DMC-GB (DMCGB/ ids): colours drawn from the mode's set each episode, videos replacing exactly the sky (easy) or
the sky and the floor (hard), hard farther from train than easy, the stand-ins' geometry, and DMC-GB's own data
read from a folder."""

import colorsys

import cv2
import gymnasium as gym
import mujoco
import numpy as np
import pytest
import torch
from dm_control.mujoco import wrapper

from bench.benchmark_methods import interior
from sgfd_envs.benchmarks import dmcgb
from sgfd_envs.benchmarks.media import (
    COLOUR_KEYS,
    DMCGB_CLIP_FRAMES,
    default_colours,
    dmcgb_clips,
    procedural_colour_set,
    read_colour_set,
)

SIZE = 32


def texture_bytes(physics, name):
    model = physics.model
    index = mujoco.mj_name2id(model.ptr, mujoco.mjtObj.mjOBJ_TEXTURE, name)
    size = model.tex_height[index] * model.tex_width[index] * model.tex_nchannel[index]
    return model.tex_data[model.tex_adr[index] : model.tex_adr[index] + size]


def compiled_texture(xml_texture):
    """What MuJoCo itself builds for one texture element."""
    return mujoco.MjModel.from_xml_string(f"<mujoco><asset>{xml_texture}</asset></mujoco>").tex_data


def rgb(values):
    return " ".join(repr(float(v)) for v in values)


def test_procedural_colour_sets_have_the_shipped_sets_geometry():
    centre = default_colours()
    np.testing.assert_allclose(centre["self_rgb"], [0.7, 0.5, 0.3])
    np.testing.assert_allclose(centre["skybox_rgb"], [0.4, 0.6, 0.8])
    stds = {}
    for difficulty in ("easy", "hard"):
        colours = procedural_colour_set(difficulty)
        assert len(colours) == 100 and all(set(entry) == set(COLOUR_KEYS) for entry in colours)
        values = {key: np.array([entry[key] for entry in colours]) for key in COLOUR_KEYS}
        np.testing.assert_allclose(values["grid_rgb2"] - values["grid_rgb1"], 0.1)
        for key in ("grid_rgb1", "self_rgb", "skybox_rgb"):
            assert values[key].min() >= 0 and values[key].max() <= 1
        deviations = np.concatenate([values[k] - centre[k] for k in ("self_rgb", "skybox_rgb")])
        stds[difficulty] = deviations.std()
        assert abs(deviations.mean()) < 0.03
    assert 0.08 < stds["easy"] < 0.12 and 0.15 < stds["hard"] < 0.22
    # The same set on every call (a seeded draw).
    np.testing.assert_array_equal(
        procedural_colour_set("easy")[3]["self_rgb"], procedural_colour_set("easy")[3]["self_rgb"]
    )


@pytest.mark.slow
@pytest.mark.parametrize("mode", ["color_easy", "color_hard"])
def test_colour_modes_put_an_entry_of_the_set_on_the_scene_each_episode(mode):
    colours = procedural_colour_set(mode.removeprefix("color_"))
    with gym.make("DMCGB/walker-walk-v0", split=mode, obs_type="state") as env:
        physics = env.unwrapped.physics
        self_material = mujoco.mj_name2id(physics.model.ptr, mujoco.mjtObj.mjOBJ_MATERIAL, "self")

        def episode_colours(seed):
            indices = []
            for episode in range(6):
                env.reset(seed=seed if episode == 0 else None)
                index = env.unwrapped.distraction.colour_index
                entry = colours[index]
                np.testing.assert_allclose(physics.model.mat_rgba[self_material], [*entry["self_rgb"], 1.0])
                indices.append(index)
            return indices, entry

        indices, _ = episode_colours(seed=0)
        assert len(set(indices)) > 1  # resampled every episode
        assert episode_colours(seed=1)[0] != indices
        again, entry = episode_colours(seed=0)
        assert again == indices
        # The floor's checker and the sky as MuJoCo builds them from DMC-GB's XML edit.
        grid = (
            f'<texture name="grid" type="2d" builtin="checker" rgb1="{rgb(entry["grid_rgb1"])}" '
            f'rgb2="{rgb(entry["grid_rgb2"])}" width="300" height="300" mark="edge" markrgb=".2 .3 .4"/>'
        )
        sky = (
            f'<texture name="skybox" type="skybox" builtin="gradient" rgb1="{rgb(entry["skybox_rgb"])}" rgb2="0 0 0" '
            'width="800" height="800" mark="random" markrgb="1 1 1"/>'
        )
        np.testing.assert_array_equal(texture_bytes(physics, "grid"), compiled_texture(grid))
        np.testing.assert_array_equal(texture_bytes(physics, "skybox"), compiled_texture(sky))


def segmentation(physics):
    all_groups = wrapper.MjvOption()
    all_groups.geomgroup[:] = 1
    return physics.render(SIZE, SIZE, camera_id=0, scene_option=all_groups, segmentation=True)


def step_both(envs, n_steps):
    rng = np.random.default_rng(0)
    observations = [env.reset(seed=4)[0] for env in envs]
    for _ in range(n_steps):
        action = rng.uniform(-1, 1, envs[0].action_space.shape).astype(np.float32)
        observations = [env.step(action)[0] for env in envs]
    return observations


@pytest.mark.parametrize("mode", ["video_easy", "video_hard"])
def test_video_replaces_the_green_screened_sky_or_sky_and_floor(mode):
    with (
        gym.make("DMCGB/cartpole-swingup-v0", split=mode, image_size=SIZE) as env,
        gym.make("DMCGB/cartpole-swingup-v0", image_size=SIZE) as train,
    ):
        observation, train_observation = step_both([env, train], n_steps=3)
        physics = env.unwrapped.physics
        labels = segmentation(physics)
        sky = interior(labels[..., 0] == -1)
        planes = np.flatnonzero(physics.model.geom_type == mujoco.mjtGeom.mjGEOM_PLANE)
        floor = interior((labels[..., 1] == mujoco.mjtObj.mjOBJ_GEOM) & np.isin(labels[..., 0], planes))
        robot = interior((labels[..., 0] != -1) & ~np.isin(labels[..., 0], planes))
        replaced = sky | floor if mode == "video_hard" else sky
        assert sky.sum() > 50 and floor.sum() > 50
        # Episode 0 after seeding shows clip 1 (DMC-GB cycles from the second clip), frame = agent step.
        clips = dmcgb_clips(mode, SIZE, None)
        frame = clips.clip(1).frame(3)
        np.testing.assert_array_equal(observation[replaced], frame[replaced])
        # The robot is what the undistracted env drew; video_easy's floor too, shadow and reflection included.
        kept = robot | floor if mode == "video_easy" else robot
        np.testing.assert_array_equal(observation[kept], train_observation[kept])
        next_episode, _ = env.reset()
        np.testing.assert_array_equal(next_episode[replaced], clips.clip(2).frame(0)[replaced])


def test_the_green_screen_keys_dmc_gbs_hsv_box():
    # DMC-GB's rule per pixel: colorsys's HSV, hue in 100-185 degrees, saturation from 80 and value from 70 of 255.
    rng = np.random.default_rng(0)
    pixels = np.concatenate([[[51, 204, 51], [30, 69, 30], [200, 120, 60]], rng.integers(0, 256, (2000, 3))])
    expected = []
    for r, g, b in pixels:
        h, s, v = colorsys.rgb_to_hsv(r / 255, g / 255, b / 255)
        expected.append(bool(100 <= h * 360 <= 185 and 80 <= s * 255 <= 255 and 70 <= v * 255 <= 255))
    keyed = dmcgb.green_screen_mask(pixels.astype(np.uint8)[np.newaxis])[0]
    assert keyed.tolist() == expected
    assert keyed[0] and not keyed[1] and not keyed[2] and 100 < keyed.sum() < 1000


def distance_to_train(env_id, split, seeds=range(4)):
    distances = []
    with gym.make(env_id, split=split, image_size=SIZE) as env, gym.make(env_id, image_size=SIZE) as train:
        for seed in seeds:
            observation = env.reset(seed=seed)[0].astype(float)
            distances.append(np.abs(observation - train.reset(seed=seed)[0]).mean())
    return float(np.mean(distances))


@pytest.mark.slow
def test_hard_modes_are_farther_from_train_than_easy_ones():
    distances = {split: distance_to_train("DMCGB/walker-walk-v0", split) for split in dmcgb.MODES[1:]}
    assert 0 < distances["color_easy"] < distances["color_hard"]
    assert 0 < distances["video_easy"] < distances["video_hard"]


def test_procedural_clips_have_the_shipped_clips_geometry():
    easy, hard = dmcgb_clips("video_easy", 16, None), dmcgb_clips("video_hard", 16, None)
    assert (len(easy), len(hard)) == (10, 100)
    assert hard.clip(99).n_frames == DMCGB_CLIP_FRAMES["video_hard"] == 500
    frame = easy.clip(0).frame(0)
    assert frame.shape == (16, 16, 3) and frame.dtype == np.uint8 and frame.std() > 5
    assert not np.array_equal(easy.clip(0).frame(0), easy.clip(1).frame(0))


# --- DMC-GB's own data ---------------------------------------------------------------------------------


def write_clip(path, n_frames, tint, size=40):
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"mp4v"), 25, (size, size))
    for t in range(n_frames):
        frame = np.full((size, size, 3), (tint % 256, (40 * t) % 256, 255 - tint % 256), dtype=np.uint8)
        frame[: size // 2, : size // 2] = 255 - frame[: size // 2, : size // 2]
        writer.write(frame)
    writer.release()


def write_colour_set(path, offset, legacy):
    entries = [
        {
            "grid_rgb1": np.array([0.005 * i, 0.2, 0.3]),
            "grid_rgb2": np.array([0.005 * i + 0.1, 0.3, 0.4]),
            "self_rgb": np.array([offset, 0.005 * i, 0.5]),
            "skybox_rgb": np.array([0.4, 0.6, 0.008 * i]),
        }
        for i in range(100)
    ]
    torch.save(entries, path, _use_new_zipfile_serialization=not legacy)
    return entries


@pytest.fixture
def data_dir(tmp_path):
    """A folder laid out as DMC-GB's src/env/data, with tiny clips and distinctive colours."""
    write_colour_set(tmp_path / "color_easy.pt", 0.11, legacy=True)  # the shipped files' format
    write_colour_set(tmp_path / "color_hard.pt", 0.22, legacy=False)  # torch.save's default today
    for mode, count in (("video_easy", 10), ("video_hard", 100)):
        (tmp_path / mode).mkdir()
        for i in range(count):
            write_clip(tmp_path / mode / f"video{i}.mp4", n_frames=4, tint=7 * i)
    return tmp_path


def test_colour_sets_are_read_from_dmcgbs_files(data_dir):
    for mode, offset in (("color_easy", 0.11), ("color_hard", 0.22)):
        colours = read_colour_set(data_dir / f"{mode}.pt")
        assert len(colours) == 100 and colours[7]["self_rgb"][0] == offset
        with gym.make("DMCGB/finger-spin-v0", split=mode, data_dir=data_dir, obs_type="state") as env:
            env.reset(seed=0)
            index = env.unwrapped.distraction.colour_index
            physics = env.unwrapped.physics
            material = mujoco.mj_name2id(physics.model.ptr, mujoco.mjtObj.mjOBJ_MATERIAL, "self")
            np.testing.assert_allclose(physics.model.mat_rgba[material, :3], colours[index]["self_rgb"])


def test_clips_are_read_from_dmcgbs_folder_and_resized_whole(data_dir):
    capture = cv2.VideoCapture(str(data_dir / "video_hard" / "video1.mp4"))
    frames = []
    while (frame := capture.read()[1]) is not None:
        frames.append(cv2.cvtColor(cv2.resize(frame, (SIZE, SIZE), interpolation=cv2.INTER_LINEAR), cv2.COLOR_BGR2RGB))
    assert len(frames) == 4
    with gym.make("DMCGB/finger-spin-v0", split="video_hard", data_dir=data_dir, image_size=SIZE) as env:
        observations = [env.reset(seed=0)[0]] + [env.step(np.zeros(2, dtype=np.float32))[0] for _ in range(5)]
        background = interior(segmentation(env.unwrapped.physics)[..., 0] == -1)
    for step, observation in enumerate(observations):  # 6 steps of a 4-frame clip: it wraps around
        np.testing.assert_array_equal(observation[background], frames[step % 4][background])


def test_bad_data_folders_are_refused_naming_the_file(data_dir):
    (data_dir / "video_easy" / "video3.mp4").unlink()
    with pytest.raises(FileNotFoundError, match=r"data_dir: .*video_easy' lacks 1 of DMC-GB's 10 clips \(video3.mp4"):
        gym.make("DMCGB/walker-walk-v0", split="video_easy", data_dir=data_dir)
    (data_dir / "color_hard.pt").unlink()
    with pytest.raises(FileNotFoundError, match=r"data_dir: no colour file .*color_hard.pt"):
        gym.make("DMCGB/walker-walk-v0", split="color_hard", data_dir=data_dir)
    # A pickle that would run code when loaded is refused, not run.
    torch.save({"a": torch.nn.Linear(1, 1)}, data_dir / "color_hard.pt")
    with pytest.raises(ValueError, match=r"is not one of DMC-GB's colour files: .* is not allowed"):
        gym.make("DMCGB/walker-walk-v0", split="color_hard", data_dir=data_dir)
    torch.save([{"self_rgb": np.zeros(3)}] * 100, data_dir / "color_hard.pt")
    with pytest.raises(ValueError, match=r"entry 0 of .* must have exactly the keys"):
        gym.make("DMCGB/walker-walk-v0", split="color_hard", data_dir=data_dir)
