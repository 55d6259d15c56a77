"""Bounded reading: a file another person wrote is read within named limits (docs/trust.md, "Limits").

A small file must not cost gigabytes or minutes. Each limit is checked before the cost it bounds is paid: a file's
size before it is read, a YAML document's depth and its size with every alias expanded before it is built (a
"billion laughs" document is refused at its first oversized alias), a JSON document's depth before it is parsed,
an array's declared size before it is allocated, a zip member's declared inflated size before it is inflated. A
file over a limit is refused in one line naming the file, the limit and the value (:class:`RefusedFile`); one
that is not what it should be is an :class:`UnreadableFile`. Every other module reads others' files through
these functions; nothing here imports more than numpy and PyYAML.
"""

from __future__ import annotations

import contextlib
import csv
import errno
import io
import json
import math
import os
import re
import stat
import zipfile
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from sgfd_zoo.arguments import ZooError


class RefusedFile(ZooError):
    """A file or a value read from disk that the zoo does not act on: one that would run code, a name that leads
    out of its folder, a symbolic link where the zoo writes, copies or deletes, a file over a limit. Never read
    "as if absent": the command stops, in one line naming the file and what was refused."""


class UnreadableFile(ZooError):
    """A run's file that exists but cannot be read back (truncated, zeroed, not what the zoo writes)."""


KIB, MIB, GIB = 1 << 10, 1 << 20, 1 << 30

#: A YAML file (a spec, a run's or a record's ``config.yml`` and ``args.yml``): the zoo's own are a few kB.
MAX_YAML_BYTES = 64 * KIB
#: Collections nested in a YAML document (the zoo's files nest 4 deep).
MAX_YAML_DEPTH = 64
#: Nodes of a YAML document with every alias expanded (its size as Python objects, once built and walked).
MAX_YAML_NODES = 10_000
#: A JSON file (``checkpoint.json``, ``finished.json``, ``final_evaluation.json``, a lock).
MAX_JSON_BYTES = 4 * MIB
#: Arrays and objects nested in a JSON document.
MAX_JSON_DEPTH = 64
#: A text file read whole (``command.txt``, ``source.txt``, ``versions.txt``).
MAX_TEXT_BYTES = 1 * MIB
#: A CSV file (``progress.csv``, ``diagnostics.csv``, ``final_evaluation.csv``, ``results.csv``).
MAX_CSV_BYTES = 16 * MIB
#: One field of a CSV file (Python's csv module's own default).
MAX_CSV_FIELD_BYTES = 128 * KIB
#: An npz file (``evaluations_<split>.npz``, a checkpoint's training state): its size on disk.
MAX_NPZ_FILE_BYTES = 64 * MIB
#: One array of an npz file, as its zip member declares it inflated (and its header may declare no more).
MAX_ARRAY_BYTES = 64 * MIB
#: All the arrays of an npz file, inflated.
MAX_NPZ_BYTES = 256 * MIB
#: A member of a model zip that the zoo reads itself (SB3's ``data``: the step counts of a final model).
MAX_ZIP_MEMBER_BYTES = 16 * MIB
#: All the members of a zip whose integrity the zoo checks by inflating them (a checkpoint found without an index).
MAX_ZIP_INFLATED_BYTES = 4 * GIB

#: Every limit by its name, as docs/trust.md lists them (``tests/zoo/test_trust_bounds.py`` checks the page).
LIMITS = {name: value for name, value in globals().items() if name.startswith("MAX_") and isinstance(value, int)}

csv.field_size_limit(MAX_CSV_FIELD_BYTES)


def over_limit(source: Path | str, what: str, value: int, limit: str) -> RefusedFile:
    """The one-line refusal of ``source``, whose ``what`` is ``value``, over the limit named ``limit``.

    :param source: the file
    :param what: what was measured, e.g. ``size in bytes``
    :param value: its value (a lower bound where the reading stopped at the limit)
    :param limit: the limit's name in :data:`LIMITS`
    """
    return RefusedFile(
        f"{source}: refused: its {what} is {value}, over the limit {limit} = {LIMITS[limit]} (docs/trust.md)"
    )


# -- files ----------------------------------------------------------------------------------------------


@contextlib.contextmanager
def opened(path: Path | str, dir_fd: int | None = None, follow: bool = True) -> Iterator[io.FileIO]:
    """``path`` opened for reading, when it is a regular file: a FIFO or a device (which could block or never end)
    is refused in one line, before anything is read.

    :param path: the file (a name in ``dir_fd`` when given)
    :param dir_fd: a folder's descriptor the name is relative to
    :param follow: False: a symbolic link at ``path`` is refused (``O_NOFOLLOW``)
    """
    flags = os.O_RDONLY | os.O_NONBLOCK | os.O_CLOEXEC | (0 if follow else os.O_NOFOLLOW)
    try:
        descriptor = os.open(path, flags, dir_fd=dir_fd)
    except OSError as error:
        if not follow and error.errno == errno.ELOOP:
            raise RefusedFile(f"{path}: refused to read it: a symbolic link") from None
        raise
    handle = io.FileIO(descriptor, "r", closefd=True)
    try:
        if not stat.S_ISREG(os.fstat(descriptor).st_mode):
            raise RefusedFile(f"{path}: refused: not a regular file (a FIFO, a device or a folder)")
        os.set_blocking(descriptor, True)
        yield handle
    finally:
        handle.close()


def read_bytes(path: Path, limit: str, handle: io.FileIO | None = None) -> bytes:
    """The bytes of ``path``, refused when there are more than the limit named ``limit`` (checked before reading,
    and again as read, should the file grow).

    :param path: the file
    :param limit: a name in :data:`LIMITS`
    :param handle: ``path`` already opened (:func:`opened`)
    """
    if handle is None:
        with opened(Path(path)) as own:
            return read_bytes(path, limit, own)
    size = os.fstat(handle.fileno()).st_size
    if size > LIMITS[limit]:
        raise over_limit(path, "size in bytes", size, limit)
    chunks, read = [], 0
    while chunk := handle.read(LIMITS[limit] + 1 - read):  # a read may return less than asked: until the end
        chunks.append(chunk)
        read += len(chunk)
        if read > LIMITS[limit]:
            raise over_limit(path, "size in bytes (at least)", read, limit)
    return b"".join(chunks)


def read_text(path: Path, limit: str = "MAX_TEXT_BYTES") -> str:
    """The UTF-8 text of ``path`` within the limit named ``limit`` (:func:`read_bytes`); an :class:`UnreadableFile`
    when it is not UTF-8."""
    data = read_bytes(path, limit)
    try:
        return data.decode()
    except UnicodeDecodeError as error:
        raise UnreadableFile(f"{path} is unreadable (not UTF-8 text: {error.reason} at byte {error.start})") from None


# -- YAML -----------------------------------------------------------------------------------------------

_COLLECTION_START = (yaml.MappingStartEvent, yaml.SequenceStartEvent)
_COLLECTION_END = (yaml.MappingEndEvent, yaml.SequenceEndEvent)


def check_yaml(text: str, source: Path | str) -> None:
    """Refuse YAML ``text`` (read from ``source``) over :data:`MAX_YAML_BYTES`, nested deeper than
    :data:`MAX_YAML_DEPTH`, or of more than :data:`MAX_YAML_NODES` nodes once its aliases are expanded.

    Read from PyYAML's event stream (its parser keeps a stack of its own, so a deep document costs no recursion),
    counting each alias as the nodes of its anchor, so that the expanded size is known without expanding
    anything: a billion-laughs document is refused at the first alias that takes it over the limit. An alias
    inside its own anchor (a document that contains itself, endless to walk) is refused too.
    """
    size = len(text.encode(errors="replace"))
    if size > MAX_YAML_BYTES:
        raise over_limit(source, "size in bytes", size, "MAX_YAML_BYTES")
    expanded: dict[str, int] = {}  # anchor -> its nodes, expanded
    open_collections: list[list[Any]] = [[None, 0]]  # [anchor, nodes so far], the document's root first
    for event in yaml.parse(text, Loader=yaml.SafeLoader):
        if isinstance(event, _COLLECTION_START):
            open_collections.append([event.anchor, 1])
            if len(open_collections) - 1 > MAX_YAML_DEPTH:
                line = event.start_mark.line + 1 if event.start_mark else "?"
                raise over_limit(source, f"nesting (at line {line})", len(open_collections) - 1, "MAX_YAML_DEPTH")
            continue
        if isinstance(event, _COLLECTION_END):
            anchor, nodes = open_collections.pop()
        elif isinstance(event, yaml.ScalarEvent):
            anchor, nodes = event.anchor, 1
        elif isinstance(event, yaml.AliasEvent):
            if any(event.anchor == anchor for anchor, _ in open_collections):
                line = event.start_mark.line + 1 if event.start_mark else "?"
                raise RefusedFile(f"{source}: refused: line {line} holds an alias inside its own anchor (a loop)")
            anchor, nodes = None, expanded.get(event.anchor, 1)
        else:  # the stream's and the documents' starts and ends
            continue
        if anchor is not None:
            expanded[anchor] = nodes
        open_collections[-1][1] += nodes
        if open_collections[-1][1] > MAX_YAML_NODES:
            what = "number of nodes with its aliases expanded (at least)"
            raise over_limit(source, what, open_collections[-1][1], "MAX_YAML_NODES")


# -- JSON -----------------------------------------------------------------------------------------------

_JSON_STRING = re.compile(rb'"(?:[^"\\]|\\.)*"', re.DOTALL)
_NOT_A_BRACKET = re.compile(rb"[^\[\]{}]+")


def json_depth(data: bytes) -> int:
    """How deep the arrays and objects of JSON ``data`` nest (brackets inside strings not counted), without
    parsing it."""
    brackets = np.frombuffer(_NOT_A_BRACKET.sub(b"", _JSON_STRING.sub(b'""', data)), dtype=np.uint8)
    if not brackets.size:
        return 0
    steps = np.where((brackets == ord("[")) | (brackets == ord("{")), 1, -1)
    return int(np.cumsum(steps).max())


def load_json(data: bytes, source: Path | str) -> Any:
    """The value of JSON ``data`` (read from ``source``): refused when it nests deeper than
    :data:`MAX_JSON_DEPTH` or holds a number that is not finite (``NaN``, ``Infinity``, ``1e999``); an
    :class:`UnreadableFile` when it does not parse."""
    depth = json_depth(data)
    if depth > MAX_JSON_DEPTH:
        raise over_limit(source, "nesting", depth, "MAX_JSON_DEPTH")

    def finite(text: str) -> float:
        value = float(text)
        if not math.isfinite(value):
            raise RefusedFile(f"{source}: refused: it holds the number {text}, which is not finite")
        return value

    def constant(text: str) -> float:
        raise RefusedFile(f"{source}: refused: it holds {text}, which is not a finite number")

    try:
        return json.loads(data, parse_float=finite, parse_constant=constant)
    except (ValueError, RecursionError) as error:
        raise UnreadableFile(f"{source} is unreadable ({type(error).__name__}: {error})") from None


# -- CSV ------------------------------------------------------------------------------------------------


def csv_rows(path: Path) -> Iterator[dict[str, str]]:
    """The rows of CSV file ``path`` as dicts (``csv.DictReader``), read as they come: refused when the file is over
    :data:`MAX_CSV_BYTES` (before any row) or a field over :data:`MAX_CSV_FIELD_BYTES`; an :class:`UnreadableFile`
    when it is not CSV."""
    with opened(Path(path)) as raw:
        size = os.fstat(raw.fileno()).st_size
        if size > MAX_CSV_BYTES:
            raise over_limit(path, "size in bytes", size, "MAX_CSV_BYTES")
        text = io.TextIOWrapper(io.BufferedReader(raw), encoding="utf-8", newline="")
        try:
            yield from csv.DictReader(text)
        except csv.Error as error:
            if "field limit" in str(error):
                longest = MAX_CSV_FIELD_BYTES + 1
                raise over_limit(path, "longest field in bytes (at least)", longest, "MAX_CSV_FIELD_BYTES") from None
            raise UnreadableFile(f"{path} is unreadable (not CSV: {error})") from None
        except UnicodeDecodeError as error:
            raise UnreadableFile(f"{path} is unreadable (not UTF-8 text: {error.reason})") from None


def read_csv(path: Path) -> list[dict[str, str]]:
    """Every row of ``path`` (:func:`csv_rows`)."""
    return list(csv_rows(path))


# -- zip and npz ----------------------------------------------------------------------------------------


def zip_member(path: Path, name: str, limit: str = "MAX_ZIP_MEMBER_BYTES") -> bytes:
    """Member ``name`` of zip file ``path``, inflated only when it declares no more bytes than the limit named
    ``limit`` (zipfile never inflates more than a member declares); a KeyError when it has none, a
    ``zipfile.BadZipFile`` when it is no zip."""
    with zipfile.ZipFile(path) as archive:
        info = archive.getinfo(name)
        if info.file_size > LIMITS[limit]:
            raise over_limit(f"{path} (member {name})", "inflated size in bytes", info.file_size, limit)
        return archive.read(info)


def zip_inflated_size(archive: zipfile.ZipFile) -> int:
    """The bytes the members of ``archive`` declare inflated, all together."""
    return sum(info.file_size for info in archive.infolist())


def load_npz(path: Path) -> dict[str, np.ndarray]:
    """The arrays of npz file ``path`` by name, as ``np.load(path, allow_pickle=False)`` gives them, read within
    :data:`MAX_NPZ_FILE_BYTES`, :data:`MAX_ARRAY_BYTES` and :data:`MAX_NPZ_BYTES`: each array's header is read
    first, and an array whose declared size is more than its member holds, or over a limit, is refused before
    anything is allocated. An :class:`UnreadableFile` when it is not an npz file of numbers (an array of Python
    objects would be a pickle: never loaded)."""
    path = Path(path)
    size = path.stat().st_size
    if size > MAX_NPZ_FILE_BYTES:
        raise over_limit(path, "size in bytes", size, "MAX_NPZ_FILE_BYTES")
    try:
        with zipfile.ZipFile(path) as archive:
            infos = archive.infolist()
            inflated = zip_inflated_size(archive)
            if inflated > MAX_NPZ_BYTES:
                raise over_limit(path, "inflated size in bytes", inflated, "MAX_NPZ_BYTES")
            return {_array_name(info, path): _read_array(archive, info, path) for info in infos}
    except (OSError, ValueError, EOFError, zipfile.BadZipFile, RuntimeError) as error:
        raise UnreadableFile(f"{path} is unreadable ({type(error).__name__}: {error})") from None


def _array_name(info: zipfile.ZipInfo, path: Path) -> str:
    if not info.filename.endswith(".npy"):
        raise UnreadableFile(f"{path} is unreadable (member {info.filename!r} is not an array)")
    return info.filename.removesuffix(".npy")


def _read_array(archive: zipfile.ZipFile, info: zipfile.ZipInfo, path: Path) -> np.ndarray:
    """One member's array, after its header: refused when it declares more bytes than the member holds."""
    where = f"{path} (member {info.filename})"
    if info.file_size > MAX_ARRAY_BYTES:
        raise over_limit(where, "inflated size in bytes", info.file_size, "MAX_ARRAY_BYTES")
    with archive.open(info) as member:
        version = np.lib.format.read_magic(member)
        if version == (1, 0):
            shape, _fortran, dtype = np.lib.format.read_array_header_1_0(member)
        elif version == (2, 0):
            shape, _fortran, dtype = np.lib.format.read_array_header_2_0(member)
        else:
            raise UnreadableFile(f"{where} is unreadable (npy format {version[0]}.{version[1]})")
    if dtype.hasobject:
        raise UnreadableFile(
            f"{where} is unreadable (an array of Python objects: a pickle, never loaded, as with allow_pickle=False)"
        )
    declared = math.prod(shape) * dtype.itemsize
    if declared > info.file_size:
        raise UnreadableFile(
            f"{where} is unreadable (its header declares {declared} bytes, its member holds {info.file_size})"
        )
    with archive.open(info) as member:
        return np.lib.format.read_array(member, allow_pickle=False)
