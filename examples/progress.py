"""What the examples share: a line of progress while they train and evaluate, and a record of what they measured.

Training prints a line every ``interval`` seconds (the step, the pace, the time left); evaluation one per finished
episode (and one every ``interval`` seconds within a long one). ``--record FILE`` writes the run's command, date,
machine, times and returns as json: the figures the documentation quotes are copied from such files, and
``tests/project/test_docs.py`` checks the copies.
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import platform
import shlex
import time
from pathlib import Path
from typing import Any

import numpy as np
import torch
from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.evaluation import evaluate_policy
from stable_baselines3.common.vec_env import VecEnv

INTERVAL = 20.0  # seconds between progress lines


def add_run_arguments(parser: argparse.ArgumentParser) -> None:
    """The options of a run that trains one model and evaluates it: its seed, where to save it, how much it says,
    and its record."""
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--save", default=None, help="save the model to this path (.zip)")
    parser.add_argument("--verbose", type=int, default=1, help="1: SB3's table every 4 episodes, 0: quiet")
    parser.add_argument("--progress", type=float, default=INTERVAL, help="seconds between progress lines")
    parser.add_argument("--record", default=None, help="write the run's command, machine, times and returns (json)")


def duration(seconds: float) -> str:
    """``754.2`` as ``12m34s``."""
    minutes, seconds = divmod(round(seconds), 60)
    return f"{minutes}m{seconds:02d}s" if minutes else f"{seconds}s"


class TrainingProgress(BaseCallback):
    """A line every ``interval`` seconds while the model learns: ``step 4000/20000 (20%), 85 steps/s, ETA 3m08s``.

    :param label: what trains, at the start of each line
    :param interval: seconds between lines
    """

    def __init__(self, label: str, interval: float = INTERVAL):
        super().__init__()
        self.label, self.interval = label, interval

    def _on_training_start(self) -> None:
        self.total = self.locals["total_timesteps"]
        self.start = self.last = time.perf_counter()
        self.start_step = self.num_timesteps
        self.updating = False

    def _on_step(self) -> bool:
        now = time.perf_counter()
        learning_starts = getattr(self.model, "learning_starts", 0)
        if not self.updating and self.num_timesteps > learning_starts:
            self.updating = True  # the pace changes here: say so, and measure the new pace from here
            self.start, self.start_step = now, self.num_timesteps
            print(f"{self.label}: step {self.num_timesteps}: random actions done, updates start", flush=True)
        elif now - self.last >= self.interval:
            rate = (self.num_timesteps - self.start_step) / max(now - self.start, 1e-9)
            left = duration((self.total - self.num_timesteps) / rate) if rate > 0 else "-"
            percent = 100 * self.num_timesteps / self.total
            print(
                f"{self.label}: step {self.num_timesteps}/{self.total} ({percent:.0f}%), {rate:.1f} steps/s, "
                f"ETA {left}",
                flush=True,
            )
            self.last = now
        return True


def evaluate(model: BaseAlgorithm, env: VecEnv, episodes: int, label: str, interval: float = INTERVAL) -> list[float]:
    """The return of each of ``episodes`` episodes of ``model`` on ``env`` (SB3's ``evaluate_policy``), with a line
    per finished episode and one every ``interval`` seconds within an episode.

    :param model: a trained model
    :param env: the environment to evaluate on, its sub-envs in SB3's Monitor
    :param episodes: how many episodes
    :param label: what is evaluated, at the start of each line
    :param interval: seconds between lines within an episode
    """
    start = last = time.perf_counter()
    finished = [0]

    def report(local: dict[str, Any], _: dict[str, Any]) -> None:
        nonlocal last
        now = time.perf_counter()
        if local["done"] and "episode" in local["info"]:
            finished[0] += 1
            episode_return = local["info"]["episode"]["r"]
            print(
                f"{label}: episode {finished[0]}/{episodes} return {episode_return:.1f} ({duration(now - start)})",
                flush=True,
            )
            last = now
        elif now - last >= interval:
            print(f"{label}: episode {finished[0] + 1}/{episodes} running ({duration(now - start)})", flush=True)
            last = now

    returns, _ = evaluate_policy(model, env, n_eval_episodes=episodes, callback=report, return_episode_rewards=True)
    return [float(value) for value in returns]


def learn_timed(
    model: BaseAlgorithm, steps: int, label: str, interval: float = INTERVAL, ms_digits: int = 0
) -> tuple[float, float]:
    """``model.learn(steps)`` with a line of progress every ``interval`` seconds and one at the end; its wall time
    and the process's CPU time (over all its threads: it depends much less than the wall time on what else the
    machine runs).

    :param model: the model to train
    :param steps: the steps it trains
    :param label: what trains, at the start of each line
    :param interval: seconds between progress lines
    :param ms_digits: the decimals of the milliseconds per step in the last line
    """
    start, cpu_start = time.perf_counter(), time.process_time()
    model.learn(steps, callback=TrainingProgress(label, interval))
    seconds, cpu_seconds = time.perf_counter() - start, time.process_time() - cpu_start
    print(
        f"{label}: {steps} steps in {seconds:.0f} s: {1000 * seconds / steps:.{ms_digits}f} ms per step "
        f"({1000 * cpu_seconds / steps:.{ms_digits}f} ms of CPU)"
    )
    return seconds, cpu_seconds


def print_returns(returns: dict[str, tuple[float, float]], episodes: int, eval_seconds: float) -> None:
    """The evaluation's time, then a line per split: the mean and standard deviation of its returns."""
    print(f"evaluated in {eval_seconds:.0f} s; the returns of the trained model:")
    width = max(len(split) for split in returns)
    for split, (mean, std) in returns.items():
        print(f"{split:>{width}}: return {mean:7.1f} ± {std:.1f} over {episodes} episodes")


def write_run_record(
    args: argparse.Namespace,
    script: str,
    argv: list[str],
    started: dict[str, Any],
    began: float,
    times: tuple[float, float, float],
    returns: dict[str, tuple[float, float]],
    ms_digits: int | None = None,
) -> None:
    """:func:`write_record` into ``args.record`` with what a training-and-evaluation example measured of its run.

    :param args: the example's options (``record``, ``steps``, ``eval_episodes``)
    :param script: the example's file name
    :param argv: its arguments
    :param started: :func:`machine` at the start of the run
    :param began: ``time.perf_counter()`` at the run's start
    :param times: the training's wall and CPU seconds (:func:`learn_timed`) and the evaluation's wall seconds
    :param returns: the mean and standard deviation of the returns of each split
    :param ms_digits: the decimals of the milliseconds per step (None: whole milliseconds)
    """
    seconds, cpu_seconds, eval_seconds = times
    figures = dict(
        wall_seconds=round(time.perf_counter() - began, 1),
        train_seconds=round(seconds, 1),
        ms_per_step=round(1000 * seconds / args.steps, ms_digits),
        cpu_ms_per_step=round(1000 * cpu_seconds / args.steps, ms_digits),
        eval_seconds=round(eval_seconds, 1),
        eval_episodes=args.eval_episodes,
        returns={split: [round(mean, 1), round(std, 1)] for split, (mean, std) in returns.items()},
    )
    write_record(args.record, script, argv, figures, started)


def machine() -> dict[str, Any]:
    """Where a run ran: the platform, the CPU model and count, the 1-minute load, the torch threads."""
    cpu = platform.processor()
    cpuinfo = Path("/proc/cpuinfo")
    if cpuinfo.exists():
        names = [line.split(":", 1)[1].strip() for line in cpuinfo.read_text().splitlines() if "model name" in line]
        cpu = names[0] if names else cpu
    return {
        "platform": platform.platform(),
        "cpu": cpu,
        "cpus": os.cpu_count(),
        "load_1min": round(os.getloadavg()[0], 2) if hasattr(os, "getloadavg") else None,
        "torch_threads": torch.get_num_threads(),
        "cuda": torch.cuda.get_device_name() if torch.cuda.is_available() else None,
    }


def write_record(
    path: str | Path, script: str, argv: list[str], figures: dict[str, Any], started: dict[str, Any]
) -> None:
    """Write the run's record as json: the command that made it, the date, the machine (at the start; the load
    also at the end), and ``figures``.

    :param path: the json file to write
    :param script: the example's file name
    :param argv: its arguments
    :param figures: what the run measured
    :param started: :func:`machine` at the start of the run
    """
    record = {
        "command": shlex.join(["python", f"examples/{script}", *argv]),
        "date": datetime.date.today().isoformat(),
        "machine": started,
        "load_1min_at_end": machine()["load_1min"],
        **figures,
    }
    Path(path).write_text(json.dumps(record, indent=2) + "\n")


def mean_and_std(returns: list[float]) -> tuple[float, float]:
    """The mean and standard deviation of episode returns, as SB3's ``evaluate_policy`` gives them."""
    return float(np.mean(returns)), float(np.std(returns))
