"""DCS's sky video (and DMC-GB's ``distracting_cs``, the same code) sends each frame of the episode's video to the GPU
once, at its first view, and draws later views by switching the sky's texture by name: the frames are those of
sending every frame at every view, over episodes and video changes, also past the cache's byte limit."""

import gymnasium as gym
import numpy as np
import pytest

from sgfd_envs.benchmarks.scene import cube_texture_bytes
from tests.envs.test_benchmarks_work import SMALL, davis_like

# DAVIS-like videos of 3 frames: the dynamic sky turns back at either end within a few agent steps, so frames are
# seen again soon; 4 videos (DCS's easy), so episodes change video.
SEEDS = (0, 1, 2, 3)
STEPS = 6


def step_both(cached, sent, rng):
    action = rng.uniform(-1, 1, cached.action_space.shape).astype(np.float32)
    return cached.step(action)[0], sent.step(action)[0]


@pytest.mark.parametrize("texture_cache_mb", [512, 2])
def test_frames_sent_once_are_the_frames_sent_at_every_view(tmp_path, texture_cache_mb):
    davis = davis_like(tmp_path / "480p")
    kwargs = {"split": "easy", "dynamic": True, "background_dir": davis, "image_size": SMALL}
    cached = gym.make("DCS/walker-walk-v0", texture_cache_mb=texture_cache_mb, **kwargs)
    sent = gym.make("DCS/walker-walk-v0", texture_cache_mb=0, **kwargs)
    with cached, sent:
        rng = np.random.default_rng(0)
        videos, views, first_views, held, video = set(), 0, 0, set(), None
        for seed in SEEDS:
            observations = [(cached.reset(seed=seed)[0], sent.reset(seed=seed)[0])]
            sky = cached.unwrapped.distraction.background
            textures = sky.textures
            if sky.video_index != video:
                held, video = set(), sky.video_index  # another video: its frames are sent anew
            videos.add(video)
            for step in range(STEPS + 1):
                frame = (sky.video_index, sky.frame_index)
                views += 1
                if frame not in held and len(held) < textures.capacity:
                    held.add(frame)
                    first_views += 1
                if step < STEPS:
                    observations.append(step_both(cached, sent, rng))
            for ours, theirs in observations:
                np.testing.assert_array_equal(ours, theirs)
            assert len(textures) == len(held)
        renderer = cached.unwrapped.renderer
        assert len(videos) > 1 and first_views < views, "the episodes must change video and see frames again"
        if texture_cache_mb * 2**20 >= 3 * cube_texture_bytes(sky.texture_side):
            # every frame of a video fits: a frame is sent at its first view and never again
            assert renderer.uploads == first_views
        else:
            # past the limit a frame is sent at its views, yet the held frames never again
            assert textures.capacity == 1
            assert first_views < renderer.uploads < sent.unwrapped.renderer.uploads


def test_the_cache_takes_a_non_negative_number_of_mib():
    with pytest.raises(ValueError, match=r"^texture_cache_mb must be a non-negative int"):
        gym.make("DCS/walker-walk-v0", split="easy", texture_cache_mb=-1)
