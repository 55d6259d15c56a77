"""Checkpoints a crash cannot spoil, taken between two env steps, and stopping at one: on Ctrl-C (and SIGTERM, as
a batch system stops a job), on a full disk, or when another process took the run over."""

from __future__ import annotations

import contextlib
import functools
import signal
import sys
import threading
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, cast

from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.off_policy_algorithm import OffPolicyAlgorithm
from stable_baselines3.common.vec_env import VecNormalize

from sgfd_zoo.exit_codes import INTERRUPTED, TERMINATED
from sgfd_zoo.runs import training_state
from sgfd_zoo.runs.checkpoints import (
    Checkpoint,
    checkpoint_file_name,
    read_index,
    remove_checkpoint_files,
    scan_checkpoints,
    write_index,
)
from sgfd_zoo.runs.files import FileWriteError, StoredFile, UnreadableFile, atomic_write, write_failure
from sgfd_zoo.runs.locks import RunLock


@dataclass(frozen=True)
class CheckpointPart:
    """
    One file of a checkpoint: what it holds, how it is written and how a resumed model gets it back.

    :param name: its key in ``checkpoint.json`` and in its file name (``checkpoint_<name>_<steps>_steps<suffix>``)
    :param suffix: ``.pkl``, ``.npz`` or ``.zip`` (the suffix decides how a file found without its index is checked)
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
        ".npz",  # data, not a pickle (:mod:`sgfd_zoo.runs.training_state`)
        save=training_state.save,
        applies=lambda model: training_state.unavailable(model) is None,
    ),
    CheckpointPart(
        "replay_buffer",
        ".pkl",
        save=lambda model, path: cast(OffPolicyAlgorithm, model).save_replay_buffer(path),
        restore=lambda model, path: cast(OffPolicyAlgorithm, model).load_replay_buffer(path),
        applies=_has_replay_buffer,
    ),
    CheckpointPart(
        "vecnormalize",
        ".pkl",
        save=lambda model, path: cast(VecNormalize, model.get_vec_normalize_env()).save(path),
        restore=_restore_vec_normalize,
        applies=lambda model: model.get_vec_normalize_env() is not None,
    ),
    CheckpointPart("model", ".zip", save=lambda model, path: model.save(path)),
)


class StopRequest:
    """Set (by Ctrl-C or SIGTERM) to ask training to stop at the next step, after a checkpoint.

    :ivar reason: what asked, e.g. ``Ctrl-C``; None until asked
    :ivar exit_code: the process's exit code for that stop (the shell's 128 + the signal)
    """

    def __init__(self) -> None:
        self.reason: str | None = None
        self.exit_code = INTERRUPTED

    def request(self, reason: str, exit_code: int = INTERRUPTED) -> None:
        self.reason, self.exit_code = reason, exit_code

    def __bool__(self) -> bool:
        return self.reason is not None


#: The most env steps between two checkpoints when ``--save-freq`` is not given.
LONGEST_CHECKPOINT_INTERVAL = 100_000
#: Without ``--save-freq``, a run checkpoints at least this many times: a kill costs at most 1/5 of a short run.
CHECKPOINTS_PER_RUN = 5


def default_checkpoint_interval(n_timesteps: int) -> int:
    """Env steps between checkpoints when ``--save-freq`` is not given: a fifth of the run, at most 100k steps
    (a paper-scale pixel checkpoint writes a 10.6 GB buffer)."""
    return max(min(LONGEST_CHECKPOINT_INTERVAL, n_timesteps // CHECKPOINTS_PER_RUN), 1)


# The signals that stop training at a checkpoint: a terminal's Ctrl-C, and the SIGTERM a batch system (SLURM's
# time limit or preemption, a job's cancel) sends before it kills; each with its name and the exit code it gives.
DEFERRED_SIGNALS = {signal.SIGINT: ("Ctrl-C", INTERRUPTED), signal.SIGTERM: ("SIGTERM", TERMINATED)}


@contextlib.contextmanager
def interrupts_deferred(stop: StopRequest) -> Iterator[None]:
    """While the block runs, the first Ctrl-C (SIGINT) or SIGTERM sets ``stop`` instead of ending the process, so
    that training ends at a step boundary with a checkpoint; a second one raises KeyboardInterrupt at once. Only
    in the main thread (the only one Python delivers signals to); elsewhere the block runs unchanged."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def at_once(signum: int, frame: Any) -> None:
        raise KeyboardInterrupt

    def first_interrupt(signum: int, frame: Any) -> None:
        stop.request(*DEFERRED_SIGNALS[signal.Signals(signum)])
        for deferred in DEFERRED_SIGNALS:
            signal.signal(deferred, at_once)

    saved = {deferred: signal.signal(deferred, first_interrupt) for deferred in DEFERRED_SIGNALS}
    try:
        yield
    finally:
        for deferred, handler in saved.items():
            signal.signal(deferred, handler)


class ResumableCheckpointCallback(BaseCallback):
    """
    Every ``save_freq`` calls, and when ``stop`` is set (then training stops), save a checkpoint between two env
    steps (at ``on_rollout_start``: with ``train_freq`` k, the first at or after the due call): the parts of
    ``parts`` that the model has, each written whole (:func:`sgfd_zoo.runs.files.atomic_write`: fsync'd, checked,
    renamed), then ``checkpoint.json`` listing them with their sizes and sha256. The two newest checkpoints are kept:
    before a new one is written the older is deleted, and the newer stays until the new one is complete, so a
    crash, a kill or a full disk at any moment leaves the previous checkpoint usable (peak: two checkpoints
    on disk; a paper-scale replay buffer is several GB).

    A checkpoint that cannot be written (disk full, or any OSError) is removed again, ``failure`` says why in
    one line, and training stops; ``stopped`` is the step it stopped at. Files an interrupted save left behind
    (a process killed while writing) are deleted when training starts again. When another process took the
    run's ``lock`` over, training stops without a checkpoint and ``taken_over`` says so.

    :param save_freq: Save every this many calls (env steps divided by the number of train envs); None: only
        when stopped
    :param save_path: Folder of the checkpoint files (the run folder)
    :param stop: Set to stop training at the next step, after a checkpoint
    :param lock: The run's lock, held by this process (:mod:`sgfd_zoo.runs.locks`); None: not checked
    :param parts: What a checkpoint holds, in the order written (the model last)
    """

    def __init__(
        self,
        save_freq: int | None,
        save_path: str | Path,
        stop: StopRequest | None = None,
        lock: RunLock | None = None,
        verbose: int = 0,
        parts: Sequence[CheckpointPart] = CHECKPOINT_PARTS,
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
        self.lock = lock
        self.failure: str | None = None
        self.taken_over: str | None = None
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
        if self.lock is not None and self.lock.lost is not None:
            self.taken_over, self.stopped = self.lock.lost, self.num_timesteps
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
