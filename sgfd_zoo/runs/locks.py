"""One run, one folder, one writer: a new run claims its folder before anything is built, and a run's writer holds
its lock, ``<run>/writer.lock``, while it trains.

Both work on a shared file system (NFS, Lustre, ...) between processes of several hosts, because they rest on
operations that are atomic there: creating a folder (``mkdir`` fails if it exists) claims a new run's folder;
linking a whole, fsync'd lock file to ``writer.lock`` (``link`` fails if it exists) takes the lock; renaming a
dead writer's lock away takes it over. No in-memory or ``flock`` state is involved.

The lock names its writer (pid, host, start time); its heartbeat is the lock file's modification time, which a
thread of the writer renews every :data:`HEARTBEAT_SECONDS`. A second writer is refused in one line naming the
holder, unless the holder is dead: on the same host, its process is gone; on any host, its heartbeat is older
than :data:`STALE_SECONDS` (a machine lost with the process). Such a lock is taken over with a one-line warning.
A writer that finds its lock taken over (it hung longer than that) stops without writing more.
"""

from __future__ import annotations

import contextlib
import errno
import json
import os
import secrets
import socket
import sys
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from sgfd_zoo.arguments import ZooError
from sgfd_zoo.runs.bounded import load_json, read_bytes
from sgfd_zoo.runs.files import fsync, temporary_path

LOCK_FILE = "writer.lock"
#: How often a writer renews its lock's heartbeat.
HEARTBEAT_SECONDS = 30.0
#: A lock whose heartbeat is older than this belongs to a writer that is gone (a lost host, a frozen process).
#: Generous: clocks of a cluster's hosts may differ a little, and a shared file system may stall.
STALE_SECONDS = 600.0


def _host() -> str:
    return socket.gethostname() or "unknown host"


def _pid_namespace() -> str | None:
    """This process's pid namespace (a container has its own): pids are comparable only within one."""
    try:
        return os.readlink("/proc/self/ns/pid")
    except OSError:
        return None


def _process_exists(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # another user's process
        return True
    return True


def _when(epoch: float) -> str:
    return time.strftime("%Y-%m-%d %H:%M:%S", time.localtime(epoch))


def _age(seconds: float) -> str:
    seconds = max(seconds, 0.0)
    return (
        f"{seconds:.0f} s"
        if seconds < 120
        else f"{seconds / 60:.0f} min"
        if seconds < 7200
        else f"{seconds / 3600:.1f} h"
    )


@dataclass(frozen=True)
class LockHolder:
    """Who holds a run's lock, as its file says.

    :param token: unique to one acquisition
    :param pid: the writer's process id
    :param host: the writer's host name
    :param pid_namespace: the writer's pid namespace (None where unknown)
    :param started: when it took the lock (seconds since the epoch)
    :param heartbeat: when it last renewed it (the file's modification time)
    :param command: what it runs, for people
    """

    token: str
    pid: int
    host: str
    pid_namespace: str | None
    started: float
    heartbeat: float
    command: str = ""

    @classmethod
    def me(cls, command: str) -> LockHolder:
        now = time.time()
        return cls(secrets.token_hex(8), os.getpid(), _host(), _pid_namespace(), now, now, command)

    def to_json(self) -> dict[str, Any]:
        keys = ("token", "pid", "host", "pid_namespace", "started", "command")
        return {key: getattr(self, key) for key in keys}

    def describe(self) -> str:
        """E.g. ``pid 4242 on host node7 (sgfd-zoo train ...) since 2026-01-01 10:00:00, heartbeat 12 s ago``."""
        command = f" ({self.command})" if self.command else ""
        return (
            f"pid {self.pid} on host {self.host}{command} since {_when(self.started)}, "
            f"heartbeat {_age(time.time() - self.heartbeat)} ago"
        )

    def gone(self) -> str | None:
        """Why the holder is no longer writing (its process is gone, its heartbeat is stale), or None."""
        same_machine = self.host == _host() and self.pid_namespace == _pid_namespace()
        if same_machine and not _process_exists(self.pid):
            return f"its process (pid {self.pid} on {self.host}) is gone"
        age = time.time() - self.heartbeat
        if age > STALE_SECONDS:
            return f"its heartbeat is {_age(age)} old (more than {_age(STALE_SECONDS)})"
        return None


def read_holder(folder: Path) -> LockHolder | None:
    """Who holds the lock of run folder ``folder``; None when it is free. A lock file being written, or one that
    does not parse, counts as held by an unknown writer (token ``""``) whose heartbeat is the file's age."""
    return _read_lock_file(Path(folder) / LOCK_FILE)


def _read_lock_file(path: Path) -> LockHolder | None:
    """The holder a lock file at ``path`` names (see :func:`read_holder`); None when there is no such file."""
    try:
        heartbeat = path.stat().st_mtime
        data = read_bytes(path, "MAX_JSON_BYTES")
    except FileNotFoundError:
        return None
    try:
        fields = load_json(data, path)  # bounded: depth, finite numbers (sgfd_zoo.runs.bounded)
        return LockHolder(
            str(fields["token"]),
            int(fields["pid"]),
            str(fields["host"]),
            fields.get("pid_namespace"),
            float(fields["started"]),
            heartbeat,
            str(fields.get("command", "")),
        )
    except (ValueError, KeyError, TypeError, ZooError):  # not JSON, or refused: a lock whose writer is unknown
        return LockHolder("", -1, "an unknown host", None, heartbeat, heartbeat, "its lock file is unreadable")


def live_holder(folder: Path) -> LockHolder | None:
    """The live writer holding the lock of run folder ``folder`` now; None when it is free or its holder is gone."""
    holder = read_holder(folder)
    return holder if holder is not None and holder.gone() is None else None


class RunLocked(ZooError):
    """Another process writes the run; the message names it and what to do."""

    @staticmethod
    def being_written(folder: Path, holder: LockHolder) -> str:
        """E.g. ``logs/sac/X_1 is being written by pid 4242 on host node7 (...) since ..., heartbeat 12 s ago``."""
        return f"{folder} is being written by {holder.describe()}"


def _create(path: Path, content: str) -> bool:
    """Create ``path`` holding ``content`` if it does not exist, atomically: a whole temporary file linked to it.
    False when it exists. Where the file system has no hard links, an exclusive create (``O_EXCL``) instead.

    The temporary file is named like every file the zoo writes (:func:`~sgfd_zoo.runs.files.temporary_path`), so the
    run's writer removes one a killed process left, as it removes those of interrupted checkpoints; a temporary
    file so removed while this process was linking it means the folder has a writer: False."""
    tmp = temporary_path(path)
    try:
        tmp.write_text(content)
        try:
            fsync(tmp)
            os.link(tmp, path)
        except (FileExistsError, FileNotFoundError):  # FileNotFoundError: the writer removed the temporary file
            return False
        except OSError as error:
            if os.stat(tmp).st_nlink == 2:  # NFS: the link was made, its reply lost
                return True
            if error.errno not in (errno.EPERM, errno.ENOTSUP, errno.EOPNOTSUPP, errno.EMLINK):
                raise
            return _create_exclusive(path, content)
        return True
    finally:
        tmp.unlink(missing_ok=True)


def _create_exclusive(path: Path, content: str) -> bool:
    try:
        descriptor = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o644)
    except FileExistsError:
        return False
    with os.fdopen(descriptor, "w") as handle:
        handle.write(content)
    fsync(path)
    return True


def _take_over(path: Path, stale: LockHolder) -> bool:
    """Remove the lock ``stale`` holds, unless another process replaced it meanwhile: it is renamed away (one
    renamer wins), then checked to be that holder's; another holder's lock is put back."""
    moved = temporary_path(path)
    try:
        os.rename(path, moved)
    except FileNotFoundError:  # another process took it over first
        return False
    try:
        if _token(moved) == stale.token:
            return True
        with contextlib.suppress(FileExistsError, FileNotFoundError):  # not found: a live writer removed it
            os.link(moved, path)
        return False
    finally:
        moved.unlink(missing_ok=True)


def _token(path: Path) -> str | None:
    """The token of the lock file at ``path`` (``""`` when it does not parse), None when there is none."""
    holder = _read_lock_file(path)
    return None if holder is None else holder.token


class RunLock:
    """The lock of one run folder, held by this process: taken by :meth:`acquire`, renewed by a heartbeat thread,
    given back by :meth:`release`.

    :param folder: the run folder
    :param holder: this process, as the lock file names it
    """

    def __init__(self, folder: Path, holder: LockHolder):
        self.folder = Path(folder)
        self.path = self.folder / LOCK_FILE
        self.holder = holder
        #: Set when another process took the lock over: what to say, and that this one must not write more.
        self.lost: str | None = None
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._beat_until_released, name=f"heartbeat {folder}", daemon=True)
        self._thread.start()

    @classmethod
    def acquire(cls, folder: Path, command: str = "", what: str = "the run") -> RunLock:
        """Take the lock of run folder ``folder`` (which exists); a :class:`RunLocked` when a live writer holds it.
        A dead writer's lock is taken over, with a warning on stderr.

        :param folder: the run folder
        :param command: what this process runs, for the lock's readers
        :param what: how messages name the run, e.g. ``--resume`` of it
        """
        path = Path(folder) / LOCK_FILE
        me = LockHolder.me(command)
        for _ in range(5):
            if _create(path, json.dumps(me.to_json())):
                return cls(folder, me)
            holder = read_holder(folder)
            if holder is None:  # released meanwhile
                continue
            reason = holder.gone()
            if reason is None:
                raise RunLocked(
                    f"{what}: {RunLocked.being_written(folder, holder)}; one writer at a time: wait for it, or stop it"
                    f" (if it is gone, its lock is taken over once its heartbeat is {_age(STALE_SECONDS)} old)"
                )
            if _take_over(path, holder):
                print(f"warning: taking over the lock of {folder} from {holder.describe()}: {reason}", file=sys.stderr)
        raise RunLocked(f"{what}: {folder}: other processes keep taking its lock; try again")

    def _beat_until_released(self) -> None:
        while not self._stop.wait(HEARTBEAT_SECONDS):
            self.beat()

    def beat(self) -> None:
        """Renew the heartbeat; when another process holds the lock now, set :attr:`lost` instead. A lock file
        removed by hand is made again."""
        if self.lost is not None:
            return
        holder = read_holder(self.folder)
        if holder is None:
            if _create(self.path, json.dumps(self.holder.to_json())):
                return
            holder = read_holder(self.folder)  # another process made it meanwhile
        if holder is None or holder.token != self.holder.token:
            by = "another process" if holder is None else holder.describe()
            self.lost = f"the lock of {self.folder} was taken over by {by} while this process trained it"
            return
        with contextlib.suppress(FileNotFoundError):
            os.utime(self.path)

    def release(self) -> None:
        """Stop the heartbeat and remove the lock, if it is still this process's."""
        self._stop.set()
        if self._thread is not threading.current_thread():
            self._thread.join(timeout=5)
        if self.lost is None and _token(self.path) == self.holder.token:
            self.path.unlink(missing_ok=True)


def latest_run_id(folder: Path, name: str) -> int:
    """The highest ``<id>`` of the ``<name>_<id>`` entries of ``folder`` (0 if none), as rl-zoo3 numbers runs."""
    ids = [int(suffix) for path in Path(folder).glob(f"{name}_*") if (suffix := path.name[len(name) + 1 :]).isdigit()]
    return max(ids, default=0)


def make_folders(folder: Path) -> list[Path]:
    """Create ``folder`` and its missing parents; returns those it created, outermost first."""
    missing = [path for path in [Path(folder), *Path(folder).parents] if not path.exists()][::-1]
    for path in missing:
        with contextlib.suppress(FileExistsError):  # another process made it meanwhile
            path.mkdir()
    return missing


def remove_empty(folders: list[Path]) -> None:
    """Remove ``folders``, innermost first, as long as they are empty (another run's files keep one)."""
    for path in reversed(folders):
        try:
            path.rmdir()
        except OSError:
            return


@dataclass
class ClaimedRun:
    """A run folder this process writes: its path, its lock, and the folders it created for it (removed again
    when the run is given up before it wrote anything)."""

    path: Path
    lock: RunLock
    created: list[Path]

    def release(self, remove_if_empty: bool = False) -> None:
        """Give the lock back; with ``remove_if_empty``, also the folders created for the run if nothing is in them."""
        self.lock.release()
        if remove_if_empty:
            remove_empty(self.created)


def claim_new_run(folder: Path, name: str, command: str = "") -> ClaimedRun:
    """A new run folder ``<folder>/<name>_<id>``, ``id`` one more than the highest there, created and locked by
    this process: processes that start together each get their own.

    :param folder: the algorithm's log folder, e.g. ``logs/sgfd_sac``
    :param name: the env's name in paths, e.g. ``SGFD-MT-walker-walk-v0``
    :param command: what this process runs, for the lock's readers
    """
    created = make_folders(folder)
    run_id = latest_run_id(folder, name) + 1
    while True:
        path = Path(folder) / f"{name}_{run_id}"
        try:
            path.mkdir()
        except FileExistsError:
            run_id += 1
            continue
        try:
            return ClaimedRun(path, RunLock.acquire(path, command), [*created, path])
        except RunLocked:  # taken with --run-id between the mkdir and the lock
            run_id += 1


def claim_run(path: Path, command: str = "", what: str = "the run") -> ClaimedRun:
    """Run folder ``path`` (made if missing: ``--run-id``, a sweep's run), locked by this process; a
    :class:`RunLocked` when another writes it.

    :param path: the run folder
    :param command: what this process runs, for the lock's readers
    :param what: how messages name the run
    """
    created = make_folders(path)
    try:
        lock = RunLock.acquire(path, command, what)
    except RunLocked:
        remove_empty(created)
        raise
    return ClaimedRun(Path(path), lock, created)
