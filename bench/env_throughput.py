"""Env steps per second at 84x84, at equal pixels: each benchmark's own way of making its frames against our id
with the same render settings (dm_control's defaults: shadows, reflections, 4x multisampling), side by side in
one run, and our fast path (``render="fast"``: none of the three) beside them. Each distracted row also runs our
undistracted split of the same task (its ``train``, same action repeat and render) and prints what the distraction
costs over it (``ours/undistracted``, time per agent step), with the textures our env sent to the GPU and the
frames it read back per agent step; the sky video rows also run ours with ``texture_cache_mb=0`` (``uncached``:
every new sky frame sent to the GPU, as before the sky's frames were held there).

Each row steps the same task at the benchmark's action repeat with random actions. The methods of a row run in
interleaved rounds, so machine load hits them alike; each figure is the mean over all timed steps (their total
time over their number). A stepper goes on from where its last round stopped, resetting at episode ends. DCS's sky
(also ``distracting_cs``'s) sends a video frame to the GPU at its first view in the episode's video only, so its
early steps cost more than its later ones: timed steps covering whole episodes (``--steps 250 --rounds 2``: one
DCS episode, two ``distracting_cs`` episodes) give the cost per agent step of training. The benchmarks' methods are
re-implemented from their code's description, on procedural frames of their data's sizes:

- undistracted: a loop of ``dm_env.step`` and ``physics.render(84, 84, camera_id=0)`` (DMC-GB, DMC-GB2, DCS and
  dmc2gym all render so); ours is ``gym.make(id)``.
- SGFD background ids, DBC's and AMBS's dmc2gym: ``physics.render``, then the colour rule (blue > green and
  blue > red) pastes the background frame (a moving texture, on dm_control's robot). Ours is the id's default since
  version 0.3.0, the SGFD authors' setup: the same rule pasting a still image into the render of their local robot
  files (before: the frame behind the robot by coverage). Not the same pixels: the row compares the cost.
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

``--every-split`` adds a table of every distracted split of walker-walk in DCS, DMC-GB and DMC-GB2 against the
undistracted split of its family (ours only, interleaved), ``--memory`` what the sky's frames held on the GPU take
(the process's resident memory, where llvmpipe keeps textures, and the GPU's used memory where nvidia-smi is).

Usage: ``python bench/env_throughput.py [--steps 40] [--rounds 3]``; on a GPU (EGL), whole episodes of every row and
split in a few minutes: ``python bench/env_throughput.py --steps 250 --rounds 2 --warmup 3 --every-split --memory``;
the cost of the sky videos alone: ``--only DCS distracting_cs --methods ours undistracted``.
"""

from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import time
from collections.abc import Callable
from typing import cast

import benchmark_methods as methods
import gymnasium as gym
import numpy as np
import torch
import torch.nn.functional as F
from PIL import Image

from sgfd_envs import domains
from sgfd_envs.backgrounds import ProceduralBackground, make_background
from sgfd_envs.benchmarks import dcs, dmcgb, dmcgb2
from sgfd_envs.benchmarks.scene import cube_texture_bytes
from sgfd_envs.dmc import DMCEnv
from sgfd_envs.registry import task_entry

IMAGE_SIZE = 84
Stepper = Callable[[], np.ndarray]
# Each row's methods; "uncached" (the sky rows): ours with texture_cache_mb=0, every new sky frame sent to the GPU.
METHODS = ("ours", "theirs", "fast", "undistracted", "uncached")


class GymStepper:
    """One agent step of our id with a random action per call, resetting at episode ends; returns the observation.
    Counts the steps and, through the env's renderer, the textures sent to the GPU and the frames read back."""

    def __init__(self, env_id: str, seed: int = 0, **kwargs) -> None:
        self.env = gym.make(env_id, **kwargs)
        self.env.reset(seed=seed)
        self.env.action_space.seed(seed)
        self.steps = 0
        self._start = self._transferred()

    def __call__(self) -> np.ndarray:
        observation, _, terminated, truncated, _ = self.env.step(self.env.action_space.sample())
        if terminated or truncated:
            self.env.reset()
        self.steps += 1
        return observation

    def _transferred(self) -> tuple[int, int]:
        renderer = cast(DMCEnv, self.env.unwrapped).renderer
        assert renderer is not None  # made by the reset's frame
        return renderer.uploads, renderer.readbacks

    def transfers(self) -> tuple[float, float]:
        """Textures sent and frames read back per agent step so far."""
        (uploads, readbacks), (start_uploads, start_readbacks) = self._transferred(), self._start
        return (uploads - start_uploads) / max(self.steps, 1), (readbacks - start_readbacks) / max(self.steps, 1)

    def held_textures(self) -> tuple[int, float]:
        """Video frames the env holds on the GPU now, and their MB (as :func:`cube_texture_bytes` counts them)."""
        distraction = cast(DMCEnv, self.env.unwrapped).distraction
        sky = getattr(distraction, "background", None)
        if not isinstance(sky, dcs.SkyVideo):
            return 0, 0.0
        return len(sky.textures), len(sky.textures) * cube_texture_bytes(sky.texture_side) / 1e6

    def close(self) -> None:
        self.env.close()


def gym_stepper(env_id: str, seed: int = 0, **kwargs) -> GymStepper:
    """:class:`GymStepper` of our id."""
    return GymStepper(env_id, seed, **kwargs)


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
    """Steps/s of each method over interleaved rounds: all its timed steps over their total time."""
    for step in methods.values():
        for _ in range(warmup):
            step()
    seconds = dict.fromkeys(methods, 0.0)
    for _ in range(rounds):
        for name, step in methods.items():
            seconds[name] += steps / steps_per_second(step, steps)
    return {name: rounds * steps / total for name, total in seconds.items()}


def rows() -> dict[str, dict[str, Callable[[], Stepper]]]:
    """Per row: its methods (ours, theirs, fast, and for a distracted row our undistracted split of the same task)
    as factories, made when the row runs."""
    # The undistracted split of each benchmark's walker-walk (its train split: its action repeat, dm_control's render).
    dmcgb2_train = "DMCGB2/walker-walk-v0"  # action repeat 2, as the SGFD ids'
    return {
        "undistracted walker-walk (DMCGB2 train / physics.render)": {
            "ours": lambda: gym_stepper(dmcgb2_train),
            "theirs": lambda: plain_render_stepper("walker", "walk", 2),
            "fast": lambda: gym_stepper(dmcgb2_train, render="fast"),
        },
        "SGFD walker-walk background / DBC colour rule": {
            "ours": lambda: gym_stepper("SGFD/walker-walk-v0"),
            "theirs": lambda: colour_rule_stepper("SGFD/walker-walk-v0"),
            "fast": lambda: gym_stepper("SGFD/walker-walk-v0", render="fast"),
            "undistracted": lambda: gym_stepper(dmcgb2_train),
        },
        "DMC-GB walker-walk video_hard": {
            "ours": lambda: gym_stepper("DMCGB/walker-walk-v0", split="video_hard"),
            "theirs": lambda: dmcgb_video_stepper("walker", "walk"),
            "fast": lambda: gym_stepper("DMCGB/walker-walk-v0", split="video_hard", render="fast"),
            "undistracted": lambda: gym_stepper("DMCGB/walker-walk-v0"),
        },
        "DMC-GB2 walker-walk video_hard": {
            "ours": lambda: gym_stepper("DMCGB2/walker-walk-v0", split="video_hard"),
            "theirs": lambda: dmcgb2_video_stepper("walker", "walk"),
            "fast": lambda: gym_stepper("DMCGB2/walker-walk-v0", split="video_hard", render="fast"),
            "undistracted": lambda: gym_stepper(dmcgb2_train),
        },
        "DCS walker-walk hard, dynamic": {
            "ours": lambda: gym_stepper("DCS/walker-walk-v0", split="hard", dynamic=True),
            "theirs": lambda: dcs_stepper("walker", "walk", 2, 0.3, every=1, renders_each_step=False),
            "fast": lambda: gym_stepper("DCS/walker-walk-v0", split="hard", dynamic=True, render="fast"),
            "undistracted": lambda: gym_stepper("DCS/walker-walk-v0"),
            "uncached": lambda: gym_stepper("DCS/walker-walk-v0", split="hard", dynamic=True, texture_cache_mb=0),
        },
        "DMC-GB walker-walk distracting_cs 0.5": {
            "ours": lambda: gym_stepper("DMCGB/walker-walk-v0", split="distracting_cs", intensity=0.5),
            "theirs": lambda: dcs_stepper("walker", "walk", 4, 0.5, every=2, renders_each_step=True),
            "fast": lambda: gym_stepper("DMCGB/walker-walk-v0", split="distracting_cs", intensity=0.5, render="fast"),
            "undistracted": lambda: gym_stepper("DMCGB/walker-walk-v0"),
            "uncached": lambda: gym_stepper(
                "DMCGB/walker-walk-v0", split="distracting_cs", intensity=0.5, texture_cache_mb=0
            ),
        },
    }


def every_split() -> dict[str, tuple[str, dict[str, dict]]]:
    """Per family: the walker-walk id and the kwargs of each distracted split (its undistracted split is ``train``)."""
    dcs_splits = {
        f"{split}{', dynamic' if dynamic else ''}": {"split": split, "dynamic": dynamic}
        for split in dcs.DIFFICULTIES
        for dynamic in (False, True)
    }
    distracting_cs = {f"distracting_cs {i}": {"split": "distracting_cs", "intensity": i} for i in dmcgb.INTENSITIES}
    return {
        "DCS": ("DCS/walker-walk-v0", dcs_splits),
        "DMC-GB": ("DMCGB/walker-walk-v0", {**{m: {"split": m} for m in dmcgb.MODES[1:]}, **distracting_cs}),
        "DMC-GB2": ("DMCGB2/walker-walk-v0", {**{m: {"split": m} for m in dmcgb2.MODES[1:]}, **distracting_cs}),
    }


def print_every_split(steps: int, rounds: int, warmup: int, only: list[str] | None) -> None:
    """Each distracted split against its family's undistracted walker-walk, in interleaved rounds (one distracted env
    at a time), with our transfers per agent step and the video frames held on the GPU at the end."""
    print("every distracted split of walker-walk, ours against the family's undistracted split (train)")
    for family, (env_id, splits) in every_split().items():
        chosen = {k: v for k, v in splits.items() if not only or any(word in f"{family} {k}" for word in only)}
        if not chosen:
            continue
        undistracted = gym_stepper(env_id)
        for label, kwargs in chosen.items():
            ours = gym_stepper(env_id, **kwargs)
            rates = measure({"ours": ours, "undistracted": undistracted}, steps, rounds, warmup)
            uploads, readbacks = ours.transfers()
            frames, megabytes = ours.held_textures()
            cost = rates["undistracted"] / rates["ours"]
            print(
                f"  {family + ' ' + label:<36} ours {1000 / rates['ours']:6.1f} ms   undistracted "
                f"{1000 / rates['undistracted']:6.1f} ms   ours/undistracted {cost:5.2f}x   uploads {uploads:.2f} "
                f"readbacks {readbacks:.2f} per step   sky frames held {frames} ({megabytes:.0f} MB)"
            )
            ours.close()
        undistracted.close()


def gpu_memory_mb() -> float | None:
    """The GPU's used memory in MB (nvidia-smi's first GPU), None without nvidia-smi."""
    if shutil.which("nvidia-smi") is None:
        return None
    query = ["nvidia-smi", "--query-gpu=memory.used", "--format=csv,noheader,nounits", "--id=0"]
    return float(subprocess.run(query, capture_output=True, text=True, check=True).stdout.split()[0]) * 2**20 / 1e6


def resident_mb() -> float:
    """This process's resident memory in MB (Linux)."""
    with open("/proc/self/statm") as statm:
        return int(statm.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 1e6


def print_memory() -> None:
    """What one env's sky frames take: DCS hard dynamic walker-walk stepped through an episode (its video's frames
    all seen) beside the same env made with texture_cache_mb=0, in lockstep on the same seed (the same video and
    frames), each step's growth of the process's resident memory (where llvmpipe keeps textures) put to the env that
    stepped; and the GPU's used memory over the episode, where the uncached env holds no more textures at its end."""
    cached = gym_stepper("DCS/walker-walk-v0", split="hard", dynamic=True)
    uncached = gym_stepper("DCS/walker-walk-v0", split="hard", dynamic=True, texture_cache_mb=0)
    grown = {"cached": 0.0, "uncached": 0.0}
    gpu_before = gpu_memory_mb()
    for _ in range(499):  # the episode's steps after its reset (500 at action repeat 2)
        for name, stepper in (("cached", cached), ("uncached", uncached)):
            before = resident_mb()
            stepper()
            grown[name] += resident_mb() - before
    gpu_after = gpu_memory_mb()
    frames, counted = cached.held_textures()
    cached.close()
    uncached.close()
    gpu = "no nvidia-smi" if gpu_before is None or gpu_after is None else f"GPU {gpu_after - gpu_before:.0f} MB"
    print(
        f"sky frames of one DCS hard dynamic walker-walk episode: {frames} held, {counted:.0f} MB counted "
        f"({counted / max(frames, 1):.2f} MB each); grown over the episode beside the uncached env: resident "
        f"{grown['cached'] - grown['uncached']:.0f} MB ({grown['cached']:.0f} - {grown['uncached']:.0f}), {gpu}"
    )


def ratio(rates: dict[str, float], faster: str, slower: str) -> str:
    """``faster``'s steps/s over ``slower``'s, or a dash where one did not run."""
    return f"{rates[faster] / rates[slower]:5.2f}x" if faster in rates and slower in rates else "    -"


def main(argv: list[str] | None = None) -> None:
    """Measure and print steps/s of each method of each row, our speed-ups, what a distraction costs over our
    undistracted split, and our env's transfers per agent step."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=40, help="agent steps per method per round")
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--warmup", type=int, default=5, help="untimed agent steps of each method first")
    parser.add_argument("--only", nargs="+", help="rows (and --every-split's splits) whose name has one of these words")
    parser.add_argument(
        "--methods", nargs="+", choices=METHODS, default=list(METHODS), help="the methods of each row to run"
    )
    parser.add_argument("--every-split", action="store_true", help="also every distracted split of walker-walk")
    parser.add_argument("--memory", action="store_true", help="also the memory of one env's sky frames")
    args = parser.parse_args(argv)
    print(
        f"MUJOCO_GL={os.environ.get('MUJOCO_GL')}, {os.cpu_count()} CPUs, {IMAGE_SIZE}x{IMAGE_SIZE}, "
        f"{args.steps} agent steps x {args.rounds} interleaved rounds, steps/s over the timed steps (ms per agent step)"
    )
    torch.set_num_threads(1)
    table = ["| row | ours | theirs | fast | ours / theirs | fast / theirs | ours / undistracted |"]
    table.append("|---|---|---|---|---|---|---|")
    for name, factories in rows().items():
        if args.only and not any(word in name for word in args.only):
            continue
        steppers = {k: make() for k, make in factories.items() if k in args.methods}
        rates = measure(steppers, args.steps, args.rounds, args.warmup)
        cells = "   ".join(f"{k} {v:7.1f} ({1000 / v:6.1f} ms)" for k, v in rates.items())
        transfers = ""
        if "ours" in rates:
            stepper = steppers["ours"]
            assert isinstance(stepper, GymStepper)
            uploads, readbacks = stepper.transfers()
            transfers = f"   uploads {uploads:.2f} readbacks {readbacks:.2f} per step"
        print(
            f"  {name:<56} {cells}   ours/theirs {ratio(rates, 'ours', 'theirs')}   fast/theirs "
            f"{ratio(rates, 'fast', 'theirs')}   ours/undistracted {ratio(rates, 'undistracted', 'ours')}{transfers}"
            + (f"   uncached/undistracted {ratio(rates, 'undistracted', 'uncached')}" if "uncached" in rates else ""),
            flush=True,
        )
        steps_per_second = " | ".join(f"{rates[k]:.1f}" if k in rates else "-" for k in ("ours", "theirs", "fast"))
        ratios = " | ".join(ratio(rates, *pair).strip() for pair in (("ours", "theirs"), ("fast", "theirs")))
        table.append(f"| {name} | {steps_per_second} | {ratios} | {ratio(rates, 'undistracted', 'ours').strip()} |")
        for stepper in steppers.values():
            if isinstance(stepper, GymStepper):
                stepper.close()
    print("\nsteps/s, as a table:\n", *table, sep="\n")
    if args.every_split:
        print_every_split(args.steps, args.rounds, args.warmup, args.only)
    if args.memory:
        print_memory()


if __name__ == "__main__":
    from recording import run_recorded  # the bench's --record FILE

    run_recorded(main, __file__)
