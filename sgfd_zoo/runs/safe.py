"""Files other people wrote are data: how the zoo reads them and writes next to them (docs/trust.md).

Run folders, log folders, study records and specs come from colleagues, clusters and pull requests. What the zoo
reads from them never runs code, and what it writes, copies or deletes stays inside the folder it was given:

- YAML is read by :class:`DataLoader`: PyYAML's safe loader and the two tags rl-zoo3's files hold (its
  ``OrderedDict`` as a list of pairs, tuples). Any other tag is refused (:class:`RefusedFile`), never constructed.
- An expression that rl-zoo3 would ``eval`` (``-params policy_kwargs:dict(net_arch=[256, 256])``) is parsed by
  :func:`literal_expression`: literals, and ``dict(...)`` of literals; nothing else.
- A write goes through :func:`write_file`: refused when the file, or a folder between the given root and it, is a
  symbolic link; the folders are then held by descriptors that follow no link
  (:func:`~sgfd_zoo.runs.files.write_below`), so a folder swapped for a link while the zoo writes cannot take the
  write elsewhere; copies and deletions alike.
- Every read is bounded (:mod:`sgfd_zoo.runs.bounded`): YAML by its size, depth and aliases before it is built.
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

from sgfd_zoo.runs.bounded import LIMITS, RefusedFile, check_yaml, opened, read_bytes
from sgfd_zoo.runs.files import StoredFile, held_folder, write_below

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
    Python object or is over a limit (:func:`~sgfd_zoo.runs.bounded.check_yaml`: size, depth, aliases), a
    ``yaml.YAMLError`` when it does not parse.

    :param text: the file's text
    :param source: where it was read, for the message
    """
    check_yaml(text, source)
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
    """:func:`~sgfd_zoo.runs.files.write_below` of ``path``, after :func:`refuse_links` from ``root``."""
    refuse_links(root, path)
    return write_below(root, path, write)


def write_text(root: Path, path: Path, text: str) -> Path:
    """``path`` holding ``text``, written whole (:func:`write_file`); returns ``path``."""
    write_file(root, path, lambda tmp: Path(tmp).write_text(text))
    return Path(path)


def make_folder(root: Path, path: Path) -> Path:
    """Folder ``path`` (and its missing parents below ``root``), each made through its parent's descriptor, none a
    link (:func:`~sgfd_zoo.runs.files.held_folder`); returns it."""
    refuse_links(root, path, "write in")
    with held_folder(root, path, create=True):
        return Path(path)


def save_figure(figure: Any, root: Path, path: Path, **savefig: Any) -> Path:
    """A matplotlib figure saved to ``path`` (its suffix picks the format) through :func:`write_file`."""
    savefig.setdefault("format", Path(path).suffix.lstrip("."))
    write_file(root, path, lambda tmp: figure.savefig(tmp, **savefig))
    return Path(path)


def copy_file(
    source_root: Path,
    source: Path,
    root: Path,
    path: Path,
    change: Callable[[str], str] | None = None,
    limit: str = "MAX_TEXT_BYTES",
) -> StoredFile:
    """Copy ``source`` (a plain file under ``source_root``, no link on its way, read through its folder's
    descriptor) to ``path`` (under ``root``), optionally changing its text on the way.

    :param change: applied to the file's text (UTF-8) before it is written; None: the bytes as they are
    :param limit: the most bytes it may hold: a name in :data:`~sgfd_zoo.runs.bounded.LIMITS`
    """
    refuse_links(source_root, source, "copy")
    assert limit in LIMITS, limit
    with held_folder(source_root, Path(source).parent) as folder, opened(Path(source).name, folder, False) as handle:
        content = read_bytes(source, limit, handle)
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
#: What rl-zoo3 and SB3 import by name: ``module.Class``, ``package.module.function``.
DOTTED_NAME = re.compile(r"[A-Za-z_][A-Za-z0-9_]*(?:\.[A-Za-z_][A-Za-z0-9_]*)+")


def strings_in(value: Any) -> list[str]:
    """Every string of ``value`` at any depth, the keys of its dicts included (a value read from a file: its size
    is bounded already, :data:`~sgfd_zoo.runs.bounded.MAX_YAML_NODES`)."""
    found, stack, visited = [], [value], 0
    while stack:
        item = stack.pop()
        visited += 1
        if visited > LIMITS["MAX_YAML_NODES"]:
            raise ValueError(f"it holds more than MAX_YAML_NODES = {LIMITS['MAX_YAML_NODES']} values")
        if isinstance(item, str):
            found.append(item)
        elif isinstance(item, dict):
            stack += [*item.keys(), *item.values()]
        elif isinstance(item, list | tuple | set | frozenset):
            stack += list(item)
    return found


def is_path(text: str) -> bool:
    """Whether ``text`` reads as a file's path (or a URL): a folder separator, or a start at ``~`` or ``.``."""
    return "/" in text or "\\" in text or text.startswith(("~", "."))


def _code_problem(key: str, value: Any) -> str | None:
    """Why ``value`` of code hyperparameter ``key`` (``policy``, ``callback``, ...) would import or aim code where
    it should not: a dotted name at any depth (an argument of a trusted callable included) from outside
    :data:`TRUSTED_PACKAGES`, or a path given to the code it names."""
    try:
        texts = strings_in(value)
    except ValueError as error:
        return f"{key}: {error}"
    for text in texts:
        if DOTTED_NAME.fullmatch(text) and not text.startswith(TRUSTED_PACKAGES):
            return f"{key} names code to import ({text!r})"
        if key != "policy" and is_path(text):
            return f"{key} gives the code it names a path ({text!r})"
    return None


def hyperparameter_problem(key: str, value: Any) -> str | None:
    """Why rl-zoo3 would run code for hyperparameter ``key`` = ``value`` (read from a run's file), or None: a
    string it evaluates that is not a literal (:func:`literal_expression`), or, at any depth, a name of code to
    import from outside the installed agents and envs, or a path handed to the code a hyperparameter names."""
    if key in EVALUATED_HYPERPARAMETERS and isinstance(value, str):
        try:
            value = literal_expression(value)
        except ValueError as error:
            return f"{key}: {error} (rl-zoo3 evaluates it)"
    if key in (*CODE_HYPERPARAMETERS, *EVALUATED_HYPERPARAMETERS, "policy"):
        return _code_problem(key, value)
    return None


def spec_setting_problem(flag: str, key: str, value: Any) -> str | None:
    """Why ``flag KEY:VALUE`` (``-params``, ``--env-kwargs``, ...) may not come from a spec, or None. A spec names
    no code at any depth: no hyperparameter that imports code (:data:`CODE_HYPERPARAMETERS`), no dotted name
    anywhere in a value, a ``policy`` by its registered short name only (``MlpPolicy``), and no path.

    :param flag: the flag, for the message
    :param key: the setting
    :param value: its value, parsed as a literal
    """
    if key in CODE_HYPERPARAMETERS and flag in ("-params", "--hyperparams"):
        return f"{flag} {key} names code to import ({value!r}): a spec names no callable, class or module"
    if key == "policy" and flag in ("-params", "--hyperparams"):
        if isinstance(value, str) and value.isidentifier():
            return None
        return f"{flag} policy {value!r} (a policy by its registered short name only, e.g. MlpPolicy)"
    try:
        texts = strings_in(value)
    except ValueError as error:
        return f"{flag} {key} ({error})"
    for text in texts:
        if DOTTED_NAME.fullmatch(text):
            return f"{flag} {key} names code ({text!r}): a spec names no callable, class or module"
        if is_path(text):
            return f"{flag} {key} gives a path ({text!r}): give paths on the command line of whoever runs the study"
    return None
