"""The run folders sgfd-zoo writes and reads, in one place (rl-zoo3's layout plus the zoo's files):

    <log folder>/<algo>/<EnvName>_<id>/        a run (:class:`RunFolder`); EnvName is the id with "/" -> "-"
        <EnvName>.zip                           the final model
        finished.json                           written after the final model: the run is finished
        <EnvName>/args.yml, config.yml          rl-zoo3's saved arguments and hyperparameters
        evaluations_<split>.npz                 evaluations during training, per split
        progress.csv, progress_from_<n>.csv     everything logged (a resumed run continues in a new file)
        checkpoint.json                         the index of the two newest checkpoints: each file's size, sha256
        checkpoint_<n>_steps.zip                a checkpoint's model (written last: the checkpoint is complete)
        checkpoint_<part>_<n>_steps.pkl         its other parts: replay_buffer, vecnormalize
        final_evaluation.json                   sgfd-zoo evaluate's result for the final model (reused while it fits)
    <log folder>/<algo>/<EnvName>_<id>.log      a sweep run's output, beside its folder

A study keeps a finished run's compact record next to its spec, with no model (:class:`RunRecord`):

    <study>/runs/<algo>/<EnvName>_<id>/         the same name as the run folder it was exported from
        config.yml, args.yml                    the run's hyperparameters and arguments
        evaluations_<split>.npz                 as in the run folder
        diagnostics.csv                         the logged figures the study reads, one row per logged step
        final_evaluation.csv                    the final model's evaluation, one row per split (written last)

Every file the zoo writes here goes through :func:`atomic_write`: a temporary ``.tmp-<name>``, fsync'd, checked,
renamed over the old one, and the folder fsync'd; a crash leaves the old file or the new one, never a mix.

Whether a run is finished is decided here only (:attr:`RunFolder.finished`). The module reads and writes files
and nothing more: it imports nothing of the experiment, and plotting and the sweep's planning use it without
torch (``load_model`` imports the algorithm's class).
"""

from __future__ import annotations

import csv
import functools
import hashlib
import json
import os
import re
import shutil
import zipfile
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import yaml

import sgfd_envs
from sgfd_zoo.algos import SGFD_ALGOS
from sgfd_zoo.arguments import ZooError, check_env_id

if TYPE_CHECKING:
    from stable_baselines3.common.base_class import BaseAlgorithm

CHECKPOINT_INDEX = "checkpoint.json"
FINISHED_MARKER = "finished.json"
TMP_PREFIX = ".tmp-"
STEPS_KEY = "time/total_timesteps"
INDEX_FORMAT = 2  # 1: the single-checkpoint index before sizes and checksums ({"num_timesteps", "model", ...})
KEPT_CHECKPOINTS = 2  # the newest and the one before it, to fall back on
_CHECKPOINT_FILE = re.compile(r"checkpoint_(?:(?P<part>[a-z_]+?)_)?(?P<steps>\d+)_steps(?P<suffix>\.[a-z]+)")


def env_name(env_id: str) -> str:
    """rl-zoo3's name of an env id in paths: ``SGFD/MT-walker-walk-v0`` -> ``SGFD-MT-walker-walk-v0``."""
    return env_id.replace("/", "-")


ENV_IDS_BY_NAME = {env_name(env_id): env_id for env_id in sgfd_envs.ENV_IDS}


class UnreadableFile(ZooError):
    """A run's file that exists but cannot be read back (truncated, zeroed, not what the zoo writes)."""


class NoUsableCheckpoint(ZooError):
    """``--resume`` of a run none of whose checkpoints verifies; the message says how to start it again."""


class FileWriteError(ZooError):
    """A file that could not be written whole; nothing of it is left behind.

    :param path: the file
    :param reason: what went wrong
    :param error: the OSError, when the system refused the write (disk full, ...)
    :param bytes_written: bytes of it on disk when the write failed
    """

    def __init__(self, path: Path, reason: str, error: OSError | None = None, bytes_written: int = 0):
        super().__init__(f"{path}: {reason}")
        self.path, self.reason, self.error, self.bytes_written = path, reason, error, bytes_written


# -- files written whole -----------------------------------------------------------------------------


@dataclass(frozen=True)
class StoredFile:
    """A file as written: its name in the run folder, size and sha256 (both None in an index of format 1 and
    for files found without an index, which are checked by their structure instead).

    :param name: file name, relative to the run folder
    :param size: bytes
    :param sha256: hex digest
    """

    name: str
    size: int | None = None
    sha256: str | None = None

    def problem(self, folder: Path, full: bool = True) -> str | None:
        """Why the file in ``folder`` is not the one written, or None; ``full``: also compare its checksum."""
        path = Path(folder) / self.name
        if not path.is_file():
            return f"{self.name} is missing"
        if self.size is None:
            return content_problem(path)
        size = path.stat().st_size
        if size != self.size:
            return f"{self.name} has {size} bytes, {self.size} were written"
        if full and self.sha256 is not None and sha256_of(path) != self.sha256:
            return f"{self.name} does not match its sha256 (changed after it was written)"
        return None

    def to_json(self) -> dict[str, Any]:
        return {"name": self.name, "size": self.size, "sha256": self.sha256}


def sha256_of(path: Path, chunk: int = 1 << 22) -> str:
    digest = hashlib.sha256()
    with open(path, "rb") as handle:
        while block := handle.read(chunk):
            digest.update(block)
    return digest.hexdigest()


def content_problem(path: Path) -> str | None:
    """Why ``path`` is not a whole file of its kind (zip, pickle, json), or None. Catches truncated and zeroed
    files without an expected checksum: a zip's members must match their CRCs, a pickle must end with its
    STOP opcode, a json file must parse."""
    name = path.name
    try:
        if path.stat().st_size == 0:
            return f"{name} is empty"
        if path.suffix in (".zip", ".npz"):
            with zipfile.ZipFile(path) as archive:
                bad = archive.testzip()
            return None if bad is None else f"{name}: member {bad} does not match its CRC"
        if path.suffix == ".pkl":
            with open(path, "rb") as handle:
                handle.seek(-1, os.SEEK_END)
                return None if handle.read(1) == b"." else f"{name} does not end like a pickle (truncated?)"
        if path.suffix == ".json":
            json.loads(path.read_text())
    except (OSError, ValueError, EOFError, zipfile.BadZipFile, RuntimeError) as error:
        return f"{name} is unreadable ({type(error).__name__}: {error})"
    return None


def atomic_write(path: Path, write: Callable[[str], None]) -> StoredFile:
    """Write ``path`` whole or not at all: ``write(tmp)`` writes a temporary file beside it, which is fsync'd,
    checked (:func:`content_problem`), renamed over ``path``, and the folder fsync'd. On any failure the
    temporary file is removed; an OSError or a failed check raises :class:`FileWriteError`.

    :param path: the file to write
    :param write: writes the file at the path it is given (keeping its suffix: SB3 appends ".zip" otherwise)
    :return: the file's name, size and sha256
    """
    path = Path(path)
    tmp = path.with_name(f"{TMP_PREFIX}{path.name}")
    try:
        write(str(tmp))
        _fsync(tmp)
        problem = content_problem(tmp)
        if problem is not None:
            raise FileWriteError(path, f"written incomplete: {problem}")
        stored = StoredFile(path.name, tmp.stat().st_size, sha256_of(tmp))
        os.replace(tmp, path)
        _fsync(path.parent)
    except OSError as error:
        written = tmp.stat().st_size if tmp.exists() else 0
        tmp.unlink(missing_ok=True)
        raise FileWriteError(path, error.strerror or str(error), error, written) from error
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    return stored


def _fsync(path: Path) -> None:
    descriptor = os.open(path, os.O_RDONLY)
    try:
        os.fsync(descriptor)
    finally:
        os.close(descriptor)


def write_json(path: Path, value: Any) -> StoredFile:
    return atomic_write(path, lambda tmp: Path(tmp).write_text(json.dumps(value, indent=1)))


def _read_json(path: Path) -> Any:
    """The parsed file, None when it does not exist, an :class:`UnreadableFile` when it does not parse."""
    if not path.exists():
        return None
    try:
        return json.loads(path.read_text())
    except (OSError, ValueError) as error:
        raise UnreadableFile(f"{path} is unreadable ({type(error).__name__}: {error})") from None


# -- checkpoints -------------------------------------------------------------------------------------


def checkpoint_file_name(part: str, steps: int, suffix: str) -> str:
    """``checkpoint_<steps>_steps.zip`` for the model, ``checkpoint_<part>_<steps>_steps<suffix>`` else."""
    return f"checkpoint_{steps}_steps{suffix}" if part == "model" else f"checkpoint_{part}_{steps}_steps{suffix}"


@dataclass(frozen=True)
class Checkpoint:
    """A checkpoint: the step it was taken at and its files, by part (``model``, ``replay_buffer``, ...).

    :param num_timesteps: the model's step count when it was saved
    :param files: part -> file, in the order they were written (the model last)
    """

    num_timesteps: int
    files: dict[str, StoredFile]

    def problem(self, folder: Path, full: bool = True) -> str | None:
        """The first reason a file of the checkpoint is not as written, or None (see :meth:`StoredFile.problem`)."""
        if "model" not in self.files:
            return f"the checkpoint at {self.num_timesteps} steps has no model file"
        return next((p for f in self.files.values() if (p := f.problem(folder, full)) is not None), None)

    @property
    def size(self) -> int | None:
        """Bytes of all its files, when known."""
        sizes = [stored.size for stored in self.files.values()]
        return None if None in sizes else sum(sizes)  # type: ignore[arg-type]

    def to_json(self) -> dict[str, Any]:
        return {"num_timesteps": self.num_timesteps, "files": {p: f.to_json() for p, f in self.files.items()}}

    @classmethod
    def from_json(cls, entry: dict[str, Any]) -> Checkpoint:
        files = {part: StoredFile(**stored) for part, stored in entry["files"].items()}
        return cls(int(entry["num_timesteps"]), files)


def read_index(folder: Path) -> list[Checkpoint]:
    """The checkpoints ``checkpoint.json`` lists, newest first ([] without one); an :class:`UnreadableFile`
    when it does not parse. Reads format 1 (one checkpoint, file names only) too."""
    path = Path(folder) / CHECKPOINT_INDEX
    index = _read_json(path)
    if index is None:
        return []
    try:
        if "checkpoints" in index:
            return [Checkpoint.from_json(entry) for entry in index["checkpoints"]]
        names = {part: StoredFile(index[part]) for part in ("replay_buffer", "vecnormalize") if part in index}
        return [Checkpoint(int(index["num_timesteps"]), {**names, "model": StoredFile(index["model"])})]
    except (KeyError, TypeError, ValueError, AttributeError) as error:
        raise UnreadableFile(f"{path} is not a checkpoint index ({type(error).__name__}: {error})") from None


def write_index(folder: Path, checkpoints: list[Checkpoint]) -> None:
    """Replace ``checkpoint.json`` with these checkpoints, newest first."""
    index = {"format": INDEX_FORMAT, "checkpoints": [checkpoint.to_json() for checkpoint in checkpoints]}
    write_json(Path(folder) / CHECKPOINT_INDEX, index)


def scan_checkpoints(folder: Path) -> list[Checkpoint]:
    """The checkpoints whose files are in ``folder``, newest first, found by their names (for a folder whose
    index is unreadable). Only those with a model file: it is written last, so the others are incomplete."""
    groups: dict[int, dict[str, StoredFile]] = {}
    for path in Path(folder).glob("checkpoint_*_steps.*"):
        match = _CHECKPOINT_FILE.fullmatch(path.name)
        if match is not None:
            groups.setdefault(int(match["steps"]), {})[match["part"] or "model"] = StoredFile(path.name)
    return [Checkpoint(steps, files) for steps, files in sorted(groups.items(), reverse=True) if "model" in files]


def describe_checkpoint(folder: Path, checkpoint: Checkpoint) -> Checkpoint:
    """``checkpoint`` with the size and sha256 of each file that has none yet (found without an index, or in an
    index of format 1), read from ``folder``."""
    files = {}
    for part, stored in checkpoint.files.items():
        if stored.size is None or stored.sha256 is None:
            path = Path(folder) / stored.name
            stored = StoredFile(stored.name, path.stat().st_size, sha256_of(path))
        files[part] = stored
    return Checkpoint(checkpoint.num_timesteps, files)


def write_failure(what: str, folder: Path, error: FileWriteError, expected_size: int | None, kept: str) -> str:
    """One line for a write that failed: what was not written where, why, the room it needs and the room there
    is, and what is kept.

    :param what: e.g. ``the checkpoint at 800 steps``
    :param folder: where it was written
    :param error: the failure
    :param expected_size: the bytes it needs, when known (a checkpoint: the previous one's size); else the
        bytes written before the failure are a lower bound
    :param kept: what is intact, e.g. ``the previous checkpoint (400 steps) is intact``
    """
    free = f"{_megabytes(shutil.disk_usage(folder).free)} free"
    if expected_size:
        room = f"it needs about {_megabytes(expected_size)}, {free}"
    elif error.bytes_written:
        room = f"it needs more than {_megabytes(error.bytes_written)}, {free}"
    else:
        room = free
    return f"{what} was not written to {folder}: {error.reason} ({room}); {kept}"


def _megabytes(size: float) -> str:
    return f"{size / 1e9:.1f} GB" if size >= 1e9 else f"{size / 1e6:.1f} MB" if size >= 1e5 else f"{size / 1e3:.0f} kB"


def mark_finished(folder: Path, model: StoredFile, num_timesteps: int) -> None:
    """Record in run folder ``folder`` that its final model ``model`` (already written) ends it at ``num_timesteps``."""
    write_json(Path(folder) / FINISHED_MARKER, {"num_timesteps": int(num_timesteps), "model": model.to_json()})


def remove_checkpoint_files(folder: Path, keep: Iterable[Checkpoint]) -> list[str]:
    """Delete the checkpoint files (and the ``.tmp-`` files of interrupted writes) of ``folder`` that no
    checkpoint of ``keep`` names; returns their names."""
    kept = {stored.name for checkpoint in keep for stored in checkpoint.files.values()}
    removed = []
    leftovers = [*Path(folder).glob(f"{TMP_PREFIX}*"), *Path(folder).glob(f"*/{TMP_PREFIX}*")]
    for path in [*Path(folder).glob("checkpoint_*_steps.*"), *leftovers]:
        if path.is_file() and path.name not in kept and path.name != CHECKPOINT_INDEX:
            path.unlink()
            removed.append(path.name)
    return sorted(removed)


# -- run folders -------------------------------------------------------------------------------------


@dataclass(frozen=True)
class _NamedRun:
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
    def config_dir(self) -> Path:
        """Where its ``config.yml`` (and ``args.yml``) lie."""
        return self.path

    @property
    def versions_file(self) -> Path:
        """What trained it (:mod:`sgfd_zoo.provenance`), a block per start: ``versions.txt`` beside its config."""
        return self.config_dir / "versions.txt"

    @functools.cached_property
    def config(self) -> dict[str, Any]:
        """The hyperparameters the run trained with ({} before the run wrote them, or when unreadable)."""
        return _read_yaml(self.config_dir / "config.yml")[0]

    @property
    def accuracy_threshold(self) -> float:
        """The accuracy SGFD's classifier trained to in this run: its config's, else its reading's default."""
        threshold = self.config.get("accuracy_threshold")
        if threshold is None:
            from sb3_sgfd.sgfd.settings import SGFDSettings  # here: reading run folders needs no torch

            threshold = SGFDSettings.of_reading(self.config.get("reading", "paper")).accuracy_threshold
        return float(threshold)

    def evaluations(self, split: str) -> dict[str, np.ndarray] | None:
        """``timesteps``, ``results`` (evaluations x episodes) and ``ep_lengths`` of a split, or None."""
        return _read_evaluations(self.path / f"evaluations_{split}.npz")


@dataclass(frozen=True)
class RunFolder(_NamedRun):
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

    @property
    def model_path(self) -> Path:
        return self.path / f"{env_name(self.env_id)}.zip"

    @property
    def finished_marker(self) -> Path:
        return self.path / FINISHED_MARKER

    @property
    def final_evaluation(self) -> Path:
        """Where ``sgfd-zoo evaluate`` keeps the final model's evaluation, to reuse it."""
        return self.path / "final_evaluation.json"

    @property
    def command_file(self) -> Path:
        """The ``sgfd-zoo train`` flags the run was last started or resumed with (JSON), to say how it goes on."""
        return self.path / "command.json"

    def train_argv(self) -> list[str] | None:
        """Those flags; None for a run that did not record them (older runs) or whose file is unreadable."""
        try:
            argv = _read_json(self.command_file)
        except UnreadableFile:
            return None
        return [str(arg) for arg in argv] if isinstance(argv, list) else None

    @property
    def config_dir(self) -> Path:
        return self.path / env_name(self.env_id)

    @functools.cached_property
    def args(self) -> dict[str, Any]:
        """rl-zoo3's saved command-line arguments ({} before the run wrote them, or when unreadable)."""
        return _read_yaml(self.config_dir / "args.yml")[0]

    @property
    def seed(self) -> int | None:
        seed = self.args.get("seed")
        return None if seed is None else int(seed)

    @property
    def env_kwargs(self) -> dict[str, Any]:
        return dict(self.args.get("env_kwargs") or self.config.get("env_kwargs") or {})

    @property
    def frame_stack(self) -> int | None:
        return self.config.get("frame_stack")

    @property
    def problems(self) -> list[str]:
        """What in the folder cannot be read (the rest of it is read as if that file were absent)."""
        found = [problem for name in ("args.yml", "config.yml") if (problem := _read_yaml(self.config_dir / name)[1])]
        for read in (lambda: read_index(self.path), lambda: _read_json(self.finished_marker)):
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
        problems = []
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
            marker = _read_json(self.finished_marker)
        except UnreadableFile:
            marker = None
        if marker is not None:
            try:
                written = StoredFile(**marker["model"])
                steps = int(marker["num_timesteps"]) if written.problem(self.path, full=False) is None else None
            except (KeyError, TypeError, ValueError):
                steps = None
        if steps is None:
            steps = _final_model_steps(self.model_path)
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
            with path.open(newline="") as handle:
                reader = csv.DictReader(handle)
                if reader.fieldnames is None or key not in reader.fieldnames or STEPS_KEY not in reader.fieldnames:
                    continue
                rows = [(row[STEPS_KEY], row[key]) for row in reader]
            resumed_at = _resume_step(path)
            points = {step: value for step, value in points.items() if step <= resumed_at}
            for steps, value in rows:
                if steps and value:
                    points[int(float(steps))] = float(value)
        steps = np.array(sorted(points), dtype=np.int64)
        return steps, np.array([points[step] for step in steps], dtype=np.float64)

    def load_model(self, device: str = "cpu") -> BaseAlgorithm:
        """The final model, without allocating its replay buffer."""
        if self.algo in SGFD_ALGOS:
            algo_class = SGFD_ALGOS[self.algo].algo_class
        else:  # a run rl-zoo3 itself trained into the folder
            from rl_zoo3.utils import ALGOS

            if self.algo not in ALGOS:
                raise ZooError(f"{self.path}: unknown algorithm {self.algo!r}; choose from {', '.join(SGFD_ALGOS)}")
            algo_class = ALGOS[self.algo]
        return algo_class.load(self.model_path, custom_objects={"buffer_size": 1}, device=device)


def _final_model_steps(path: Path) -> int | None:
    """The step count of a whole final model that reached the total it was trained for, else None."""
    try:
        with zipfile.ZipFile(path) as archive:
            data = json.loads(archive.read("data"))
        steps, total = int(data["num_timesteps"]), int(data["_total_timesteps"])
    except (OSError, ValueError, KeyError, TypeError, EOFError, zipfile.BadZipFile, RuntimeError):
        return None
    return steps if 0 < total <= steps else None


def find_runs(
    folder: Path, algos: Iterable[str] | None = None, env_ids: Iterable[str] | None = None, finished: bool = True
) -> list[RunFolder]:
    """The runs under a log folder, sorted by algo, env and id; optionally only some algos and env ids.

    :param folder: the log folder
    :param algos: only these algorithm keys
    :param env_ids: only these env ids
    :param finished: only finished runs (else every run folder)
    """
    runs = [run for path in _run_paths(folder, algos, env_ids) if (run := RunFolder(path)).finished or not finished]
    return sorted(runs, key=lambda run: (run.algo, run.env_id, run.run_id))


def _run_paths(folder: Path, algos: Iterable[str] | None, env_ids: Iterable[str] | None) -> list[Path]:
    """The ``<algo>/<EnvName>_<id>`` folders under ``folder``, optionally of some algos and env ids only."""
    algos, env_ids = set(algos or ()), set(env_ids or ())
    if not Path(folder).is_dir():
        return []
    paths = []
    for algo_dir in sorted(path for path in Path(folder).iterdir() if path.is_dir()):
        if algos and algo_dir.name not in algos:
            continue
        for path in algo_dir.iterdir():
            env_id = _run_env_id(path) if path.is_dir() else None
            if env_id is not None and (not env_ids or env_id in env_ids):
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


# -- a study's records of finished runs -----------------------------------------------------------------

FINAL_EVALUATION_FIELDS = ("algo", "env", "split", "seed", "mean_reward", "std_reward", "n_episodes")
# Kept when present: whether the split played on a built-in stand-in of a benchmark's data (older records lack it).
OPTIONAL_EVALUATION_FIELDS = ("stand_in",)


@dataclass(frozen=True)
class RunRecord(_NamedRun):
    """A finished run as a study keeps it next to its spec: ``<study>/runs/<algo>/<EnvName>_<id>``. What the
    study's tables and figures read, so that a later session, on a machine without the log folder, continues
    the study without training these runs again.

    :param path: the record's folder
    """

    @property
    def final_evaluation(self) -> Path:
        return self.path / "final_evaluation.csv"

    @property
    def diagnostics(self) -> Path:
        return self.path / "diagnostics.csv"

    @property
    def source_file(self) -> Path:
        return self.path / "source.txt"

    @property
    def source(self) -> Path | None:
        """The log run this record was made from (None for a record written before records named it)."""
        return Path(self.source_file.read_text().strip()) if self.source_file.exists() else None

    @functools.cached_property
    def final_rows(self) -> list[dict[str, Any]]:
        """The final model's evaluation, one row per split ([] when the record has none), as ``sgfd-zoo
        evaluate`` gives it, ``run`` being the record's folder."""
        if not self.final_evaluation.exists():
            return []
        with self.final_evaluation.open(newline="") as handle:
            rows = list(csv.DictReader(handle))
        types = {"seed": int, "mean_reward": float, "std_reward": float, "n_episodes": int}
        try:
            return [
                {
                    **{key: types.get(key, str)(row[key]) for key in FINAL_EVALUATION_FIELDS},
                    **{key: row[key] for key in OPTIONAL_EVALUATION_FIELDS if row.get(key)},
                    "run": str(self.path),
                }
                for row in rows
            ]
        except (KeyError, TypeError, ValueError) as error:
            raise UnreadableFile(f"{self.final_evaluation} is unreadable ({type(error).__name__}: {error})") from None

    @property
    def seed(self) -> int | None:
        return self.final_rows[0]["seed"] if self.final_rows else None

    @property
    def complete(self) -> bool:
        """Whether the record has the final model's evaluation on every split of its env."""
        return {row["split"] for row in self.final_rows} >= set(sgfd_envs.splits(self.env_id))

    def log(self, key: str) -> tuple[np.ndarray, np.ndarray]:
        """(timesteps, values) of one logged figure kept in ``diagnostics.csv`` (empty when it was not kept)."""
        steps, values = [], []
        if self.diagnostics.exists():
            with self.diagnostics.open(newline="") as handle:
                for row in csv.DictReader(handle):
                    if row.get(key):
                        steps.append(int(row["timesteps"]))
                        values.append(float(row[key]))
        return np.array(steps, dtype=np.int64), np.array(values, dtype=np.float64)

    def write(self, run: RunFolder, final_rows: list[dict[str, Any]], diagnostics: Callable[[Path], None]) -> None:
        """This record of the finished ``run``: its files, then its final evaluation (last: a record with
        one is whole).

        :param run: the run folder
        :param final_rows: its final model's evaluation (``sgfd-zoo evaluate``'s rows)
        :param diagnostics: writes the logged figures to the path it is given
        """
        self.path.mkdir(parents=True, exist_ok=True)
        self.final_evaluation.unlink(missing_ok=True)
        atomic_write(self.source_file, lambda tmp: Path(tmp).write_text(f"{run.path.resolve()}\n"))
        for npz in sorted(run.path.glob("evaluations_*.npz")):
            atomic_write(self.path / npz.name, lambda tmp, npz=npz: shutil.copyfile(npz, tmp))
        for name in ("config.yml", "args.yml", run.versions_file.name):
            if (run.config_dir / name).exists():
                atomic_write(self.path / name, lambda tmp, name=name: shutil.copyfile(run.config_dir / name, tmp))
        atomic_write(self.diagnostics, lambda tmp: diagnostics(Path(tmp)))

        def write_rows(tmp: str) -> None:
            with open(tmp, "w", newline="") as handle:
                writer = csv.DictWriter(
                    handle, FINAL_EVALUATION_FIELDS + OPTIONAL_EVALUATION_FIELDS, extrasaction="ignore"
                )
                writer.writeheader()
                writer.writerows(final_rows)

        atomic_write(self.final_evaluation, write_rows)
        self.__dict__.pop("final_rows", None)


def find_records(
    folder: Path, algos: Iterable[str] | None = None, env_ids: Iterable[str] | None = None
) -> list[RunRecord]:
    """The run records under a study's ``runs`` folder, sorted by algo, env and id (whole or not: see
    :attr:`RunRecord.complete`).

    :param folder: the study's ``runs`` folder
    :param algos: only these algorithm keys
    :param env_ids: only these env ids
    """
    records = [RunRecord(path) for path in _run_paths(folder, algos, env_ids)]
    return sorted(records, key=lambda record: (record.algo, record.env_id, record.run_id))


def _read_evaluations(path: Path) -> dict[str, np.ndarray] | None:
    if not path.exists():
        return None
    with np.load(path) as data:
        return {key: data[key] for key in data.files}


def _read_yaml(path: Path) -> tuple[dict[str, Any], str | None]:
    """The mapping in a yaml file ({} when absent) and, when it cannot be read, why."""
    if not path.exists():
        return {}, None
    try:
        loaded = yaml.load(path.read_text(), Loader=yaml.UnsafeLoader)
        # rl-zoo3 writes an OrderedDict, or a list of (key, value) pairs
        return (dict(loaded) if loaded else {}), None
    except (OSError, ValueError, TypeError, yaml.YAMLError) as error:
        return {}, f"{path} is unreadable ({type(error).__name__}: {str(error).splitlines()[0]})"


def _resume_step(path: Path) -> int:
    suffix = path.stem.removeprefix("progress").removeprefix("_from_")
    return int(suffix) if suffix.isdigit() else -1
