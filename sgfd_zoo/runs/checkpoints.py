"""A run's checkpoints on disk: their index (``checkpoint.json``), their files, and finding them without it.

    checkpoint.json                         the index of the two newest checkpoints: each file's size, sha256
    checkpoint_<n>_steps.zip                a checkpoint's model (written last: the checkpoint is complete)
    checkpoint_<part>_<n>_steps.pkl         its other parts: replay_buffer, vecnormalize (SB3's pickles)
    checkpoint_training_state_<n>_steps.npz what an exact resume needs (:mod:`sgfd_zoo.runs.training_state`;
                                            a pickle, .pkl, before version 0.2.0)

The names an index lists are plain file names of the run folder (:func:`sgfd_zoo.runs.safe.plain_name`): an index
naming ``../x`` or ``/x`` is refused, never read.

Files only: what a checkpoint holds and when it is taken is :mod:`sgfd_zoo.runs.checkpoint_callback`'s.
"""

from __future__ import annotations

import re
import shutil
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from sgfd_zoo.runs.files import TMP_PREFIX, StoredFile, UnreadableFile, read_json, sha256_of, write_json
from sgfd_zoo.runs.safe import plain_name

CHECKPOINT_INDEX = "checkpoint.json"
INDEX_FORMAT = 2  # 1: the single-checkpoint index before sizes and checksums ({"num_timesteps", "model", ...})
KEPT_CHECKPOINTS = 2  # the newest and the one before it, to fall back on
_CHECKPOINT_FILE = re.compile(r"checkpoint_(?:(?P<part>[a-z_]+?)_)?(?P<steps>\d+)_steps(?P<suffix>\.[a-z]+)")


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
    def from_json(cls, entry: dict[str, Any], index: Path) -> Checkpoint:
        """The checkpoint an entry of ``index`` describes; a RefusedFile when it names a file outside its folder."""
        files = {part: StoredFile(**stored) for part, stored in entry["files"].items()}
        for stored in files.values():
            plain_name(stored.name, index)
        return cls(int(entry["num_timesteps"]), files)


def read_index(folder: Path) -> list[Checkpoint]:
    """The checkpoints ``checkpoint.json`` lists, newest first ([] without one); an :class:`UnreadableFile`
    when it does not parse. Reads format 1 (one checkpoint, file names only) too."""
    path = Path(folder) / CHECKPOINT_INDEX
    index = read_json(path)
    if index is None:
        return []
    try:
        if "checkpoints" in index:
            return [Checkpoint.from_json(entry, path) for entry in index["checkpoints"]]
        parts = [part for part in ("replay_buffer", "vecnormalize", "model") if part in index or part == "model"]
        names = {part: StoredFile(plain_name(index[part], path)) for part in parts}
        return [Checkpoint(int(index["num_timesteps"]), names)]
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


def remove_checkpoint_files(folder: Path, keep: Iterable[Checkpoint]) -> list[str]:
    """Delete the checkpoint files (and the temporary files of interrupted writes) of ``folder`` that no
    checkpoint of ``keep`` names; returns their names. Only its writer calls this (it holds the run's lock), so
    every temporary file there is one a stopped process left, or one of a process trying to take the lock, which
    is refused either way (:mod:`sgfd_zoo.runs.locks`)."""
    kept = {stored.name for checkpoint in keep for stored in checkpoint.files.values()}
    removed = []
    # The run's own subfolders only: a linked one is not followed (what it points to is not the run's).
    subfolders = [path for path in Path(folder).iterdir() if path.is_dir() and not path.is_symlink()]
    leftovers = [path for where in [Path(folder), *subfolders] for path in where.glob(f"{TMP_PREFIX}*")]
    for path in [*Path(folder).glob("checkpoint_*_steps.*"), *leftovers]:
        if path.name in kept or path.name == CHECKPOINT_INDEX:
            continue
        # a link is removed itself (unlink never follows one), not what it points to
        if path.is_file() or path.is_symlink():
            path.unlink(missing_ok=True)
            removed.append(path.name)
        elif path.is_dir() and path.name.startswith(TMP_PREFIX):  # a write's private folder (files.write_below)
            shutil.rmtree(path)  # descriptor-based where the system allows: it follows no link inside
            removed.append(path.name)
    return sorted(removed)
