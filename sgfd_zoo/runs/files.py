"""Files written whole and read back with their problems named: the zoo's one way to write a file.

Every file the zoo writes goes through :func:`atomic_write` (or :func:`write_below`, from the folder a command was
given): written in a private folder beside it whose name is unique to the writing process
(``.tmp-<host>-<pid>-<random>-<name>``), fsync'd, checked, renamed over the old one, and the folder fsync'd; a
crash leaves the old file or the new one, never a mix, and two processes never share a temporary file. The folders
are held by descriptors, reached one name at a time without following a link (``O_NOFOLLOW``), and the writer
is handed its file through the held folder (``/proc/self/fd/<folder>/...``): a folder swapped for a link while it
writes cannot take even the temporary file elsewhere. No heavy import: reporting reads files through this module.
"""

from __future__ import annotations

import contextlib
import errno
import hashlib
import json
import os
import secrets
import shutil
import socket
import zipfile
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from sgfd_zoo.arguments import ZooError
from sgfd_zoo.runs.bounded import (
    MAX_JSON_DEPTH,
    MAX_ZIP_INFLATED_BYTES,
    RefusedFile,
    UnreadableFile,
    json_depth,
    load_json,
    read_bytes,
    zip_inflated_size,
)

TMP_PREFIX = ".tmp-"
#: Where Linux shows the processes' open descriptors as paths: a writer reaches its file through the held folder.
PROC = Path("/proc")


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
                inflated = zip_inflated_size(archive)
                if inflated > MAX_ZIP_INFLATED_BYTES:
                    return f"{name} declares {inflated} bytes inflated, over MAX_ZIP_INFLATED_BYTES (docs/trust.md)"
                bad = archive.testzip()
            return None if bad is None else f"{name}: member {bad} does not match its CRC"
        if path.suffix == ".pkl":
            with open(path, "rb") as handle:
                handle.seek(-1, os.SEEK_END)
                return None if handle.read(1) == b"." else f"{name} does not end like a pickle (truncated?)"
        if path.suffix == ".json":
            data = read_bytes(path, "MAX_JSON_BYTES")
            if json_depth(data) > MAX_JSON_DEPTH:
                return f"{name} nests deeper than MAX_JSON_DEPTH = {MAX_JSON_DEPTH} (docs/trust.md)"
            json.loads(data)
    except (OSError, ValueError, EOFError, zipfile.BadZipFile, RuntimeError, ZooError) as error:
        return f"{name} is unreadable ({type(error).__name__}: {error})"
    return None


def temporary_path(path: Path) -> Path:
    """A name beside ``path`` for writing it, unique to this process and this call (processes on other hosts of a
    shared file system included), ending like ``path`` (SB3 appends ".zip" to a name that does not)."""
    host = socket.gethostname().split(".")[0] or "host"
    return path.with_name(f"{TMP_PREFIX}{host}-{os.getpid()}-{secrets.token_hex(4)}-{path.name}")


def _refused_link(path: Path, root: Path) -> RefusedFile:
    return RefusedFile(
        f"{path}: refused to write in it: a symbolic link, or no longer a folder, inside {root}; sgfd-zoo never "
        "follows links there"
    )


@contextlib.contextmanager
def held_folder(root: Path, folder: Path | None = None, create: bool = False) -> Iterator[int]:
    """A descriptor of ``folder`` (``root`` itself by default), reached from ``root`` one name at a time, none
    followed if it is a link (``O_NOFOLLOW``); a :class:`~sgfd_zoo.runs.bounded.RefusedFile` when one is a link or
    leads out of ``root``. ``root`` itself may be a link: the user gave it.

    :param root: the folder the command was given
    :param folder: a folder below it
    :param create: make the missing folders on the way
    """
    root = Path(root)
    try:
        parts = () if folder is None else Path(folder).relative_to(root).parts
    except ValueError:
        raise RefusedFile(f"{folder}: refused to write in it: it is not inside {root}") from None
    if any(part in ("..", ".") for part in parts):
        raise RefusedFile(f"{folder}: refused to write in it: '..' in its path leads out of {root}")
    if create:
        root.mkdir(parents=True, exist_ok=True)
    descriptor = os.open(root, os.O_RDONLY | os.O_DIRECTORY | os.O_CLOEXEC)
    try:
        for depth, part in enumerate(parts):
            if create:
                with contextlib.suppress(FileExistsError):
                    os.mkdir(part, dir_fd=descriptor)
            try:
                child = os.open(part, os.O_RDONLY | os.O_DIRECTORY | os.O_NOFOLLOW | os.O_CLOEXEC, dir_fd=descriptor)
            except OSError as error:
                if error.errno in (errno.ELOOP, errno.ENOTDIR):
                    raise _refused_link(root.joinpath(*parts[: depth + 1]), root) from None
                raise
            os.close(descriptor)
            descriptor = child
        yield descriptor
    finally:
        os.close(descriptor)


def _through(folder: int, name: str, path: Path) -> Path:
    """The path by which a writer reaches ``name`` inside the held ``folder`` (``path`` where the system shows no
    descriptors as paths): by this process's id, not ``self``, so that a program it starts (ffmpeg) reaches it too."""
    descriptors = PROC / str(os.getpid()) / "fd"
    return descriptors / str(folder) / name if descriptors.is_dir() else path


def atomic_write(path: Path, write: Callable[[str], object]) -> StoredFile:
    """Write ``path`` whole or not at all (:func:`write_below` from its own folder)."""
    path = Path(path)
    return write_below(path.parent, path, write)


def write_below(root: Path, path: Path, write: Callable[[str], object]) -> StoredFile:
    """Write ``path`` (below the folder ``root``) whole or not at all: ``write(tmp)`` writes a temporary file in a
    private folder beside it (:func:`temporary_path`), which is fsync'd, checked (:func:`content_problem`), renamed
    over ``path``, and the folder fsync'd. Each folder from ``root`` down is held by its descriptor, none a link
    (:func:`held_folder`). On any failure the temporary file is removed; an OSError or a failed check raises
    :class:`FileWriteError`.

    :param root: the folder the command was given (it may be a link)
    :param path: the file to write
    :param write: writes the file at the path it is given (keeping its suffix: SB3 appends ".zip" otherwise)
    :return: the file's name, size and sha256
    """
    path = Path(path)
    with held_folder(root, path.parent) as folder:
        private = temporary_path(path).name
        os.mkdir(private, 0o700, dir_fd=folder)  # only this user adds names there: none can be swapped for a link
        held = os.open(private, os.O_RDONLY | os.O_DIRECTORY | os.O_NOFOLLOW | os.O_CLOEXEC, dir_fd=folder)
        tmp = _through(held, path.name, path.parent / private / path.name)
        try:
            write(str(tmp))
            fsync(tmp)
            problem = content_problem(tmp)
            if problem is not None:
                raise FileWriteError(path, f"written incomplete: {problem}")
            stored = StoredFile(path.name, tmp.stat().st_size, sha256_of(tmp))
            os.replace(path.name, path.name, src_dir_fd=held, dst_dir_fd=folder)
            os.fsync(folder)
        except OSError as error:
            written = tmp.stat().st_size if tmp.exists() else 0
            raise FileWriteError(path, error.strerror or str(error), error, written) from error
        finally:
            for leftover in os.listdir(held):  # the file when it was not renamed, and whatever else a writer left
                with contextlib.suppress(OSError):
                    os.unlink(leftover, dir_fd=held)
            os.close(held)
            with contextlib.suppress(OSError):
                os.rmdir(private, dir_fd=folder)
    return stored


def fsync(path: Path) -> None:
    """Flush ``path`` (a file or a folder) to the disk."""
    descriptor = os.open(path, os.O_RDONLY)
    try:
        os.fsync(descriptor)
    finally:
        os.close(descriptor)


def write_json(path: Path, value: Any) -> StoredFile:
    return atomic_write(path, lambda tmp: Path(tmp).write_text(json.dumps(value, indent=1)))


def read_json(path: Path) -> Any:
    """The parsed file, None when it does not exist, an :class:`UnreadableFile` when it does not parse; refused
    over the limits of :func:`~sgfd_zoo.runs.bounded.load_json` (size, depth, numbers that are not finite)."""
    if not path.exists():
        return None
    try:
        data = read_bytes(path, "MAX_JSON_BYTES")
    except OSError as error:
        raise UnreadableFile(f"{path} is unreadable ({type(error).__name__}: {error})") from None
    return load_json(data, path)


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
    free = f"{megabytes(shutil.disk_usage(folder).free)} free"
    if expected_size:
        room = f"it needs about {megabytes(expected_size)}, {free}"
    elif error.bytes_written:
        room = f"it needs more than {megabytes(error.bytes_written)}, {free}"
    else:
        room = free
    return f"{what} was not written to {folder}: {error.reason} ({room}); {kept}"


def megabytes(size: float) -> str:
    """A byte count for people: kB, MB or GB."""
    return f"{size / 1e9:.1f} GB" if size >= 1e9 else f"{size / 1e6:.1f} MB" if size >= 1e5 else f"{size / 1e3:.0f} kB"
