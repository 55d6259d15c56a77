"""A distraction does only the work a frame shows: its walks and random streams move at every simulator step whether
frames are rendered or not, and it touches the scene (colours, textures, poses) only for a render; an agent step
sends at most one texture to the GPU and reads one frame back; a video texture holds only the mip levels a frame
reads."""

import cv2
import gymnasium as gym
import numpy as np
import pytest

from sgfd_envs.backgrounds import ImageBackground, halve
from sgfd_envs.benchmarks import dcs, dmcgb2

SIZE = 84
# The work tests' frames (the rule that picks a texture's mip level is checked at SIZE).
SMALL = 48
# Distracted splits, moving at every (or every second) simulator step or once an episode, and the textures an
# agent step sends: a new sky or screen frame each step, nothing where the video is composited on the CPU (DMC-GB's
# green screen, SGFD's backgrounds) or the distraction changes once an episode.
SPLITS = {
    "DCS hard dynamic": ("DCS/walker-walk-v0", {"split": "hard", "dynamic": True}, 1),
    "DCS medium static": ("DCS/cartpole-swingup-v0", {"split": "medium"}, 0),
    "DMC-GB distracting_cs": ("DMCGB/walker-walk-v0", {"split": "distracting_cs", "intensity": 0.5}, 1),
    "DMC-GB video_hard": ("DMCGB/walker-walk-v0", {"split": "video_hard"}, 0),
    "DMC-GB color_hard": ("DMCGB/finger-spin-v0", {"split": "color_hard"}, 0),
    "DMC-GB2 color_video_hard": ("DMCGB2/cheetah-run-v0", {"split": "color_video_hard"}, 1),
    "DMC-GB2 rotate_shift_hard": ("DMCGB2/finger-spin-v0", {"split": "rotate_shift_hard"}, 0),
    "SGFD background": ("SGFD/walker-walk-v0", {"split": "test"}, 0),
}


def equal(a, b) -> bool:
    """Nested dicts, lists and arrays of the same values."""
    if isinstance(a, dict):
        return a.keys() == b.keys() and all(equal(a[k], b[k]) for k in a)
    if isinstance(a, (list, tuple)):
        return len(a) == len(b) and all(equal(x, y) for x, y in zip(a, b, strict=True))
    return bool(np.array_equal(a, b))


@pytest.mark.parametrize("split", sorted(SPLITS))
def test_a_distraction_moves_unseen_and_touches_the_scene_only_for_a_frame(split):
    env_id, kwargs, uploads_per_step = SPLITS[split]
    rendered = gym.make(env_id, image_size=SMALL, **kwargs)
    unseen = gym.make(env_id, image_size=SMALL, obs_type="state", render_mode="rgb_array", **kwargs)
    with rendered, unseen:
        rng = np.random.default_rng(0)
        for episode in range(2):
            rendered.reset(seed=3 if episode == 0 else None)
            unseen.reset(seed=3 if episode == 0 else None)
            renderer = rendered.unwrapped.renderer
            uploads, readbacks = renderer.uploads, renderer.readbacks
            colours = unseen.unwrapped.physics.model.mat_rgba.copy()
            for _ in range(4):
                action = rng.uniform(-1, 1, rendered.action_space.shape).astype(np.float32)
                observation = rendered.step(action)[0]
                unseen.step(action)
                # no frame, no colour set: the model's colours stay as the reset left them
                np.testing.assert_array_equal(unseen.unwrapped.physics.model.mat_rgba, colours)
            # an agent step sends at most one texture to the GPU and reads one frame back
            assert (renderer.uploads - uploads, renderer.readbacks - readbacks) == (4 * uploads_per_step, 4)
            assert equal(rendered.unwrapped.get_state(), unseen.unwrapped.get_state())
            # the frame the unrendered env draws now is the one the env that rendered every step shows
            np.testing.assert_array_equal(unseen.render(), observation)


def textured(rng, height, width):
    """A uint8 RGB picture with detail at every scale: smooth colour fields plus pixel noise."""
    coarse = rng.integers(0, 256, (height // 40, width // 40, 3)).astype(np.uint8)
    smooth = cv2.resize(coarse, (width, height), interpolation=cv2.INTER_CUBIC).astype(int)
    return np.clip(smooth + rng.integers(-40, 40, (height, width, 3)), 0, 255).astype(np.uint8)


def davis_like(folder, n_videos=4):
    """DAVIS's layout for the first videos of DCS's training list: 3 frames of 480p, 16:9."""
    rng = np.random.default_rng(0)
    for name in dcs.DAVIS_VIDEOS["train"][:n_videos]:
        (folder / name).mkdir(parents=True)
        for t in range(3):
            assert cv2.imwrite(str(folder / name / f"{t:05d}.jpg"), textured(rng, 480, 854))
    return folder


@pytest.mark.parametrize("env_id", ["DCS/walker-walk-v0", "DCS/finger-spin-v0"])
def test_the_sky_texture_gives_the_frame_of_dcss_800_px_sky(env_id, tmp_path):
    davis = davis_like(tmp_path / "480p")
    with gym.make(env_id, split="easy", background_dir=davis, distractions=("background",)) as env:
        env.reset(seed=0)
        observation = env.step(env.action_space.sample())[0]
        unwrapped = env.unwrapped
        background = unwrapped.distraction.background
        assert background._sky.original_shape[1] == 800 and dcs.sky_texture_side(SIZE) == 400
        name = dcs.DAVIS_VIDEOS["train"][background.video_index]
        frames = sorted((davis / name).iterdir())
        whole = ImageBackground(frames, 800, 800, crop=False, interpolation=dcs.RESIZE).frame(background.frame_index)
        background._sky.write(whole, whole.shape[:2])
        background._sky.upload_if_changed(unwrapped.renderer)
        from_whole = unwrapped.renderer.render()
    # Equal but for the rounding of the first average (the GPU's and OpenCV's), which moves a pixel by a level.
    difference = np.abs(observation.astype(int) - from_whole).max(axis=-1)
    assert difference.max() <= 2 and (difference > 1).mean() < 0.005, "the 400 px sky is not the 800 px sky's frame"


@pytest.mark.parametrize("domain", ["walker", "finger"])
def test_the_screen_texture_gives_the_frame_of_dmcgb2s_256_px_screen(domain):
    task = next(t for d, t in dmcgb2.TASKS if d == domain)
    with gym.make(f"DMCGB2/{domain}-{task}-v0", split="video_easy") as env:
        env.reset(seed=0)
        env.step(env.action_space.sample())
        unwrapped = env.unwrapped
        distraction, renderer = unwrapped.distraction, unwrapped.renderer
        texture = dmcgb2.projector_texture(SIZE)
        assert (texture.side, distraction._screen_side) == (128, 128)
        clip_frame = textured(np.random.default_rng(0), 352, 352)
        whole = cv2.resize(clip_frame, (256, 256), interpolation=texture.interpolation)
        overrides = [(unwrapped.physics.data.site_xpos, distraction._screen_site, distraction.screen_position())]
        frames = []
        for image in (halve(whole, texture.halvings), whole, np.zeros_like(whole)):
            distraction._screen.write(image, image.shape[:2])
            distraction._screen.upload_if_changed(renderer)
            frames.append(renderer.render(overrides).astype(int))
    ours, from_whole, blank = frames
    # A texel's rounding (a level) times the screen's lighting: up to two levels.
    assert np.abs(ours - from_whole).max() <= 2, "the 128 px screen is not the 256 px screen's frame"
    assert (np.abs(from_whole - blank).max(axis=-1) > 8).mean() > 0.1  # the screen is in view
