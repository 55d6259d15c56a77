"""Env steps per second at 84x84: sgfd_envs against the prior practice, measured in one run.

Prior practice (DBC/AMBS's dmc2gym): dm_control's ``physics.render(84, 84, camera_id=0)`` with its
default flags (shadows, reflections, 4x multisampling; a new Camera every call), then the colour
rule (blue > green and blue > red) to paste the background frame. Ours: one reused scene, shadows,
reflections and multisampling off, colour and depth read in one pass, depth mask. Both use the same
physics, action repeat and background frames; the methods run in interleaved rounds so machine load
hits both alike, and each figure is the median over rounds.

Each benchmark id is measured against its own benchmark's method, re-implemented from its description on the
same physics and the same procedural frames:

- DMC-GB ``video_hard``: the sky and floor painted green ([.2, .8, .2]), dm_control's default render, then a
  per-pixel Python loop converting each pixel to HSV and replacing those with hue 100-185 degrees, saturation
  80-255 and value 70-255 by the video frame resized (bilinear) to the observation (DMC-GB's
  ``do_green_screen``, "not optimized for speed").
- DMC-GB2 ``video_hard``: the video frame written into the screen's 256x256 cube texture and sent to the GPU
  every agent step, the screen moved with the torso, the floor invisible, dm_control's default render.
- DCS ``hard``, dynamic: every simulator step the background frame (pre-resized to the 800x800 sky texture)
  sent to the GPU, the camera pose and every material colour written into the model; dm_control's default
  render once per agent step.

Usage: ``python bench/env_throughput.py [--steps 300] [--rounds 3] [--env SGFD/walker-walk-v0]``
"""

from __future__ import annotations

import argparse
import colorsys
import os
import statistics
import time
from collections.abc import Callable

import cv2
import gymnasium as gym
import mujoco
import numpy as np

import sgfd_envs
from sgfd_envs import domains
from sgfd_envs.backgrounds import ProceduralBackground, composite, make_background
from sgfd_envs.benchmarks import dcs, dmcgb, dmcgb2
from sgfd_envs.benchmarks.scene import TextureSlot, object_id, rgb_attribute, suite_texture_data
from sgfd_envs.registry import task_entry

IMAGE_SIZE = 84


def gym_stepper(env: gym.Env, seed: int) -> Callable[[], None]:
    """One agent step of a gymnasium env with a random action, resetting at episode ends."""
    env.reset(seed=seed)
    env.action_space.seed(seed)

    def step() -> None:
        *_, terminated, truncated, _ = env.step(env.action_space.sample())
        if terminated or truncated:
            env.reset()

    return step


def prior_practice_stepper(env_id: str, seed: int) -> Callable[[], None]:
    """One agent step the DBC way: repeat the action, render with default flags, colour-rule composite."""
    entry = task_entry(env_id)
    dm_env = domains.load(entry.robot, entry.task)
    background = make_background("train", 0, IMAGE_SIZE, IMAGE_SIZE)
    rng = np.random.default_rng(seed)
    action_spec = dm_env.action_spec()
    state = {"control_steps": 0, "frame": 0}

    def reset() -> None:
        dm_env.reset()
        state["control_steps"] = 0
        state["frame"] = int(rng.integers(background.n_frames))

    def step() -> None:
        action = rng.uniform(action_spec.minimum, action_spec.maximum)
        for _ in range(entry.action_repeat):
            dm_env.step(action)
            state["control_steps"] += 1
        rendered = dm_env.physics.render(IMAGE_SIZE, IMAGE_SIZE, camera_id=0)
        red, green, blue = (rendered[..., channel].astype(np.int16) for channel in range(3))
        composite(rendered, (blue > green) & (blue > red), background.frame(state["frame"]))
        state["frame"] += 1
        if state["control_steps"] >= 1000:
            reset()

    reset()
    return step


def _random_actions(dm_env, seed: int) -> Callable[[], np.ndarray]:
    rng = np.random.default_rng(seed)
    spec = dm_env.action_spec()
    return lambda: rng.uniform(spec.minimum, spec.maximum)


def _upload(physics, texture_id: int) -> None:
    with physics.contexts.gl.make_current() as ctx:
        ctx.call(mujoco.mjr_uploadTexture, physics.model.ptr, physics.contexts.mujoco.ptr, texture_id)


# DMC-GB's green screen: the colour it paints the sky and floor, and the HSV box it keys out.
_GREEN = (0.2, 0.8, 0.2)
_HSV_LOW, _HSV_HIGH = (100, 80, 70), (185, 255, 255)


def _green_screen_per_pixel(rendered: np.ndarray, background: np.ndarray) -> np.ndarray:
    """DMC-GB's keying as it describes it: every pixel to HSV in Python, the green ones replaced."""
    out = rendered.copy()
    height, width = rendered.shape[:2]
    for row in range(height):
        for col in range(width):
            r, g, b = rendered[row, col]
            h, s, v = colorsys.rgb_to_hsv(r / 255.0, g / 255.0, b / 255.0)
            h, s, v = h * 360, s * 255, v * 255
            if (
                _HSV_LOW[0] <= h <= _HSV_HIGH[0]
                and _HSV_LOW[1] <= s <= _HSV_HIGH[1]
                and _HSV_LOW[2] <= v <= _HSV_HIGH[2]
            ):
                out[row, col] = background[row, col]
    return out


def dmcgb_video_stepper(domain: str, task: str, seed: int) -> Callable[[], None]:
    """One agent step of DMC-GB's video_hard the DMC-GB way (see the module docstring)."""
    dm_env = domains.load_suite(domain, task)
    physics = dm_env.physics
    green = rgb_attribute(_GREEN)
    sky, grid = TextureSlot(physics, "skybox"), TextureSlot(physics, "grid")
    sky.write(suite_texture_data("skybox", rgb1=green, rgb2=green, markrgb=green))
    grid.write(suite_texture_data("grid", rgb1=green, rgb2=green, markrgb=green))
    physics.render(IMAGE_SIZE, IMAGE_SIZE, camera_id=0)  # makes the context the textures go to
    _upload(physics, sky.texture_id)
    _upload(physics, grid.texture_id)
    repeat = dmcgb.TASKS[(domain, task)]
    clip = ProceduralBackground(3100, 352, 352, n_frames=500)  # a video_hard clip's size and length
    action = _random_actions(dm_env, seed)
    state = {"control_steps": 0, "frame": 0}

    def step() -> None:
        command = action()
        for _ in range(repeat):
            dm_env.step(command)
            state["control_steps"] += 1
        rendered = physics.render(IMAGE_SIZE, IMAGE_SIZE, camera_id=0)
        frame = cv2.resize(clip.frame(state["frame"]), (IMAGE_SIZE, IMAGE_SIZE), interpolation=cv2.INTER_LINEAR)
        _green_screen_per_pixel(rendered, frame)
        state["frame"] += 1
        if state["control_steps"] >= 1000:
            dm_env.reset()
            state.update(control_steps=0, frame=0)

    dm_env.reset()
    return step


def dmcgb2_video_stepper(domain: str, task: str, seed: int) -> Callable[[], None]:
    """One agent step of DMC-GB2's video_hard the DMC-GB2 way (see the module docstring)."""
    side = dmcgb2.PROJECTOR_TEXTURE_SIDE
    dm_env = dmcgb2.load_with_projector(domain, task, side)
    physics = dm_env.physics
    screen = TextureSlot(physics, "video_screen")
    site = object_id(physics, mujoco.mjtObj.mjOBJ_SITE, "video_screen")
    torso = object_id(physics, mujoco.mjtObj.mjOBJ_BODY, "torso")
    follow = dmcgb2.PROJECTOR_FOLLOWS.get(domain)
    physics.model.mat_rgba[object_id(physics, mujoco.mjtObj.mjOBJ_MATERIAL, "grid"), 3] = 0.0
    clip = ProceduralBackground(3101, side, side, n_frames=500)
    action = _random_actions(dm_env, seed)
    repeat = dmcgb2.TASKS[(domain, task)]
    physics.render(IMAGE_SIZE, IMAGE_SIZE, camera_id=0)
    state = {"control_steps": 0, "frame": 0}

    def step() -> None:
        command = action()
        for _ in range(repeat):
            dm_env.step(command)
            state["control_steps"] += 1
        screen.write(clip.frame(state["frame"]), (side, side))
        _upload(physics, screen.texture_id)
        if follow is not None:
            physics.data.site_xpos[site, 0] = physics.data.subtree_com[torso, 0] + follow[0]
            physics.data.site_xpos[site, 2] = physics.data.subtree_com[torso, 2] + follow[1]
        physics.render(IMAGE_SIZE, IMAGE_SIZE, camera_id=0)
        state["frame"] += 1
        if state["control_steps"] >= 1000:
            dm_env.reset()
            state.update(control_steps=0, frame=0)

    dm_env.reset()
    return step


def dcs_stepper(domain: str, task: str, seed: int) -> Callable[[], None]:
    """One agent step of DCS hard, dynamic, the DCS way (see the module docstring)."""
    dm_env = domains.load_suite(domain, task)
    physics = dm_env.physics
    side = dcs.SKY_TEXTURE_SIDE
    sky = TextureSlot(physics, "skybox")
    scale = dcs.DIFFICULTY_SCALE["hard"]
    physics.model.mat_rgba[object_id(physics, mujoco.mjtObj.mjOBJ_MATERIAL, "grid"), 3] = dcs.GROUND_ALPHA.get(
        domain, dcs.DEFAULT_GROUND_ALPHA
    )
    # DCS resizes every frame of the episode's video to the sky texture at reset.
    source = ProceduralBackground(4000, 120, 214, n_frames=70)
    frames = [cv2.resize(source.frame(t), (side, side), interpolation=cv2.INTER_LINEAR) for t in range(70)]
    camera = dcs.CameraWalk(physics, 0, scale, dynamic=True, upper_quadrant=domain != "reacher")
    colour = dcs.ColourWalk(physics, scale, dynamic=True)
    rng = np.random.default_rng(seed)
    action = _random_actions(dm_env, seed)
    repeat = dcs.TASKS[(domain, task)]
    physics.render(IMAGE_SIZE, IMAGE_SIZE, camera_id=0)
    state = {"control_steps": 0, "index": 0, "direction": 1}

    def reset() -> None:
        dm_env.reset()
        camera.start(rng)
        colour.start(rng)
        state.update(control_steps=0, index=int(rng.integers(len(frames))), direction=1)

    def step() -> None:
        command = action()
        for _ in range(repeat):
            dm_env.step(command)
            state["control_steps"] += 1
            index = state["index"] + state["direction"]
            if index <= 0 or index >= len(frames) - 1:
                state["direction"] *= -1
            state["index"] = int(np.clip(index, 0, len(frames) - 1))
            sky.write(frames[state["index"]], (side, side))
            _upload(physics, sky.texture_id)
            camera.advance(rng)
            position, orientation = camera.pose()
            physics.data.cam_xpos[0], physics.data.cam_xmat[0] = position, orientation.reshape(-1)
            colour.advance(rng)
        physics.render(IMAGE_SIZE, IMAGE_SIZE, camera_id=0)
        if state["control_steps"] >= 1000:
            reset()

    reset()
    return step


def steps_per_second(step: Callable[[], None], n_steps: int) -> float:
    """Agent steps per second over ``n_steps`` calls."""
    start = time.perf_counter()
    for _ in range(n_steps):
        step()
    return n_steps / (time.perf_counter() - start)


def main(argv: list[str] | None = None) -> None:
    """Measure and print steps/s of each method and the speed-up."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--env", default="SGFD/walker-walk-v0", help="background id to compare")
    parser.add_argument("--mt-env", default="SGFD/MT-walker-walk-v0", help="MT id measured alongside")
    parser.add_argument("--steps", type=int, default=300, help="agent steps per method per round")
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument(
        "--benchmark-steps", type=int, default=100, help="agent steps per round of each benchmark row (theirs are slow)"
    )
    parser.add_argument("--warmup", type=int, default=20, help="untimed agent steps of each method first")
    args = parser.parse_args(argv)
    if task_entry(args.env).variation != "background":
        parser.error(f"--env must be a background id, one of {[i for i in sgfd_envs.SGFD_IDS if '/MT-' not in i]}")

    methods = {
        f"ours   {args.env} (pixels, procedural background)": gym_stepper(gym.make(args.env), seed=0),
        f"prior  {args.env} (default render + colour rule)": prior_practice_stepper(args.env, seed=0),
        f"ours   {args.mt_env} (pixels)": gym_stepper(gym.make(args.mt_env), seed=0),
    }
    for step in methods.values():  # warm-up: contexts, caches, background textures
        for _ in range(args.warmup):
            step()
    rates: dict[str, list[float]] = {name: [] for name in methods}
    for _ in range(args.rounds):
        for name, step in methods.items():
            rates[name].append(steps_per_second(step, args.steps))

    print(
        f"MUJOCO_GL={os.environ.get('MUJOCO_GL')}, {os.cpu_count()} CPUs, {IMAGE_SIZE}x{IMAGE_SIZE}, "
        f"{args.steps} agent steps x {args.rounds} interleaved rounds, median"
    )
    medians = {name: statistics.median(values) for name, values in rates.items()}
    for name, median in medians.items():
        print(f"  {name:<62} {median:8.1f} steps/s  ({1000 / median:6.2f} ms/step)")
    ours, prior = list(medians.values())[:2]
    print(f"  speed-up of ours over the prior practice: {ours / prior:.1f}x (goal >= 3x)")

    # Each benchmark against its own method, walker-walk (in all three), interleaved rounds as above.
    pairs = {
        "DMC-GB video_hard": (
            gym_stepper(gym.make("DMCGB/walker-walk-v0", split="video_hard"), seed=0),
            dmcgb_video_stepper("walker", "walk", seed=0),
        ),
        "DMC-GB2 video_hard": (
            gym_stepper(gym.make("DMCGB2/walker-walk-v0", split="video_hard"), seed=0),
            dmcgb2_video_stepper("walker", "walk", seed=0),
        ),
        "DCS hard, dynamic": (
            gym_stepper(gym.make("DCS/walker-walk-v0", split="hard", dynamic=True), seed=0),
            dcs_stepper("walker", "walk", seed=0),
        ),
    }
    for ours_step, theirs_step in pairs.values():
        for step in (ours_step, theirs_step):
            for _ in range(min(5, args.warmup)):
                step()
    pair_rates: dict[str, tuple[list[float], list[float]]] = {name: ([], []) for name in pairs}
    for _ in range(args.rounds):
        for name, (ours_step, theirs_step) in pairs.items():
            pair_rates[name][0].append(steps_per_second(ours_step, args.benchmark_steps))
            pair_rates[name][1].append(steps_per_second(theirs_step, args.benchmark_steps))
    print(
        f"benchmark ids (walker-walk, each at its benchmark's action repeat) against their own method, "
        f"{args.benchmark_steps} agent steps x {args.rounds} interleaved rounds, median"
    )
    for name, (ours_rates, theirs_rates) in pair_rates.items():
        ours_median, theirs_median = statistics.median(ours_rates), statistics.median(theirs_rates)
        print(
            f"  {name:<20} ours {ours_median:7.1f} steps/s ({1000 / ours_median:6.2f} ms)   theirs "
            f"{theirs_median:7.1f} steps/s ({1000 / theirs_median:6.2f} ms)   {ours_median / theirs_median:5.1f}x"
        )


if __name__ == "__main__":
    main()
