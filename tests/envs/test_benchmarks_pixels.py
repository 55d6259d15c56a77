"""Every id renders as its benchmark does: the undistracted split is dm_control's ``physics.render`` (shadows,
reflections, multisampling), and each distracted mode agrees with the benchmark's own way of making the frame,
re-implemented from its description (``bench/benchmark_methods.py``, the methods bench/env_throughput.py times),
on the same state."""

import cv2
import gymnasium as gym
import numpy as np
import pytest
from PIL import Image

from bench.benchmark_methods import SIZE, dcs_look_at_point, dcs_sky, disagreement, dmcgb2_screen, dmcgb_green_screen
from sgfd_envs.backgrounds import ProceduralBackground
from sgfd_envs.benchmarks import dcs, dmcgb, dmcgb2
from sgfd_envs.benchmarks.media import DMCGB_CLIP_COUNTS

# A pixel "disagrees" when a channel is off by more than this many levels of 255; the benchmarks' modes allow at
# most MAX_DISAGREEMENT of them per frame.
LEVELS = 8
MAX_DISAGREEMENT = 0.01


def run(env, seed=0, steps=6):
    """Reset with ``seed`` and take ``steps`` steps of a fixed action sequence; the last observation."""
    env.reset(seed=seed)
    return act(env, seed, steps)


def act(env, seed, steps):
    """``steps`` (at least 1) steps of the fixed action sequence of ``seed``; the last observation."""
    rng = np.random.default_rng(seed)
    for _ in range(steps):
        observation, *_ = env.step(rng.uniform(-1, 1, env.action_space.shape).astype(np.float32))
    return observation


@pytest.mark.parametrize(
    ("env_id", "kwargs"),
    [
        ("SGFD/MT-walker-walk-v0", {}),
        ("SGFD/MT-cheetah-run-v0", {"split": "extrapolation"}),
        ("SGFD/MT-finger-spin-v0", {}),
        *[(f"DMCGB/{domain}-{task}-v0", {}) for domain, task in dmcgb.TASKS],
        ("DMCGB2/cheetah-run-v0", {}),
        ("DCS/reacher-easy-v0", {}),
    ],
)
def test_the_undistracted_split_is_dm_controls_render(env_id, kwargs):
    with gym.make(env_id, **kwargs) as env:
        observation = run(env)
        reference = env.unwrapped.physics.render(SIZE, SIZE, camera_id=0)
    # The same scene through the same MuJoCo calls: equal to the bit (the stated bound is 2 levels).
    assert np.abs(observation.astype(int) - reference).max() <= 2


def test_the_fast_path_is_the_render_without_shadows_reflections_and_multisampling():
    with gym.make("SGFD/MT-walker-walk-v0", render="fast") as fast, gym.make("SGFD/MT-walker-walk-v0") as full:
        fast_observation, full_observation = run(fast), run(full)
        physics = fast.unwrapped.physics
        assert physics.model.vis.quality.offsamples == 0
        flags = {"shadow": False, "reflection": False}
        reference = physics.render(SIZE, SIZE, camera_id=0, render_flag_overrides=flags)
    np.testing.assert_array_equal(fast_observation, reference)
    # Not the benchmarks' picture: the floor loses the walker's shadow and reflection, the edges their blend.
    assert disagreement(fast_observation, full_observation, 20) > 0.01


# --- DMC-GB ---------------------------------------------------------------------------------------------------


@pytest.mark.slow
@pytest.mark.parametrize(("domain", "task"), list(dmcgb.TASKS))
@pytest.mark.parametrize("mode", ["video_easy", "video_hard"])
def test_dmcgb_video_agrees_with_its_green_screen(domain, task, mode):
    with gym.make(f"DMCGB/{domain}-{task}-v0", split=mode) as env:
        observation = run(env, steps=5)
        distraction = env.unwrapped.distraction
        frame = distraction._clips.clip(distraction.clip_index).frame(5)
        theirs = dmcgb_green_screen(domain, mode, env.unwrapped.physics, frame)
    assert disagreement(observation, theirs, 2) == 0


# --- DMC-GB2 --------------------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def dmcgb_data(tmp_path_factory):
    """DMC-GB's data layout with clips of natural-looking moving texture (the screen's only source here)."""
    folder = tmp_path_factory.mktemp("dmcgb_data")
    for mode, count in DMCGB_CLIP_COUNTS.items():
        (folder / mode).mkdir()
        for i in range(count):
            source = ProceduralBackground(9000 + i, 120, 120, n_frames=8)
            path = str(folder / mode / f"video{i}.mp4")
            writer = cv2.VideoWriter(path, cv2.VideoWriter_fourcc(*"mp4v"), 25, (120, 120))
            for t in range(8):
                writer.write(cv2.cvtColor(source.frame(t), cv2.COLOR_RGB2BGR))
            writer.release()
    return folder


def clip_frame(path, index):
    capture = cv2.VideoCapture(str(path))
    frames = []
    while (frame := capture.read()[1]) is not None:
        frames.append(cv2.cvtColor(frame, cv2.COLOR_BGR2RGB))
    capture.release()
    return frames[index % len(frames)]


@pytest.mark.slow
@pytest.mark.parametrize("domain", sorted(dmcgb2.PROJECTORS))
@pytest.mark.parametrize("mode", ["video_easy", "video_hard"])
def test_dmcgb2_video_agrees_with_its_screen(domain, mode, dmcgb_data):
    task = next(t for d, t in dmcgb2.TASKS if d == domain)
    with gym.make(f"DMCGB2/{domain}-{task}-v0", split=mode, data_dir=dmcgb_data) as env:
        observation = run(env, steps=3)
        clip = env.unwrapped.distraction.clip_index
        frame = clip_frame(dmcgb_data / mode / f"video{clip}.mp4", 3)
        theirs = dmcgb2_screen(domain, mode, env.unwrapped.physics, frame)
    assert disagreement(observation, theirs, LEVELS) <= MAX_DISAGREEMENT


# --- the Distracting Control Suite, and DMC-GB's and DMC-GB2's distracting_cs ---------------------------------


@pytest.fixture(scope="module")
def davis(tmp_path_factory):
    """DAVIS's layout for the training list: 3 frames of natural-looking texture per video, 16:9."""
    root = tmp_path_factory.mktemp("davis") / "JPEGImages" / "480p"
    for v, name in enumerate(dcs.DAVIS_VIDEOS["train"]):
        (root / name).mkdir(parents=True)
        source = ProceduralBackground(8000 + v, 135, 240, n_frames=3)
        for t in range(3):
            assert cv2.imwrite(str(root / name / f"{t:05d}.jpg"), cv2.cvtColor(source.frame(t), cv2.COLOR_RGB2BGR))
    return root


# (benchmark's id prefix, split kwargs, Pillow's filter closest to the benchmark's resize)
SKY_CASES = {
    "DCS hard": ("DCS", {"split": "hard", "dynamic": True}, Image.Resampling.BILINEAR),
    "DMC-GB distracting_cs 0.2": ("DMCGB", {"split": "distracting_cs", "intensity": 0.2}, Image.Resampling.NEAREST),
    "DMC-GB2 distracting_cs 0.5": ("DMCGB2", {"split": "distracting_cs", "intensity": 0.5}, Image.Resampling.BICUBIC),
}


@pytest.mark.slow
@pytest.mark.parametrize("case", sorted(SKY_CASES))
@pytest.mark.parametrize("domain", ["cartpole", "walker", "finger", "ball_in_cup"])
def test_the_sky_video_agrees_with_the_suites(case, domain, davis):
    prefix, kwargs, resample = SKY_CASES[case]
    tasks = {"DCS": dcs.TASKS, "DMCGB": dmcgb.TASKS, "DMCGB2": dmcgb2.TASKS}[prefix]
    task = next(t for d, t in tasks if d == domain)
    with gym.make(f"{prefix}/{domain}-{task}-v0", background_dir=davis, **kwargs) as env:
        physics = env.unwrapped.physics
        env.reset(seed=0)
        # DCS aims a fixed camera at the point its unmoved view looks at when the episode starts.
        start_target = dcs_look_at_point(physics)
        observation = act(env, seed=0, steps=3)
        distraction = env.unwrapped.distraction
        background = distraction.background
        name = dcs.DAVIS_VIDEOS["train"][background.video_index]
        frame = np.asarray(Image.open(davis / name / f"{background.frame_index:05d}.jpg"))
        # The walks' drawn state; the floor's alpha and the camera's pose the reference works out by itself.
        camera = (distraction.camera.spherical, distraction.camera.roll, start_target)
        theirs = dcs_sky(domain, physics, frame, distraction.colour.current, camera, resample)
    assert disagreement(observation, theirs, LEVELS) <= MAX_DISAGREEMENT
