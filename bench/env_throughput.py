"""Env steps per second at 84x84, at equal pixels: each benchmark's own way of making its frames against our id
with the same render settings (dm_control's defaults: shadows, reflections, 4x multisampling), side by side in
one run, and our fast path (``render="fast"``: none of the three) beside them.

Each row steps the same task at the benchmark's action repeat with random actions. The methods of a row run in
interleaved rounds, so machine load hits them alike; each figure is the median over rounds. The benchmarks'
methods are re-implemented from their code's description, on procedural frames of their data's sizes:

- undistracted: a loop of ``dm_env.step`` and ``physics.render(84, 84, camera_id=0)`` (DMC-GB, DMC-GB2, DCS and
  dmc2gym all render so); ours is ``gym.make(id)``.
- SGFD background ids, DBC's and AMBS's dmc2gym: ``physics.render``, then the colour rule (blue > green and
  blue > red) pastes the background frame. Not the same pixels as ours (the rule keeps the skybox's stars and
  replaces bluish robot parts; ours puts the frame behind by coverage): the row compares the cost.
- DMC-GB ``video_hard``: the sky and floor textures green, ``physics.render``, the whole clip frame (video_hard's
  are 352 x 352, 500 frames) scaled to 84x84 by torch's bilinear interpolate, and the per-pixel HSV loop in Python
  (DMC-GB's ``do_green_screen``, "not optimized for speed").
- DMC-GB2 ``video_hard``: the next frame, resized (Pillow, bicubic) to 256 x 256 when the episode's clip is
  loaded, written into the screen texture and sent to the GPU every agent step, the screen moved with the torso,
  ``physics.render``.
- DCS ``hard`` dynamic (google-research): every simulator step the sky texture (800 x 800) written and sent to
  the GPU, the camera pose and every material's colour written; ``physics.render`` once per agent step.
- DMC-GB ``distracting_cs`` (0.5): as DCS, but the walks move every second simulator step, and dm_control's pixel
  wrapper inside DMC-GB's dmc2gym renders after every simulator step besides dmc2gym's own render per agent step.

The benchmarks' per-frame methods (the green screen's HSV loop, DMC-GB2's screen write and torso follow, DCS's
floor, sky write and camera pose) are ``bench/benchmark_methods.py``'s, the very functions with which
``tests/envs/test_benchmarks_pixels.py`` checks that ours and theirs make the same pixels on the same state (all rows
but the background one); this script measures the cost.

Usage: ``python bench/env_throughput.py [--steps 40] [--rounds 3]``
"""

from __future__ import annotations

import argparse
import os
import statistics
import time
from collections.abc import Callable

import benchmark_methods as methods
import gymnasium as gym
import numpy as np
import torch
import torch.nn.functional as F
from PIL import Image

from sgfd_envs import domains
from sgfd_envs.backgrounds import ProceduralBackground, make_background
from sgfd_envs.benchmarks import dcs, dmcgb, dmcgb2
from sgfd_envs.registry import task_entry

IMAGE_SIZE = 84
Stepper = Callable[[], np.ndarray]


def gym_stepper(env_id: str, seed: int = 0, **kwargs) -> Stepper:
    """One agent step of our id with a random action, resetting at episode ends; returns the observation."""
    env = gym.make(env_id, **kwargs)
    env.reset(seed=seed)
    env.action_space.seed(seed)

    def step() -> np.ndarray:
        observation, _, terminated, truncated, _ = env.step(env.action_space.sample())
        if terminated or truncated:
            env.reset()
        return observation

    return step


class Loop:
    """A dm_control task stepped the benchmarks' way: random actions, ``repeat`` simulator steps per agent step,
    ``on_control_step`` after each, a reset every 1000 simulator steps."""

    def __init__(self, dm_env, repeat: int, seed: int, on_control_step: Callable[[], None] | None = None) -> None:
        self.dm_env, self.repeat = dm_env, repeat
        self.physics = dm_env.physics
        self._rng = np.random.default_rng(seed)
        spec = dm_env.action_spec()
        self._low, self._high = spec.minimum, spec.maximum
        self._on_control_step = on_control_step
        self.control_steps = 0
        self.agent_steps = 0
        self.reset_hooks: list[Callable[[], None]] = []
        dm_env.task.random.seed(seed)
        dm_env.reset()

    def step(self) -> None:
        action = self._rng.uniform(self._low, self._high)
        for _ in range(self.repeat):
            self.dm_env.step(action)
            self.control_steps += 1
            if self._on_control_step is not None:
                self._on_control_step()
        self.agent_steps += 1
        if self.control_steps >= 1000:
            self.dm_env.reset()
            self.control_steps = self.agent_steps = 0
            for hook in self.reset_hooks:
                hook()

    def render(self) -> np.ndarray:
        return self.physics.render(IMAGE_SIZE, IMAGE_SIZE, camera_id=0)


def plain_render_stepper(domain: str, task: str, repeat: int) -> Stepper:
    loop = Loop(domains.load_suite(domain, task), repeat, seed=0)

    def step() -> np.ndarray:
        loop.step()
        return loop.render()

    return step


def colour_rule_stepper(env_id: str) -> Stepper:
    """DBC's dmc2gym: default render, the blue rule pastes the background."""
    entry = task_entry(env_id)
    loop = Loop(domains.load(entry.robot, entry.task), entry.action_repeat, seed=0)
    background = make_background("train", 0, IMAGE_SIZE, IMAGE_SIZE)

    def step() -> np.ndarray:
        loop.step()
        rendered = loop.render()
        red, green, blue = (rendered[..., c].astype(np.int16) for c in range(3))
        mask = (blue > green) & (blue > red)
        return np.where(mask[..., np.newaxis], background.frame(loop.agent_steps), rendered)

    return step


def dmcgb_video_stepper(domain: str, task: str) -> Stepper:
    """DMC-GB's video_hard (see the module docstring)."""
    dm_env = domains.load_suite(domain, task)
    dm_env.physics.reload_from_xml_string(*methods.dmcgb_green_model(domain, "video_hard"))
    loop = Loop(dm_env, dmcgb.TASKS[(domain, task)], seed=0)
    clip = ProceduralBackground(3100, 352, 352, n_frames=500)

    def step() -> np.ndarray:
        loop.step()
        rendered = loop.render()
        clip_frame = torch.from_numpy(clip.frame(loop.agent_steps)).permute(2, 0, 1).float().unsqueeze(0) / 255.0
        scaled = F.interpolate(clip_frame, size=(IMAGE_SIZE, IMAGE_SIZE), mode="bilinear", align_corners=False)
        frame = (scaled * 255.0).byte().squeeze(0).permute(1, 2, 0).numpy()
        return methods.green_screen(rendered, frame)

    return step


def dmcgb2_video_stepper(domain: str, task: str) -> Stepper:
    """DMC-GB2's video_hard (see the module docstring)."""
    dm_env = domains.load_suite(domain, task)
    dm_env.physics.reload_from_xml_string(*methods.dmcgb2_screen_model(domain))
    loop = Loop(dm_env, dmcgb2.TASKS[(domain, task)], seed=0)
    methods.dmcgb2_prepare(loop.physics, "video_hard")
    source = ProceduralBackground(3101, 352, 352, n_frames=500)
    # Resized when the clip is loaded at the episode's start (outside the timed steps here).
    frames = [methods.dmcgb2_resize(source.frame(t)) for t in range(500)]
    loop.render()

    def step() -> np.ndarray:
        loop.step()
        methods.dmcgb2_show(loop.physics, domain, frames[loop.agent_steps % len(frames)])
        return loop.render()

    return step


def dcs_stepper(domain: str, task: str, repeat: int, scale: float, every: int, renders_each_step: bool) -> Stepper:
    """The Distracting Control Suite's way (google-research: ``every`` 1; DMC-GB's distracting_cs: 2, and a render
    after every simulator step by dm_control's pixel wrapper inside dmc2gym). The random walks are sgfd_envs'
    (the same draws as DCS's); the floor, sky and camera pose are the benchmark's (``benchmark_methods``)."""
    dm_env = domains.load_suite(domain, task)
    physics = dm_env.physics
    methods.dcs_prepare(physics, domain)
    # DCS resizes every frame of the episode's video to the sky texture when the episode starts (untimed here).
    source = ProceduralBackground(4000, 120, 214, n_frames=70)
    frames = [methods.dcs_resize(source.frame(t), Image.Resampling.BILINEAR) for t in range(70)]
    upper_quadrant = domain != "reacher"
    camera = dcs.CameraWalk(physics, 0, scale, dynamic=True, upper_quadrant=upper_quadrant)
    colour = dcs.ColourWalk(physics, scale, dynamic=True)
    rng = np.random.default_rng(0)
    state = {"steps": 0, "index": 0, "direction": 1}
    start_target = np.zeros(3)

    def control_step() -> None:
        state["steps"] += 1
        if state["steps"] % every == 0:
            index = state["index"] + state["direction"]
            if index <= 0 or index >= len(frames) - 1:
                state["direction"] *= -1
            state["index"] = int(np.clip(index, 0, len(frames) - 1))
            methods.dcs_show_sky(physics, frames[state["index"]])
            camera.advance(rng)
            colour.advance(rng)
        pose = methods.dcs_camera_pose(physics, camera.spherical, camera.roll, start_target, upper_quadrant)
        methods.dcs_set_camera(physics, pose)
        if renders_each_step:
            physics.render(IMAGE_SIZE, IMAGE_SIZE, camera_id=0)

    loop = Loop(dm_env, repeat, seed=0, on_control_step=control_step)

    def start() -> None:
        start_target[:] = methods.dcs_look_at_point(physics)
        camera.start(rng)
        colour.start(rng)
        state.update(steps=0, index=int(rng.integers(len(frames))), direction=1)

    loop.reset_hooks.append(start)
    loop.render()
    start()

    def step() -> np.ndarray:
        loop.step()
        return loop.render()

    return step


def steps_per_second(step: Stepper, n_steps: int) -> float:
    start = time.perf_counter()
    for _ in range(n_steps):
        step()
    return n_steps / (time.perf_counter() - start)


def measure(methods: dict[str, Stepper], steps: int, rounds: int, warmup: int) -> dict[str, float]:
    """Median steps/s of each method over interleaved rounds."""
    for step in methods.values():
        for _ in range(warmup):
            step()
    rates: dict[str, list[float]] = {name: [] for name in methods}
    for _ in range(rounds):
        for name, step in methods.items():
            rates[name].append(steps_per_second(step, steps))
    return {name: statistics.median(values) for name, values in rates.items()}


def rows() -> dict[str, dict[str, Callable[[], Stepper]]]:
    """Per row: its methods (ours, theirs, fast) as factories, made when the row runs."""
    return {
        "undistracted walker-walk (DMCGB2 train / physics.render)": {
            "ours": lambda: gym_stepper("DMCGB2/walker-walk-v0"),
            "theirs": lambda: plain_render_stepper("walker", "walk", 2),
            "fast": lambda: gym_stepper("DMCGB2/walker-walk-v0", render="fast"),
        },
        "SGFD walker-walk background / DBC colour rule": {
            "ours": lambda: gym_stepper("SGFD/walker-walk-v0"),
            "theirs": lambda: colour_rule_stepper("SGFD/walker-walk-v0"),
            "fast": lambda: gym_stepper("SGFD/walker-walk-v0", render="fast"),
        },
        "DMC-GB walker-walk video_hard": {
            "ours": lambda: gym_stepper("DMCGB/walker-walk-v0", split="video_hard"),
            "theirs": lambda: dmcgb_video_stepper("walker", "walk"),
            "fast": lambda: gym_stepper("DMCGB/walker-walk-v0", split="video_hard", render="fast"),
        },
        "DMC-GB2 walker-walk video_hard": {
            "ours": lambda: gym_stepper("DMCGB2/walker-walk-v0", split="video_hard"),
            "theirs": lambda: dmcgb2_video_stepper("walker", "walk"),
            "fast": lambda: gym_stepper("DMCGB2/walker-walk-v0", split="video_hard", render="fast"),
        },
        "DCS walker-walk hard, dynamic": {
            "ours": lambda: gym_stepper("DCS/walker-walk-v0", split="hard", dynamic=True),
            "theirs": lambda: dcs_stepper("walker", "walk", 2, 0.3, every=1, renders_each_step=False),
            "fast": lambda: gym_stepper("DCS/walker-walk-v0", split="hard", dynamic=True, render="fast"),
        },
        "DMC-GB walker-walk distracting_cs 0.5": {
            "ours": lambda: gym_stepper("DMCGB/walker-walk-v0", split="distracting_cs", intensity=0.5),
            "theirs": lambda: dcs_stepper("walker", "walk", 4, 0.5, every=2, renders_each_step=True),
            "fast": lambda: gym_stepper("DMCGB/walker-walk-v0", split="distracting_cs", intensity=0.5, render="fast"),
        },
    }


def main(argv: list[str] | None = None) -> None:
    """Measure and print steps/s of each method of each row and our speed-ups."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=40, help="agent steps per method per round")
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--warmup", type=int, default=5, help="untimed agent steps of each method first")
    parser.add_argument("--only", nargs="+", help="rows whose name contains one of these words")
    args = parser.parse_args(argv)
    print(
        f"MUJOCO_GL={os.environ.get('MUJOCO_GL')}, {os.cpu_count()} CPUs, {IMAGE_SIZE}x{IMAGE_SIZE}, "
        f"{args.steps} agent steps x {args.rounds} interleaved rounds, median steps/s (ms per agent step)"
    )
    torch.set_num_threads(1)
    table = ["| row | ours | theirs | fast | ours / theirs | fast / theirs |", "|---|---|---|---|---|---|"]
    for name, factories in rows().items():
        if args.only and not any(word in name for word in args.only):
            continue
        medians = measure({k: make() for k, make in factories.items()}, args.steps, args.rounds, args.warmup)
        cells = "   ".join(f"{k} {v:7.1f} ({1000 / v:6.1f} ms)" for k, v in medians.items())
        ratio = medians["ours"] / medians["theirs"]
        fast = medians["fast"] / medians["theirs"]
        print(f"  {name:<56} {cells}   ours/theirs {ratio:5.2f}x   fast/theirs {fast:5.2f}x", flush=True)
        steps_per_second = " | ".join(f"{medians[k]:.1f}" for k in ("ours", "theirs", "fast"))
        table.append(f"| {name} | {steps_per_second} | {ratio:.2f}x | {fast:.2f}x |")
    print("\nsteps/s, as a table:\n", *table, sep="\n")


if __name__ == "__main__":
    from recording import run_recorded  # the bench's --record FILE

    run_recorded(main, __file__)
