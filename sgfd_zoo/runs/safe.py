"""Files other people wrote are data: how the zoo reads them and writes next to them (docs/trust.md).

Run folders, log folders, study records and specs come from colleagues, clusters and pull requests. What the zoo
reads from them never runs code, and what it writes, copies or deletes stays inside the folder it was given:

- YAML is read by :class:`DataLoader`: PyYAML's safe loader and the two tags rl-zoo3's files hold (its
  ``OrderedDict`` as a list of pairs, tuples). Any other tag is refused (:class:`RefusedFile`), never constructed.
- An expression that rl-zoo3 would ``eval`` (``-params policy_kwargs:dict(net_arch=[256, 256])``) is parsed by
  :func:`literal_expression`: literals, and ``dict(...)`` of literals; nothing else.
- A write goes through :func:`write_file`: refused when the file, or a folder between the given root and it, is a
  symbolic link (``os.replace`` of :func:`~sgfd_zoo.runs.files.atomic_write` replaces a link at the file itself,
  but a linked folder above it would take the write elsewhere); copies and deletions alike.
- Credentials in URLs (``postgresql://user:password@host/db``) are removed before a command line or an argument
  is written (:func:`redact`).
"""

from __future__ import annotations

import ast
import os
import re
from collections import OrderedDict
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import yaml

from sgfd_zoo.arguments import ZooError
from sgfd_zoo.runs.files import StoredFile, atomic_write


class RefusedFile(ZooError):
    """A file or a value read from disk that the zoo does not act on: one that would run code, a name that leads
    out of its folder, a symbolic link where the zoo writes, copies or deletes. Never read "as if absent": the
    command stops, in one line naming the file and what was refused."""


# -- YAML ------------------------------------------------------------------------------------------------

ORDERED_DICT_TAG = "tag:yaml.org,2002:python/object/apply:collections.OrderedDict"
TUPLE_TAG = "tag:yaml.org,2002:python/tuple"


class _CodeTag(yaml.YAMLError):
    """A tag the safe loader does not construct, with where it is."""

    def __init__(self, tag: str, line: int):
        super().__init__(tag)
        self.tag, self.line = tag, line


class DataLoader(yaml.SafeLoader):
    """PyYAML's SafeLoader, plus the two tags rl-zoo3's ``config.yml`` and ``args.yml`` hold: an ``OrderedDict``
    written as the list of its (key, value) pairs, and tuples. Everything else that names a Python object
    (``!!python/object/apply:os.system``, ``!!python/name:...``) raises instead of being built."""


def _ordered_dict(loader: yaml.SafeLoader, node: yaml.Node) -> OrderedDict:
    if not isinstance(node, yaml.SequenceNode):
        raise yaml.constructor.ConstructorError(None, None, "an OrderedDict that is not a list", node.start_mark)
    arguments = loader.construct_sequence(node, deep=True)
    if len(arguments) != 1 or not all(isinstance(pair, list) and len(pair) == 2 for pair in arguments[0]):
        raise yaml.constructor.ConstructorError(None, None, "an OrderedDict that is not [[key, value], ...]", None)
    return OrderedDict((key, value) for key, value in arguments[0])


def _tuple(loader: yaml.SafeLoader, node: yaml.Node) -> tuple:
    if not isinstance(node, yaml.SequenceNode):
        raise yaml.constructor.ConstructorError(None, None, "a tuple that is not a list", node.start_mark)
    return tuple(loader.construct_sequence(node, deep=True))


def _refuse(loader: yaml.SafeLoader, node: yaml.Node) -> None:
    raise _CodeTag(node.tag, node.start_mark.line + 1)


DataLoader.add_constructor(ORDERED_DICT_TAG, _ordered_dict)
DataLoader.add_constructor(TUPLE_TAG, _tuple)
DataLoader.add_constructor(None, _refuse)  # any tag without a constructor of its own


def load_yaml(text: str, source: Path | str) -> Any:
    """The data of YAML ``text`` (read from ``source``); a :class:`RefusedFile` when it holds a tag that names a
    Python object, a ``yaml.YAMLError`` when it does not parse.

    :param text: the file's text
    :param source: where it was read, for the message
    """
    try:
        return yaml.load(text, Loader=DataLoader)
    except _CodeTag as tag:
        short = tag.tag.replace("tag:yaml.org,2002:", "!!")
        raise RefusedFile(
            f"{source}: refused: line {tag.line} holds the tag {short}, which names Python code; sgfd-zoo reads "
            "this file as data only (docs/trust.md)"
        ) from None


# -- expressions rl-zoo3 evaluates ---------------------------------------------------------------------------


def literal_expression(text: str) -> Any:
    """The value of ``text`` if it is a literal (numbers, strings, booleans, None, lists, tuples, dicts, sets) or
    rl-zoo3's ``dict(key=...)`` of such values, which ``eval`` gives alike; a ValueError naming what else it holds.

    :param text: e.g. ``dict(net_arch=[256, 256])``
    """
    try:
        tree = ast.parse(text.strip(), mode="eval")
    except SyntaxError:
        raise ValueError(f"{text!r} is not a Python literal") from None
    try:
        return _literal(tree.body, text)
    except TypeError as error:  # an unhashable key or set item
        raise ValueError(f"{text!r}: {error}") from None


def _literal(node: ast.expr, text: str) -> Any:
    if isinstance(node, ast.Call) and isinstance(node.func, ast.Name) and node.func.id == "dict" and not node.args:
        if any(keyword.arg is None for keyword in node.keywords):
            raise ValueError(f"{text!r}: dict(**...) is not a literal")
        return {keyword.arg: _literal(keyword.value, text) for keyword in node.keywords}
    if isinstance(node, ast.List | ast.Tuple | ast.Set):
        items = [_literal(item, text) for item in node.elts]
        return tuple(items) if isinstance(node, ast.Tuple) else set(items) if isinstance(node, ast.Set) else items
    if isinstance(node, ast.Dict):
        keys = [key for key in node.keys if key is not None]
        if len(keys) != len(node.keys):
            raise ValueError(f"{text!r}: {{**...}} is not a literal")
        return {_literal(key, text): _literal(value, text) for key, value in zip(keys, node.values, strict=True)}
    try:
        return ast.literal_eval(node)  # constants, and signed numbers
    except ValueError:
        raise ValueError(f"{text!r} holds {ast.unparse(node)!r}, which is not a literal") from None


# -- links ------------------------------------------------------------------------------------------------


def refuse_links(root: Path, path: Path, action: str = "write") -> None:
    """A :class:`RefusedFile` when ``path``, or a folder between ``root`` and it, is a symbolic link, or when
    ``path`` is not inside ``root``. ``root`` itself may be a link: the user gave it.

    :param root: the folder the command was given (a log folder, a study's folder)
    :param path: a file or folder in it
    :param action: what the zoo was about to do there, for the message
    """
    root, path = Path(root), Path(path)
    try:
        parts = path.relative_to(root).parts
    except ValueError:
        raise RefusedFile(f"{path}: refused to {action} it: it is not inside {root}") from None
    current = root
    for part in parts:
        if part in ("", ".", ".."):
            raise RefusedFile(f"{path}: refused to {action} it: {part!r} in its path leads out of {root}")
        current = current / part
        if current.is_symlink():
            raise RefusedFile(
                f"{current}: refused to {action} {'through ' if current != path else ''}it: a symbolic link (to "
                f"{os.readlink(current)}) inside {root}; sgfd-zoo never follows links there: replace it with what "
                "it points to"
            )


def find_link(folder: Path) -> Path | None:
    """The first symbolic link inside ``folder`` (its subfolders included, not followed), or None."""
    for where, folders, files in os.walk(folder):
        for name in sorted([*folders, *files]):
            if (Path(where) / name).is_symlink():
                return Path(where) / name
    return None


def refuse_links_inside(folder: Path, root: Path, action: str = "write") -> None:
    """:func:`refuse_links` of ``folder`` and of everything inside it (a run folder the zoo writes, or copies)."""
    refuse_links(root, folder, action)
    link = find_link(folder)
    if link is not None:
        refuse_links(root, link, action)


def write_file(root: Path, path: Path, write: Callable[[str], object]) -> StoredFile:
    """:func:`~sgfd_zoo.runs.files.atomic_write` of ``path``, after :func:`refuse_links` from ``root``."""
    refuse_links(root, path)
    return atomic_write(path, write)


def write_text(root: Path, path: Path, text: str) -> Path:
    """``path`` holding ``text``, written whole (:func:`write_file`); returns ``path``."""
    write_file(root, path, lambda tmp: Path(tmp).write_text(text))
    return Path(path)


def make_folder(root: Path, path: Path) -> Path:
    """Folder ``path`` (and its missing parents below ``root``), after :func:`refuse_links`; returns it."""
    refuse_links(root, path, "write in")
    Path(path).mkdir(parents=True, exist_ok=True)
    return Path(path)


def save_figure(figure: Any, root: Path, path: Path, **savefig: Any) -> Path:
    """A matplotlib figure saved to ``path`` (its suffix picks the format) through :func:`write_file`."""
    write_file(root, path, lambda tmp: figure.savefig(tmp, **savefig))
    return Path(path)


def copy_file(
    source_root: Path, source: Path, root: Path, path: Path, change: Callable[[str], str] | None = None
) -> StoredFile:
    """Copy ``source`` (a plain file under ``source_root``, no link on its way) to ``path`` (under ``root``),
    optionally changing its text on the way.

    :param change: applied to the file's text (UTF-8) before it is written; None: the bytes as they are
    """
    refuse_links(source_root, source, "copy")
    content = Path(source).read_bytes()
    if change is not None:
        content = change(content.decode()).encode()
    return write_file(root, path, lambda tmp: Path(tmp).write_bytes(content))


def plain_name(name: Any, source: Path) -> str:
    """``name`` if it names a file directly inside the folder of ``source`` (an index naming its files), else a
    :class:`RefusedFile`: a path (``../x``, ``/etc/x``, ``sub/x``) would take a read or a delete elsewhere."""
    if not isinstance(name, str) or name in ("", ".", "..") or "/" in name or "\\" in name or "\0" in name:
        raise RefusedFile(f"{source}: refused: it names {name!r}, which is not a file of its folder")
    return name


# -- credentials -----------------------------------------------------------------------------------------

#: ``scheme://user:password@`` (or a token as the user) in a URL.
_USER_INFO = re.compile(r"(?P<scheme>\b[A-Za-z][A-Za-z0-9+.-]*://)[^\s/@'\"]+@")
#: A secret passed as a URL's query parameter.
_SECRET_PARAMETER = re.compile(
    r"(?P<key>[?&](?:password|passwd|pwd|token|access_token|secret|api_key|apikey|auth)=)[^&\s'\"]+", re.IGNORECASE
)
REDACTED = "***"


def redact(text: str) -> str:
    """``text`` with the credentials of every URL in it replaced by ``***``: ``postgresql://***@host/db``."""
    text = _USER_INFO.sub(lambda match: f"{match['scheme']}{REDACTED}@", text)
    return _SECRET_PARAMETER.sub(lambda match: f"{match['key']}{REDACTED}", text)


def redact_argv(argv: Sequence[str]) -> list[str]:
    """Each argument of ``argv`` with :func:`redact` applied."""
    return [redact(arg) for arg in argv]


def redact_values(value: Any) -> Any:
    """``value`` (arguments, as rl-zoo3 saves them) with :func:`redact` applied to every string in it."""
    if isinstance(value, str):
        return redact(value)
    if isinstance(value, dict):
        return type(value)((key, redact_values(item)) for key, item in value.items())
    if isinstance(value, list | tuple):
        return type(value)(redact_values(item) for item in value)
    return value


# -- rl-zoo3's hyperparameters ------------------------------------------------------------------------------

#: Hyperparameters whose string value rl-zoo3 passes to ``eval``.
EVALUATED_HYPERPARAMETERS = ("policy_kwargs", "replay_buffer_kwargs", "monitor_kwargs", "normalize")
#: Hyperparameters that name a class or a module for rl-zoo3 to import.
CODE_HYPERPARAMETERS = ("env_wrapper", "vec_env_wrapper", "callback", "replay_buffer_class")


#: Packages whose classes a configuration may name (``policy: sb3_sgfd.policies.CnnPolicy``,
#: ``replay_buffer_class: sb3_sgfd.buffers.DomainReplayBuffer``, as the zoo's own runs write them): importing them
#: runs only the installed agents' and envs' code.
TRUSTED_PACKAGES = ("sb3_sgfd.", "sgfd_envs.", "stable_baselines3.", "sb3_contrib.", "rl_zoo3.", "gymnasium.")


def _foreign_names(value: Any) -> list[str]:
    """The dotted names in ``value`` (a name, or rl-zoo3's list or dict of names with their arguments) outside
    :data:`TRUSTED_PACKAGES`."""
    if isinstance(value, str):
        return [value] if "." in value and not value.startswith(TRUSTED_PACKAGES) else []
    if isinstance(value, dict):
        return [name for key in value for name in _foreign_names(str(key))]
    if isinstance(value, (list, tuple)):
        return [name for item in value for name in _foreign_names(item)]
    return []


def hyperparameter_problem(key: str, value: Any) -> str | None:
    """Why rl-zoo3 would run code for hyperparameter ``key`` = ``value`` (read from a file or a spec), or None: a
    string it evaluates that is not a literal (:func:`literal_expression`), or a name of code to import from
    outside the installed agents and envs."""
    if key in CODE_HYPERPARAMETERS or key == "policy":
        foreign = _foreign_names(value)
        if foreign:
            return f"{key} names code to import ({foreign[0]!r})"
    if key in EVALUATED_HYPERPARAMETERS and isinstance(value, str):
        try:
            literal_expression(value)
        except ValueError as error:
            return f"{key}: {error} (rl-zoo3 evaluates it)"
    return None
