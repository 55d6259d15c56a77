"""The run folders sgfd-zoo writes and reads, in one place (rl-zoo3's layout plus the zoo's files):

    <log folder>/<algo>/<EnvName>_<id>/        a run (:class:`RunFolder`); EnvName is the id with "/" -> "-"
        <EnvName>.zip                           the final model
        finished.json                           written after the final model: the run is finished
        <EnvName>/args.yml, config.yml          rl-zoo3's saved arguments and hyperparameters
        <EnvName>/command.txt                   the ``sgfd-zoo train`` command of its latest start (quoted as
                                                a shell reads it; earlier versions kept the flags in command.json)
        <EnvName>/versions.txt                  what trained it (:mod:`sgfd_zoo.runs.provenance`), a block per start
        evaluations_<split>.npz                 evaluations during training, per split
        progress.csv, progress_from_<n>.csv     everything logged (a resumed run continues in a new file)
        checkpoint.json, checkpoint_*           its checkpoints (:mod:`sgfd_zoo.runs.checkpoints`)
        writer.lock                             while a process trains it: which one (:mod:`sgfd_zoo.runs.locks`)
        final_evaluation.json                   sgfd-zoo evaluate's result for the final model (reused while it fits)
    <log folder>/<algo>/<EnvName>_<id>.log      a sweep run's output, beside its folder

A study keeps a finished run's compact record (:mod:`sgfd_zoo.runs.records`). Every file is written through
:func:`sgfd_zoo.runs.files.atomic_write`. The files are data (:mod:`sgfd_zoo.runs.safe`): YAML safe-loaded, names in
indexes confined to the run, no link inside a log folder followed, no credential of a URL recorded.

Whether a run is finished is decided here only (:attr:`RunFolder.finished`). The module reads and writes files
and nothing more: it imports nothing of the experiment, and plotting and the sweep's planning use it without
torch (``load_model`` imports the algorithm's class).
"""

from __future__ import annotations

import functools
import shlex
import time
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, overload

import numpy as np
import yaml

import sgfd_envs
from sgfd_envs.families import env_kwargs_as_trained, family_kwargs
from sgfd_zoo.algos import SGFD_ALGOS
from sgfd_zoo.arguments import ZooError, check_env_id
from sgfd_zoo.runs import provenance
from sgfd_zoo.runs.bounded import csv_rows, read_text
from sgfd_zoo.runs.checkpoints import Checkpoint, read_index, scan_checkpoints
from sgfd_zoo.runs.fields import ALGO_KEY, finite_number, whole_number
from sgfd_zoo.runs.files import StoredFile, UnreadableFile, read_json, write_json
from sgfd_zoo.runs.readers import config_value, final_model_steps, read_evaluations, read_yaml
from sgfd_zoo.runs.safe import (
    RefusedFile,
    plain_name,
    redact_argv,
    redact_values,
    refuse_links,
    refuse_links_inside,
    write_text,
)

if TYPE_CHECKING:
    from stable_baselines3.common.base_class import BaseAlgorithm

FINISHED_MARKER = "finished.json"
STEPS_KEY = "time/total_timesteps"


def env_name(env_id: str) -> str:
    """rl-zoo3's name of an env id in paths: ``SGFD/MT-walker-walk-v0`` -> ``SGFD-MT-walker-walk-v0``."""
    return env_id.replace("/", "-")


ENV_IDS_BY_NAME = {env_name(env_id): env_id for env_id in sgfd_envs.ENV_IDS}


class NoUsableCheckpoint(ZooError):
    """``--resume`` of a run none of whose checkpoints verifies; the message says how to start it again."""


def mark_finished(folder: Path, model: StoredFile, num_timesteps: int) -> None:
    """Record in run folder ``folder`` that its final model ``model`` (already written) ends it at ``num_timesteps``."""
    write_json(Path(folder) / FINISHED_MARKER, {"num_timesteps": int(num_timesteps), "model": model.to_json()})


# -- run folders -------------------------------------------------------------------------------------


class FileInFolder:
    """A read-only attribute of a run or a record (:class:`NamedRun`): the path of the file ``name`` in its folder.

    :param name: the file's name
    :param doc: what the file holds (the attribute's docstring)
    """

    def __init__(self, name: str, doc: str | None = None) -> None:
        self.name = name
        self.__doc__ = doc

    @overload
    def __get__(self, run: None, owner: type) -> FileInFolder: ...

    @overload
    def __get__(self, run: NamedRun, owner: type) -> Path: ...

    def __get__(self, run: NamedRun | None, owner: type) -> Path | FileInFolder:
        return self if run is None else run.path / self.name


@dataclass(frozen=True)
class NamedRun:
    """What a run's place says: ``<algo>/<EnvName>_<id>``, and its evaluations during training."""

    path: Path

    @property
    def algo(self) -> str:
        return self.path.parent.name

    @property
    def env_id(self) -> str:
        return ENV_IDS_BY_NAME[self.path.name.rpartition("_")[0]]

    @property
    def run_id(self) -> int:
        return int(self.path.name.rpartition("_")[2])

    @property
    def root(self) -> Path:
        """The folder of its algorithms' folders (a log folder, a study's ``runs``): nothing below it is a link."""
        return self.path.parent.parent

    @property
    def config_dir(self) -> Path:
        """Where its ``config.yml`` (and ``args.yml``) lie."""
        return self.path

    @property
    def versions_file(self) -> Path:
        """What trained it (:mod:`sgfd_zoo.runs.provenance`), a block per start: ``versions.txt`` beside its config."""
        return self.config_dir / "versions.txt"

    @functools.cached_property
    def config(self) -> dict[str, Any]:
        """The hyperparameters the run trained with ({} before the run wrote them, or when unreadable)."""
        return read_yaml(self.config_dir / "config.yml")[0]

    @property
    def accuracy_threshold(self) -> float:
        """The accuracy SGFD's classifier trained to in this run: its config's, else its reading's default."""
        source = self.config_dir / "config.yml"
        threshold = config_value(self.config, "accuracy_threshold", source, "fraction")
        if threshold is None:
            from sb3_sgfd.sgfd.settings import SGFDSettings  # here: reading run folders needs no torch

            reading = config_value(self.config, "reading", source, "name") or "paper"
            try:
                threshold = SGFDSettings.of_reading(reading).accuracy_threshold
            except ValueError as error:
                raise RefusedFile(f"{source} reading: refused: {error}") from None
        return float(threshold)

    def evaluations(self, split: str) -> dict[str, np.ndarray] | None:
        """``timesteps``, ``results`` (evaluations x episodes) and ``ep_lengths`` of a split, or None."""
        return read_evaluations(self.path / f"evaluations_{split}.npz")


@dataclass(frozen=True)
class RunFolder(NamedRun):
    """One run: ``<log folder>/<algo>/<EnvName>_<id>``.

    :param path: the run's folder
    """

    @classmethod
    def at(cls, folder: Path, algo: str, env_id: str, run_id: int) -> RunFolder:
        """The folder of run ``run_id`` of ``algo`` on ``env_id`` under the log folder ``folder``."""
        return cls(Path(folder) / algo / f"{env_name(env_id)}_{run_id}")

    @classmethod
    def parse(cls, path: Path) -> RunFolder | None:
        """``path`` as a run folder, or None if its name is not ``<EnvName>_<id>`` of an SGFD id."""
        return cls(Path(path)) if _run_env_id(Path(path)) is not None else None

    @property
    def log_file(self) -> Path:
        """A sweep run's output: next to the folder, so a run that fails early leaves no half-made folder."""
        return self.path.with_name(f"{self.path.name}.log")

    def refuse_links(self) -> None:
        """A :class:`~sgfd_zoo.runs.safe.RefusedFile` when the run's place holds a symbolic link (its folder, a
        file or folder in it, its algorithm's folder, its sweep log): writing, copying or deleting there would
        follow it out of the log folder."""
        refuse_links(self.root, self.log_file)
        refuse_links_inside(self.path, self.root)

    @property
    def model_path(self) -> Path:
        return self.path / f"{env_name(self.env_id)}.zip"

    finished_marker = FileInFolder(FINISHED_MARKER, "Written after the final model: the run is finished.")
    final_evaluation = FileInFolder(
        "final_evaluation.json", "Where ``sgfd-zoo evaluate`` keeps the final model's evaluation, to reuse it."
    )

    @property
    def command_file(self) -> Path:
        """The ``sgfd-zoo train`` command the run was last started or resumed with, to say how it goes on."""
        return self.config_dir / "command.txt"

    legacy_command_file = FileInFolder(
        "command.json",
        "Where runs of earlier versions kept their ``sgfd-zoo train`` flags (a JSON list) beside a ``command.txt`` "
        "that rl-zoo3 wrote (the process's command line, unquoted; a sweep's: Ray's worker's).",
    )

    def train_argv(self) -> list[str] | None:
        """The flags after ``sgfd-zoo train`` of the run's latest recorded start, from :attr:`command_file`, or
        in a run of an earlier version from :attr:`legacy_command_file`; None for a run that recorded neither
        (version 0.1.0's runs) or whose files are unreadable."""
        try:
            command = shlex.split(read_text(self.command_file))
        except (OSError, ValueError, UnreadableFile):
            command = []
        if command[:2] == ["sgfd-zoo", "train"]:
            return command[2:]
        try:
            argv = read_json(self.legacy_command_file)
        except UnreadableFile:
            return None
        return [str(arg) for arg in argv] if isinstance(argv, list) else None

    @property
    def config_dir(self) -> Path:
        return self.path / env_name(self.env_id)

    def record_start(self, config: dict[str, Any], args: dict[str, Any], argv: list[str] | None, step: int) -> None:
        """What a start (or resume) of the run writes beside its model, each file whole: rl-zoo3's ``config.yml``
        and ``args.yml`` (with ``stand_in``: the splits that run on a built-in stand-in of a benchmark's data, so no
        number of theirs passes for the benchmark's), the ``sgfd-zoo train`` command (``command.txt``, which
        ``sgfd-zoo evaluate`` reads to print the command that continues the run; an earlier version's
        ``command.json`` it replaces is removed), and a block of ``versions.txt`` (appended: a resumed run's later
        steps may come from other code).

        :param config: the hyperparameters as rl-zoo3 saves them (its ``env_kwargs`` decide the family recorded in
            ``args.yml``'s ``env_family``)
        :param args: rl-zoo3's arguments
        :param argv: the ``sgfd-zoo train`` flags of this process (a sweep's run too: its process is a Ray worker);
            None where they are unknown (a manager built in Python): no command is recorded
        :param step: the step the run starts from
        """
        self.refuse_links()
        self.config_dir.mkdir(parents=True, exist_ok=True)
        env_kwargs = dict(config.get("env_kwargs") or {})
        stand_ins = {
            label: sgfd_envs.stand_in(self.env_id, **{**env_kwargs, **mode})
            for label, mode in sgfd_envs.evaluation_modes(self.env_id)
        }
        args = {**args, "stand_in": {label: what for label, what in stand_ins.items() if what is not None}}
        args["env_family"] = family_kwargs(self.env_id, env_kwargs)  # what a run without it trained on: the earlier
        # A URL's credentials (an Optuna --storage) are not kept: the files are shared, and readable by others.
        write_text(self.root, self.config_dir / "config.yml", yaml.dump(redact_values(config)))
        write_text(self.root, self.config_dir / "args.yml", yaml.dump(redact_values(args)))
        if argv is not None:
            write_text(self.root, self.command_file, shlex.join(["sgfd-zoo", "train", *redact_argv(argv)]) + "\n")
            self.legacy_command_file.unlink(missing_ok=True)
        block = f"=== from step {step}, {time.strftime('%Y-%m-%d %H:%M:%S')}\n{provenance.versions()}"
        earlier = read_text(self.versions_file) if self.versions_file.exists() else ""
        write_text(self.root, self.versions_file, earlier + block)

    @functools.cached_property
    def args(self) -> dict[str, Any]:
        """rl-zoo3's saved command-line arguments ({} before the run wrote them, or when unreadable)."""
        return read_yaml(self.config_dir / "args.yml")[0]

    @property
    def seed(self) -> int | None:
        return config_value(self.args, "seed", self.config_dir / "args.yml", "seed")

    @property
    def env_kwargs(self) -> dict[str, Any]:
        """The env kwargs it trained with, its envs' family among them (``env_family``; sgfd_envs.families)."""
        given = config_value(self.args, "env_kwargs", self.config_dir / "args.yml", "mapping")
        recorded = dict(
            given or config_value(self.config, "env_kwargs", self.config_dir / "config.yml", "mapping") or {}
        )
        return env_kwargs_as_trained(self.env_id, recorded, self.args.get("env_family"))

    @property
    def frame_stack(self) -> int | None:
        return config_value(self.config, "frame_stack", self.config_dir / "config.yml", "frames")

    @property
    def problems(self) -> list[str]:
        """What in the folder cannot be read (the rest of it is read as if that file were absent)."""
        found = [problem for name in ("args.yml", "config.yml") if (problem := read_yaml(self.config_dir / name)[1])]
        for read in (lambda: read_index(self.path), lambda: read_json(self.finished_marker)):
            try:
                read()
            except UnreadableFile as error:
                found.append(str(error))
        return found

    # -- checkpoints --

    def checkpoints(self) -> list[Checkpoint]:
        """The checkpoints recorded in the folder, newest first; when the index is unreadable, those its files
        make up (:func:`scan_checkpoints`)."""
        try:
            return read_index(self.path)
        except UnreadableFile:
            return scan_checkpoints(self.path)

    @property
    def checkpoint(self) -> Checkpoint | None:
        """The newest checkpoint whose files are all there at their written sizes (no checksum: cheap enough
        for planning; resuming verifies with :meth:`usable_checkpoint`), or None."""
        return next((c for c in self.checkpoints() if c.problem(self.path, full=False) is None), None)

    def usable_checkpoint(self) -> tuple[Checkpoint | None, list[str]]:
        """The newest checkpoint whose files match their size and sha256, and why each newer one is unusable."""
        problems: list[str] = []
        for checkpoint in self.checkpoints():
            problem = checkpoint.problem(self.path)
            if problem is None:
                return checkpoint, problems
            problems.append(problem)
        return None, problems

    @property
    def finished(self) -> bool:
        """Whether the run says it ended: its final model is whole and no checkpoint is newer than it.

        The say is ``finished.json``, written after the final model. Runs trained before the marker existed
        (or killed between the final model and the marker, which is written last) say it through the final
        model itself: a whole zip whose step count reached the total it was trained for. A run stopped
        early (Ctrl-C, a kill, a full disk) has no final model, or one short of its total.
        """
        steps = None
        try:
            marker = read_json(self.finished_marker)
        except UnreadableFile:
            marker = None
        if marker is not None:
            try:
                written = StoredFile(**marker["model"])
                plain_name(written.name, self.finished_marker)
                whole = written.name == self.model_path.name and written.problem(self.path, full=False) is None
                steps = int(marker["num_timesteps"]) if whole else None
            except (KeyError, TypeError, ValueError):
                steps = None
        if steps is None:
            steps = final_model_steps(self.model_path)
        if steps is None:
            return False
        return all(checkpoint.num_timesteps <= steps for checkpoint in self.checkpoints())

    def log(self, key: str) -> tuple[np.ndarray, np.ndarray]:
        """(timesteps, values) of one logged figure over the whole run, sorted by timesteps.

        A resumed run continues in ``progress_from_<steps>.csv``; where files overlap, the later file wins
        (the resumed run replaced what the crashed one logged after its checkpoint).

        :param key: a logged name, e.g. ``sgfd/classifier_accuracy``
        """
        points: dict[int, float] = {}
        for path in sorted(self.path.glob("progress*.csv"), key=_resume_step):
            rows = [(row.get(STEPS_KEY), row.get(key)) for row in csv_rows(path)]
            resumed_at = _resume_step(path)
            points = {step: value for step, value in points.items() if step <= resumed_at}
            for logged_at, value in rows:
                if logged_at and value:
                    points[whole_number(logged_at, STEPS_KEY, path)] = finite_number(value, key, path)
        steps = np.array(sorted(points), dtype=np.int64)
        return steps, np.array([points[step] for step in sorted(points)], dtype=np.float64)

    def load_model(self, device: str = "cpu") -> BaseAlgorithm:
        """The final model, without allocating its replay buffer."""
        algo_class: type[BaseAlgorithm]
        if self.algo in SGFD_ALGOS:
            algo_class = SGFD_ALGOS[self.algo].algo_class
        else:  # a run rl-zoo3 itself trained into the folder
            from rl_zoo3.utils import ALGOS

            if self.algo not in ALGOS:
                raise ZooError(f"{self.path}: unknown algorithm {self.algo!r}; choose from {', '.join(SGFD_ALGOS)}")
            algo_class = ALGOS[self.algo]
        try:
            return algo_class.load(self.model_path, custom_objects={"buffer_size": 1}, device=device)
        except Exception as error:  # SB3 raises what the zip's contents make it raise
            reason = (str(error).strip().splitlines() or [""])[0]
            what = f"{type(error).__name__}: {reason}"
            raise ZooError(f"{self.model_path}: the final model does not load ({what})") from None


def find_runs(
    folder: Path, algos: Iterable[str] | None = None, env_ids: Iterable[str] | None = None, finished: bool = True
) -> list[RunFolder]:
    """The runs under a log folder, sorted by algo, env and id; optionally only some algos and env ids.

    :param folder: the log folder
    :param algos: only these algorithm keys
    :param env_ids: only these env ids
    :param finished: only finished runs (else every run folder)
    """
    runs = [RunFolder(path) for path in run_paths(folder, algos, env_ids)]
    runs = [run for run in runs if not finished or run.finished]
    return sorted(runs, key=lambda run: (run.algo, run.env_id, run.run_id))


def run_paths(folder: Path, algos: Iterable[str] | None, env_ids: Iterable[str] | None) -> list[Path]:
    """The ``<algo>/<EnvName>_<id>`` folders under ``folder``, optionally of some algos and env ids only."""
    algos, env_ids = set(algos or ()), set(env_ids or ())
    if not Path(folder).is_dir():
        return []
    paths = []
    for algo_dir in sorted(path for path in Path(folder).iterdir() if path.is_dir()):
        if algos and algo_dir.name not in algos:
            continue
        refuse_links(folder, algo_dir, "read runs in")
        found = [path for path in algo_dir.iterdir() if path.is_dir() and _run_env_id(path) is not None]
        if found and not ALGO_KEY.fullmatch(algo_dir.name):  # its name becomes table cells, records' paths
            raise RefusedFile(f"{algo_dir}: refused: its runs' algorithm {algo_dir.name!r} is not an algorithm's key")
        for path in found:
            if not env_ids or _run_env_id(path) in env_ids:
                refuse_links(folder, path, "read")
                paths.append(path)
    return paths


def _run_env_id(path: Path) -> str | None:
    """The env id of a run's folder name ``<EnvName>_<id>``, or None if it is not one of an SGFD id."""
    name, _, run_id = path.name.rpartition("_")
    return ENV_IDS_BY_NAME[name] if name in ENV_IDS_BY_NAME and run_id.isdigit() else None


def runs_by_id(folder: Path, algo: str, env_id: str) -> dict[int, RunFolder]:
    """Every run folder (finished or not) of ``algo`` on ``env_id``, by run id."""
    return {run.run_id: run for run in find_runs(folder, [algo], [env_id], finished=False)}


def select_run(folder: Path, env_id: str, algo: str, run_id: int | None = None) -> RunFolder:
    """The finished run ``run_id`` of ``algo`` on ``env_id``, or the newest one; a ZooError naming the choices.

    :param folder: the log folder
    :param env_id: an SGFD id
    :param algo: algorithm key
    :param run_id: the run's number (the ``_<id>`` suffix); None: the highest
    """
    if not Path(folder).is_dir():
        raise ZooError(f"--folder {folder} does not exist (train first: sgfd-zoo train -f {folder} ...)")
    check_env_id(env_id)
    runs = {run.run_id: run for run in find_runs(folder, [algo], [env_id])}
    if not runs:
        raise ZooError(f"no finished {algo} run of {env_id} under {folder} (expected {algo}/<EnvName>_<id>/)")
    if run_id is None:
        return runs[max(runs)]
    if run_id not in runs:
        raise ZooError(f"--exp-id {run_id}: no finished run {run_id} of {algo} on {env_id}; choose from {sorted(runs)}")
    return runs[run_id]


def _resume_step(path: Path) -> int:
    suffix = path.stem.removeprefix("progress").removeprefix("_from_")
    return int(suffix) if suffix.isdigit() else -1
