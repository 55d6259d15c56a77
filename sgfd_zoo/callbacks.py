"""Callbacks the zoo adds to rl-zoo3's: evaluation on every split, a CSV of everything logged, and progress
reports for the sweep's live view (checkpoints: :mod:`sgfd_zoo.runs.checkpoint_callback`)."""

from __future__ import annotations

import functools
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.evaluation import evaluate_policy
from stable_baselines3.common.logger import CSVOutputFormat
from stable_baselines3.common.vec_env import VecEnv

from sgfd_zoo.runs.bounded import load_npz
from sgfd_zoo.runs.files import UnreadableFile, atomic_write

#: The split whose evaluations rl-zoo3's file holds (its EvalCallback evaluates on the training envs), and the file
TRAIN_SPLIT, RL_ZOO3_EVALUATIONS = "train", "evaluations.npz"


class MultiSplitEvalCallback(BaseCallback):
    """
    Every ``eval_freq`` calls, evaluate the policy on the domains of several splits (training domains
    and the unseen ones), log ``eval/<split>/mean_reward`` and append to ``evaluations_<split>.npz``
    (same arrays as SB3's EvalCallback: timesteps, results, ep_lengths). The training split's are also written
    as ``evaluations.npz``, where rl-zoo3's EvalCallback writes its own (on the training envs): rl-zoo3's
    ``all_plots`` reads that file.

    :param eval_envs: Split name -> VecEnv with one sub-env per domain of that split
    :param eval_freq: Evaluate every this many calls (env steps divided by the number of train envs)
    :param n_eval_episodes: Episodes per split, spread over its domains
    :param log_path: Folder of the ``evaluations_<split>.npz`` files; existing files are continued from the
        step training starts at
    :param deterministic: Use the deterministic policy
    :param on_split: Called with each split's name before it is evaluated and with None after the last (a
        progress report: an evaluation can take minutes)
    """

    def __init__(
        self,
        eval_envs: dict[str, VecEnv],
        eval_freq: int,
        n_eval_episodes: int = 10,
        log_path: str | Path | None = None,
        deterministic: bool = True,
        verbose: int = 1,
        on_split: Callable[[str | None], None] | None = None,
    ):
        super().__init__(verbose)
        if eval_freq < 1:
            raise ValueError(f"eval_freq must be >= 1, got {eval_freq}")
        self.eval_envs = eval_envs
        self.eval_freq = eval_freq
        self.n_eval_episodes = n_eval_episodes
        self.log_path = Path(log_path) if log_path is not None else None
        self.deterministic = deterministic
        self.on_split = on_split
        self.history: dict[str, dict[str, list]] = {split: _load_history(self._file(split)) for split in eval_envs}

    def _file(self, split: str) -> Path | None:
        return None if self.log_path is None else self.log_path / f"evaluations_{split}.npz"

    def _on_training_start(self) -> None:
        # A run restarted where an attempt stopped (from its checkpoint, or from step 0 without one) keeps
        # the evaluations up to that point only: the attempt's later ones are redone, not duplicated.
        for history in self.history.values():
            kept = sum(step <= self.num_timesteps for step in history["timesteps"])
            for values in history.values():
                del values[kept:]

    def _on_step(self) -> bool:
        if self.n_calls % self.eval_freq == 0:
            self.evaluate()
        return True

    def evaluate(self) -> dict[str, float]:
        """Evaluate every split now; returns split -> mean episode reward."""
        means = {}
        for split, env in self.eval_envs.items():
            if self.on_split is not None:
                self.on_split(split)
            rewards, lengths = evaluate_policy(
                self.model,
                env,
                n_eval_episodes=self.n_eval_episodes,
                deterministic=self.deterministic,
                return_episode_rewards=True,
            )
            history = self.history[split]
            history["timesteps"].append(self.num_timesteps)
            history["results"].append(rewards)
            history["ep_lengths"].append(lengths)
            path = self._file(split)
            if path is not None:
                path.parent.mkdir(parents=True, exist_ok=True)
                arrays = {key: np.array(value) for key, value in history.items()}
                for file in (path, path.with_name(RL_ZOO3_EVALUATIONS)) if split == TRAIN_SPLIT else (path,):
                    atomic_write(file, functools.partial(_save_arrays, arrays=arrays))
            means[split] = float(np.mean(rewards))
            self.logger.record(f"eval/{split}/mean_reward", means[split])
            self.logger.record(f"eval/{split}/std_reward", float(np.std(rewards)))
            if self.verbose > 0:
                print(f"Eval at {self.num_timesteps} steps, {split}: {means[split]:.1f} +/- {np.std(rewards):.1f}")
        # The step with the row, so that a CSV row of evaluations can be placed on the training's time axis.
        self.logger.record("time/total_timesteps", self.num_timesteps, exclude="tensorboard")
        self.logger.dump(self.num_timesteps)
        if self.on_split is not None:
            self.on_split(None)
        return means

    def latest_returns(self) -> dict[str, float]:
        """The mean return of each split's latest evaluation (resumed runs: their earlier ones count)."""
        return {split: float(np.mean(h["results"][-1])) for split, h in self.history.items() if h["results"]}

    def _on_training_end(self) -> None:
        for env in self.eval_envs.values():
            env.close()


def _save_arrays(path: str, arrays: dict[str, Any]) -> None:
    np.savez(path, **arrays)


def _load_history(path: Path | None) -> dict[str, list]:
    history: dict[str, list] = {"timesteps": [], "results": [], "ep_lengths": []}
    if path is not None and path.exists():
        try:
            data = load_npz(path)  # within the limits of sgfd_zoo.runs.bounded
            for key in history:
                history[key] = list(data[key])
        except (KeyError, UnreadableFile) as error:
            raise UnreadableFile(
                f"{path} is unreadable ({type(error).__name__}: {error}): move it away to go on without the "
                "evaluations it held"
            ) from None
    return history


class CSVLogCallback(BaseCallback):
    """
    Also write everything the model logs (``train/``, ``sgfd/``, ``eval/``, ...) to a CSV file, whatever
    outputs rl-zoo3 configured, so a run's curves can be read back without tensorboard.

    :param path: The CSV file (a resumed run writes a new file rather than truncating the old one)
    """

    def __init__(self, path: str | Path, verbose: int = 0):
        super().__init__(verbose)
        self.path = Path(path)
        self._output: CSVOutputFormat | None = None

    def _on_training_start(self) -> None:
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._output = CSVOutputFormat(str(self.path))
        self.model.logger.output_formats.append(self._output)

    def _on_step(self) -> bool:
        return True

    def _on_training_end(self) -> None:
        if self._output is not None:
            self.model.logger.output_formats.remove(self._output)
            self._output.close()
            self._output = None


class ProgressCallback(BaseCallback):
    """
    Report the run's progress to ``reporter`` at most every ``interval`` seconds, at once when an evaluation
    starts a split or ends (:meth:`evaluating`), and at the end: steps done, the total, the steps per second of
    learning, the step learning starts at (the steps before it are random actions without updates, many times
    faster, so they do not count in the rate), the split under evaluation and since when, the latest evaluation
    return of each split, and whether it ended.

    :param reporter: called with a dict of figures; must return quickly (a Ray actor's ``.remote``)
    :param total_timesteps: steps the run trains for in all
    :param latest_returns: gives the latest evaluation return of each split (``MultiSplitEvalCallback``)
    :param interval: seconds between reports
    """

    def __init__(
        self,
        reporter: Callable[[dict[str, Any]], None],
        total_timesteps: int,
        latest_returns: Callable[[], dict[str, float]] | None = None,
        interval: float = 5.0,
    ):
        super().__init__()
        self.reporter = reporter
        self.total_timesteps = int(total_timesteps)
        self.latest_returns = latest_returns
        self.interval = interval
        self._last_report = 0.0
        self._learning_since: tuple[float, int] | None = None  # (monotonic time, steps) when the rate starts
        self._evaluating: tuple[str, float] | None = None  # (split, wall-clock time it started)

    @property
    def learning_starts(self) -> int:
        return int(getattr(self.model, "learning_starts", 0))

    def _on_training_start(self) -> None:
        self._learning_since = None
        self._report(done=False)

    def _on_step(self) -> bool:
        if self._learning_since is None and self.num_timesteps >= self.learning_starts:
            self._learning_since = (time.monotonic(), self.num_timesteps)
        if time.monotonic() - self._last_report >= self.interval:
            self._report(done=False)
        return True

    def _on_training_end(self) -> None:
        self._report(done=True)

    def evaluating(self, split: str | None) -> None:
        """Report at once that the run evaluates ``split`` now (None: its evaluation ended)."""
        self._evaluating = None if split is None else (split, time.time())
        # The evaluation runs inside another callback's step, before this one's has counted the step.
        self.num_timesteps = self.model.num_timesteps
        self._report(done=False)

    def _report(self, done: bool) -> None:
        self._last_report = now = time.monotonic()
        rate = 0.0
        if self._learning_since is not None:
            started, start_steps = self._learning_since
            elapsed = now - started
            rate = (self.num_timesteps - start_steps) / elapsed if elapsed > 0 else 0.0
        returns = self.latest_returns() if self.latest_returns is not None else {}
        report: dict[str, Any] = {
            "steps": self.num_timesteps,
            "total": self.total_timesteps,
            "steps_per_second": rate,
            "learning_starts": self.learning_starts,
            "done": done,
        }
        if returns:
            report["returns"] = returns
        if self._evaluating is not None and not done:
            report["evaluating"], report["evaluating_since"] = self._evaluating
        try:
            self.reporter(report)
        except Exception as error:  # the sweep's board is gone: its live view loses this run, the run goes on
            print(f"warning: progress reports stopped ({type(error).__name__}: {error})", file=sys.stderr)
            self.reporter = _ignore


def _ignore(report: dict[str, Any]) -> None:
    pass
