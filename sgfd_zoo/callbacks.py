"""Callbacks the zoo adds to rl-zoo3's: evaluation on every split, checkpoints a crash cannot spoil, a CSV of
everything logged, and progress reports for the sweep's live view."""

from __future__ import annotations

import contextlib
import functools
import signal
import sys
import threading
import time
import zipfile
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.evaluation import evaluate_policy
from stable_baselines3.common.logger import CSVOutputFormat
from stable_baselines3.common.vec_env import VecEnv, VecNormalize

from sgfd_zoo import training_state
from sgfd_zoo.runs import (
    Checkpoint,
    FileWriteError,
    StoredFile,
    UnreadableFile,
    atomic_write,
    checkpoint_file_name,
    read_index,
    remove_checkpoint_files,
    scan_checkpoints,
    write_failure,
    write_index,
)


class MultiSplitEvalCallback(BaseCallback):
    """
    Every ``eval_freq`` calls, evaluate the policy on the domains of several splits (training domains
    and the unseen ones), log ``eval/<split>/mean_reward`` and append to ``evaluations_<split>.npz``
    (same arrays as SB3's EvalCallback: timesteps, results, ep_lengths).

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
            if self.log_path is not None:
                self.log_path.mkdir(parents=True, exist_ok=True)
                arrays = {key: np.array(value) for key, value in history.items()}
                atomic_write(self._file(split), lambda tmp, arrays=arrays: np.savez(tmp, **arrays))
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


def _load_history(path: Path | None) -> dict[str, list]:
    history: dict[str, list] = {"timesteps": [], "results": [], "ep_lengths": []}
    if path is not None and path.exists():
        try:
            with np.load(path) as data:
                for key in history:
                    history[key] = list(data[key])
        except (OSError, ValueError, KeyError, EOFError, zipfile.BadZipFile) as error:
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


@dataclass(frozen=True)
class CheckpointPart:
    """
    One file of a checkpoint: what it holds, how it is written and how a resumed model gets it back.

    :param name: its key in ``checkpoint.json`` and in its file name (``checkpoint_<name>_<steps>_steps<suffix>``)
    :param suffix: ``.pkl`` or ``.zip`` (the suffix decides how a file found without its index is checked)
    :param save: writes the part of ``model`` to the path it is given
    :param restore: loads it into the resumed ``model``; None for the model itself (loaded first, by the class)
    :param applies: whether ``model`` has this part
    """

    name: str
    suffix: str
    save: Callable[[BaseAlgorithm, str], None]
    restore: Callable[[BaseAlgorithm, str], None] | None = None
    applies: Callable[[BaseAlgorithm], bool] = lambda model: True


def _has_replay_buffer(model: BaseAlgorithm) -> bool:
    return hasattr(model, "save_replay_buffer") and getattr(model, "replay_buffer", None) is not None


def _restore_vec_normalize(model: BaseAlgorithm, path: str) -> None:
    current = model.get_vec_normalize_env()
    if current is None:
        raise ValueError(f"{path} holds VecNormalize statistics, but the resumed run does not normalize")
    saved = VecNormalize.load(path, current.venv)
    current.obs_rms, current.ret_rms = saved.obs_rms, saved.ret_rms


# What a checkpoint saves, in the order it is written. The model comes last: a checkpoint whose model file
# exists is complete, which is how one is recognised without its index. Resuming restores every part the
# checkpoint has; the training state (generators, envs) when the resumed training starts (sgfd_zoo.experiment).
CHECKPOINT_PARTS: tuple[CheckpointPart, ...] = (
    CheckpointPart(
        "training_state",
        ".pkl",
        save=training_state.save,
        applies=lambda model: training_state.unavailable(model) is None,
    ),
    CheckpointPart(
        "replay_buffer",
        ".pkl",
        save=lambda model, path: model.save_replay_buffer(path),
        restore=lambda model, path: model.load_replay_buffer(path),
        applies=_has_replay_buffer,
    ),
    CheckpointPart(
        "vecnormalize",
        ".pkl",
        save=lambda model, path: model.get_vec_normalize_env().save(path),
        restore=_restore_vec_normalize,
        applies=lambda model: model.get_vec_normalize_env() is not None,
    ),
    CheckpointPart("model", ".zip", save=lambda model, path: model.save(path)),
)


class StopRequest:
    """Set (by Ctrl-C) to ask training to stop at the next step, after a checkpoint."""

    def __init__(self) -> None:
        self.reason: str | None = None

    def request(self, reason: str) -> None:
        self.reason = reason

    def __bool__(self) -> bool:
        return self.reason is not None


@contextlib.contextmanager
def interrupts_deferred(stop: StopRequest) -> Iterator[None]:
    """While the block runs, the first Ctrl-C (SIGINT) sets ``stop`` instead of raising KeyboardInterrupt, so
    that training ends at a step boundary with a checkpoint; a second one raises at once. Only in the main
    thread (the only one Python delivers signals to); elsewhere the block runs unchanged."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def first_interrupt(signum: int, frame: Any) -> None:
        stop.request("Ctrl-C")
        signal.signal(signal.SIGINT, signal.default_int_handler)

    saved = signal.signal(signal.SIGINT, first_interrupt)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, saved)


class ResumableCheckpointCallback(BaseCallback):
    """
    Every ``save_freq`` calls, and when ``stop`` is set (then training stops), save a checkpoint between two env
    steps (at ``on_rollout_start``: with ``train_freq`` k, the first at or after the due call): the parts of
    ``parts`` that the model has, each written whole (:func:`sgfd_zoo.runs.atomic_write`: fsync'd, checked, renamed),
    then ``checkpoint.json`` listing them with their sizes and sha256. The two newest checkpoints are kept:
    before a new one is written the older is deleted, and the newer stays until the new one is complete, so a
    crash, a kill or a full disk at any moment leaves the previous checkpoint usable (peak: two checkpoints
    on disk; a paper-scale replay buffer is several GB).

    A checkpoint that cannot be written (disk full, or any OSError) is removed again, ``failure`` says why in
    one line, and training stops; ``stopped`` is the step it stopped at. Files an interrupted save left behind
    (a process killed while writing) are deleted when training starts again.

    :param save_freq: Save every this many calls (env steps divided by the number of train envs); None: only
        when stopped
    :param save_path: Folder of the checkpoint files (the run folder)
    :param stop: Set to stop training at the next step, after a checkpoint
    :param parts: What a checkpoint holds, in the order written (the model last)
    """

    def __init__(
        self,
        save_freq: int | None,
        save_path: str | Path,
        stop: StopRequest | None = None,
        parts: Sequence[CheckpointPart] = CHECKPOINT_PARTS,
        verbose: int = 0,
    ):
        super().__init__(verbose)
        if save_freq is not None and save_freq < 1:
            raise ValueError(f"save_freq must be None or >= 1, got {save_freq}")
        if not parts or parts[-1].name != "model":
            raise ValueError(f"parts must end with the model (written last), got {[part.name for part in parts]}")
        self.save_freq = save_freq
        self.save_path = Path(save_path)
        self.stop = stop if stop is not None else StopRequest()
        self.parts = tuple(parts)
        self.failure: str | None = None
        self.stopped: int | None = None
        self._next_save = save_freq or 0

    def _on_training_start(self) -> None:
        self.save_path.mkdir(parents=True, exist_ok=True)
        try:
            kept = read_index(self.save_path)
        except UnreadableFile:
            return  # its files may be all that is left of the checkpoints: they stay
        removed = remove_checkpoint_files(self.save_path, kept)
        if removed and self.verbose > 0:
            print(f"Removed what interrupted saves left in {self.save_path}: {', '.join(removed)}")

    def _on_rollout_start(self) -> None:
        # Between two env steps: the last step's transition is stored and trained on, the next not yet taken, so
        # the checkpoint's model, buffer and training state are of one moment and a resume continues from it
        # bit for bit. The step after a stopping checkpoint is taken and then dropped (_on_step stops before
        # SB3 stores it).
        if self.stopped is not None:
            return
        due = self.save_freq is not None and self.n_calls >= self._next_save
        if not due and not self.stop:
            return
        newest = self.newest()
        # A run resumed and stopped before its first step: its checkpoint is this moment already.
        saved = newest if newest is not None and newest.num_timesteps == self.num_timesteps else self.save()
        if due:
            self._next_save = (self.n_calls // self.save_freq + 1) * self.save_freq  # type: ignore[operator]
        if saved is None or self.stop:
            self.stopped = self.num_timesteps

    def _on_step(self) -> bool:
        return self.stopped is None

    def _on_training_end(self) -> None:
        # The end of training is between two steps too (after the last step's update): a due checkpoint is taken
        # there, so that a kill during the final save loses nothing.
        if self.stopped is None and (self.stop or (self.save_freq is not None and self.n_calls >= self._next_save)):
            self._on_rollout_start()

    def newest(self) -> Checkpoint | None:
        try:
            checkpoints = read_index(self.save_path)
        except UnreadableFile:
            return None
        return checkpoints[0] if checkpoints else None

    def save(self) -> Checkpoint | None:
        """Write a checkpoint at the current step; None (and ``failure`` set) when it could not be written."""
        folder, steps = self.save_path, self.num_timesteps
        folder.mkdir(parents=True, exist_ok=True)
        try:
            listed = read_index(folder)
        except UnreadableFile as error:
            listed = scan_checkpoints(folder)
            print(f"warning: {error}; the new index lists the newest checkpoint its files make up", file=sys.stderr)
        previous = listed[:1]
        written: dict[str, StoredFile] = {}
        try:
            # Room for the new checkpoint: the older one goes, the newer stays until the new one is complete.
            if len(listed) > 1:
                write_index(folder, previous)
            remove_checkpoint_files(folder, previous)
            for part in self.parts:
                if part.applies(self.model):
                    path = folder / checkpoint_file_name(part.name, steps, part.suffix)
                    written[part.name] = atomic_write(path, functools.partial(part.save, self.model))
            checkpoint = Checkpoint(steps, written)
            write_index(folder, [checkpoint, *previous])
        except FileWriteError as error:
            remove_checkpoint_files(folder, _listed(folder, previous))
            # The new checkpoint is about the size of the previous one; without one, what was written is a bound.
            error.bytes_written += sum(stored.size or 0 for stored in written.values())
            kept = "no checkpoint"
            if previous:
                kept = f"the previous checkpoint ({previous[0].num_timesteps} steps) is intact"
            self.failure = write_failure(f"the checkpoint at {steps} steps", folder, error, _size(previous), kept)
            return None
        except BaseException:  # a second Ctrl-C, say
            remove_checkpoint_files(folder, _listed(folder, previous))
            raise
        if self.verbose > 0:
            print(f"Checkpoint at {steps} steps in {folder}")
        return checkpoint


def _listed(folder: Path, otherwise: list[Checkpoint]) -> list[Checkpoint]:
    """What the index lists now (it may already list the new checkpoint when a save is interrupted)."""
    try:
        return read_index(folder)
    except UnreadableFile:
        return otherwise


def _size(checkpoints: list[Checkpoint]) -> int | None:
    return checkpoints[0].size if checkpoints else None


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
