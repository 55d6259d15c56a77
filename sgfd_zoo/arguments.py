"""The zoo's error type and its argument checks, in one place, with no heavy import (plotting and ``-h`` need
them too: the env registry is imported only to check an env id)."""

from __future__ import annotations

import argparse
import ast
import builtins
import difflib
import importlib
import os
import re
import shlex
from collections.abc import Iterable, Iterator, Mapping, Sequence
from pathlib import Path
from types import ModuleType
from typing import Any, NoReturn

#: What a terminal acts on rather than shows: C0 and C1 controls (escape sequences, line breaks), DEL, and the
#: invisible marks that reorder or hide text (bidirectional overrides and isolates, zero-width characters).
CONTROL_CHARACTERS = re.compile("[\x00-\x1f\x7f-\x9f\u200b-\u200f\u2028-\u202e\u2060-\u2069\ufeff]")


def printable(text: str, lines: bool = False) -> str:
    """``text`` with every control character shown as its escape (``\\x1b``, ``\\n``, ``\\u202e``): a value read
    from someone else's file cannot move the cursor, retitle the terminal or break a line where it is printed.

    :param text: what is to be printed
    :param lines: keep its line breaks (``\\n``): a table of many lines
    """

    def escape(match: re.Match) -> str:
        return match.group() if lines and match.group() == "\n" else match.group().encode("unicode_escape").decode()

    return CONTROL_CHARACTERS.sub(escape, text)


class ZooError(Exception):
    """Something the user must change (an argument, a file, free space); the CLI prints it as one line, after
    ``sgfd-zoo COMMAND: <label>:``, and exits with ``exit_code``. Its text is :func:`printable`: the file names and
    values it quotes come from others' folders."""

    label = "error"
    exit_code = 2

    def __str__(self) -> str:
        return printable(super().__str__())


class TrainingStopped(ZooError):
    """Training stopped before its end (Ctrl-C, a checkpoint that could not be written); the run is not finished
    and the message says how to continue it.

    :param message: what happened, what is kept, what to type
    :param exit_code: ``exit_codes.INTERRUPTED`` for an interrupt (the shell's 128 + SIGINT), 1 otherwise
    """

    label = "stopped"

    def __init__(self, message: str, exit_code: int = 1):
        super().__init__(message)
        self.exit_code = exit_code


#: A Sphinx cross-reference in a docstring: ``:mod:`sgfd_zoo.runs```, ``:func:`~sgfd_envs.splits```
SPHINX_ROLE = re.compile(r":(?:py:)?[a-z]+:`(~?)([^`<]*?)(?:\s*<[^>]*>)?`")


def plain_text(text: str) -> str:
    """``text`` (a docstring, a help line) without Sphinx's markup, as a terminal shows it: a cross-reference
    becomes its target's name (``~`` its last part), a double-backquoted literal its text."""

    def name(match: re.Match[str]) -> str:
        target = match.group(2).strip()
        return target.rsplit(".", 1)[-1] if match.group(1) else target

    return SPHINX_ROLE.sub(name, text).replace("``", "")


class ZooArgumentParser(argparse.ArgumentParser):
    """The parser of every ``sgfd-zoo`` command: no abbreviated option (``--qui`` is not taken for ``--quick``,
    nor passed on for another parser to read differently), help without Sphinx markup, and an error as a
    :class:`ZooError`, which the command prints as one line (argparse would print its usage block first)."""

    def __init__(self, *args: Any, **kwargs: Any):
        kwargs["allow_abbrev"] = False
        for text in ("description", "epilog"):  # plain before argparse wraps it; format_help catches the rest
            if kwargs.get(text):
                kwargs[text] = plain_text(kwargs[text])
        super().__init__(*args, **kwargs)

    def format_help(self) -> str:
        return plain_text(super().format_help())

    def format_usage(self) -> str:
        return plain_text(super().format_usage())

    def error(self, message: str) -> NoReturn:
        whole = "; an option is taken by its whole name only" if message.startswith("unrecognized arguments") else ""
        raise ZooError(f"{message}{whole} (see {self.prog} -h)")


#: What ``sgfd-zoo COMMAND -h`` says above the options and below them (description, epilog), for the commands whose
#: parser :func:`command_parser` makes
COMMAND_HELP: dict[str, tuple[str, str]] = {
    "enjoy": (
        "Watch a trained agent (or roll it out without a window: --no-render) on any split and domain; "
        "each episode's return and length are printed. A video: sgfd-zoo record-video.",
        "Every option has its whole name: an abbreviation is refused.",
    ),
    "record-video": (
        "Write an mp4 of a trained agent on any split and domain (imageio's ffmpeg; no system ffmpeg).",
        "e.g. sgfd-zoo record-video --algo sgfd_sac --env SGFD/MT-walker-walk-v0 -f logs --split extrapolation",
    ),
    "load-from-hub": (
        "Copy a run from the Hugging Face Hub (or a local copy of its repository) into a new run folder "
        "of a log folder, where enjoy, record-video and evaluate find it.",
        "The model zip holds pickles (SB3's format): load runs only from people whose code you would run.",
    ),
    "push-to-hub": (
        "Push a finished run to the Hugging Face Hub: its model, hyperparameters, the evaluation of every "
        "split with its domains (model card and metadata) and a video. Log in first (hf auth login) or set HF_TOKEN.",
        "e.g. sgfd-zoo push-to-hub --algo sgfd_sac --env SGFD/MT-walker-walk-v0 -f logs -orga my-lab",
    ),
}


def command_parser(command: str) -> ZooArgumentParser:
    """The parser of ``sgfd-zoo COMMAND``, with no option yet: its help's description and epilog are
    :data:`COMMAND_HELP`'s."""
    description, epilog = COMMAND_HELP[command]
    return ZooArgumentParser(prog=f"sgfd-zoo {command}", description=description, epilog=epilog)


def import_gym_packages(modules: Sequence[str]) -> None:
    """Import the modules a user names with ``--gym-packages`` (their own env packages, which register ids on
    import), as rl-zoo3's scripts do; a module that is not there is named in one line.

    :param modules: module names from the command line
    """
    for module in modules:
        try:
            importlib.import_module(module)
        except ModuleNotFoundError as error:
            raise ZooError(f"--gym-packages {module}: no such module ({error})") from None


def check_env_id(env_id: str | None, flag: str = "--env") -> str:
    """``env_id`` if it is a registered id (``sgfd_envs.ENV_IDS``), else a ZooError naming the flag, the closest
    id and the known ones.

    :param env_id: the value given
    :param flag: the option it came from
    """
    import sgfd_envs

    if env_id not in sgfd_envs.ENV_IDS:
        known = ", ".join(sgfd_envs.ENV_IDS)
        if env_id is None:
            raise ZooError(f"{flag} is required; one of {known}")
        close = difflib.get_close_matches(env_id, sgfd_envs.ENV_IDS, n=1)
        hint = f" (did you mean {close[0]}?)" if close else ""
        raise ZooError(f"{flag} {env_id!r} is not a registered id{hint}; choose from {known}")
    return env_id


def check_log_folder(flag: str, folder: Path) -> None:
    """A ZooError unless run folders can be made in ``folder``: a folder (or one to create) that this process may
    write, on a file system mounted for writing.

    :param flag: the option it came from, e.g. ``-f``
    :param folder: the log folder
    """
    folder = Path(folder)
    if folder.exists() and not folder.is_dir():
        raise ZooError(f"{flag} {folder}: is a file, not a folder; give a log folder (made if missing)")
    existing = next(path for path in [folder, *folder.absolute().parents] if path.exists())
    if not existing.is_dir():
        raise ZooError(f"{flag} {folder}: {existing} is a file, so the folder cannot be made")
    if not os.access(existing, os.W_OK | os.X_OK):
        where = "it is" if folder == existing else f"{existing} is"
        raise ZooError(f"{flag} {folder}: cannot be written ({where} read-only for this user or its file system)")


def checked_names(flag: str, values: Sequence[str], known: Sequence[str]) -> list[str]:
    """``values`` without repeats if each is one of ``known``, else a ZooError naming the flag and a close match.

    :param flag: the option they came from
    :param values: the values given
    :param known: the allowed values
    """
    for value in values:
        if value not in known:
            close = difflib.get_close_matches(value, list(known), n=1)
            hint = f" (did you mean {close[0]}?)" if close else ""
            raise ZooError(f"{flag}: {value!r} is unknown{hint}; choose from {', '.join(known)}")
    return list(dict.fromkeys(values))


def check_at_least(flag: str, value: float | None, low: float, strict: bool = False) -> None:
    """A ZooError unless ``value`` is None or at least ``low`` (above it with ``strict``).

    :param flag: the option, for the message
    :param value: the value given
    :param low: the bound
    :param strict: require value > low
    """
    if value is None:
        return
    if value < low or (strict and value == low):
        raise ZooError(f"{flag} must be {'>' if strict else '>='} {low:g}, got {value:g}")


def check_keywords(
    where: str,
    given: Iterable[str],
    valid: Iterable[str],
    message: str = "unknown key(s) in {where}: {keys}; it takes {valid}",
) -> None:
    """A ZooError naming the keys of ``given`` that are not in ``valid``, a close match, and the valid ones.

    :param where: what the keys are given to, e.g. ``policy_kwargs of sgfd_sac (MlpPolicy)``
    :param given: the keys given
    :param valid: the keys it takes
    :param message: the error's line, formatted with ``where``, ``keys`` (each unknown key with its close match)
        and ``valid`` (the valid keys in name order)
    """
    valid = sorted(valid)
    unknown = [key for key in given if key not in valid]
    if not unknown:
        return
    hints = []
    for key in unknown:
        close = difflib.get_close_matches(key, valid, n=1)
        hints.append(f"{key!r}" + (f" (did you mean {close[0]!r}?)" if close else ""))
    raise ZooError(message.format(where=where, keys=", ".join(hints), valid=", ".join(valid) or "none"))


def has_flag(argv: Sequence[str], flag: str) -> bool:
    """Whether ``argv`` sets ``flag`` (as ``flag value`` or ``flag=value``)."""
    return any(arg == flag or arg.startswith(f"{flag}=") for arg in argv)


def flag_value(argv: Sequence[str], flag: str) -> str | None:
    """The last value ``argv`` gives ``flag``, or None."""
    value = None
    for index, arg in enumerate(argv):
        if arg == flag and index + 1 < len(argv):
            value = argv[index + 1]
        elif arg.startswith(f"{flag}="):
            value = arg.split("=", 1)[1]
    return value


def flag_items(argv: Sequence[str], flag: str) -> list[str]:
    """The items ``argv`` gives a flag that takes several (``flag a b c``, up to the next option), every time it
    is given."""
    items: list[str] = []
    taking = False
    for arg in argv:
        if arg == flag:
            taking = True
        elif taking and arg.startswith("-") and not arg[1:2].isdigit():
            taking = False
        elif taking:
            items.append(arg)
    return items


def without_flags(argv: Sequence[str], switches: Iterable[str] = (), options: Iterable[str] = ()) -> list[str]:
    """``argv`` without the flags ``switches`` (no value) and ``options`` (with their value)."""
    switches, options = set(switches), set(options)
    kept, skip = [], False
    for arg in argv:
        if skip:
            skip = False
        elif arg in switches or any(arg.startswith(f"{option}=") for option in options):
            continue
        elif arg in options:
            skip = True
        else:
            kept.append(arg)
    return kept


def train_command(argv: Sequence[str], run_id: int | None, resume: bool) -> str:
    """The ``sgfd-zoo train`` command line of ``argv`` that continues (``resume``) or restarts run ``run_id``.

    :param argv: the flags the run was started with (after ``sgfd-zoo train``)
    :param run_id: its folder's ``_<id>``; None: leave the choice to ``--resume`` (the newest run)
    :param resume: continue from the checkpoint, else start again from step 0
    """
    flags = without_flags(argv, switches=["--resume"], options=["--run-id"])
    flags += [] if run_id is None else ["--run-id", str(run_id)]
    return shlex.join(["sgfd-zoo", "train", *flags, *(["--resume"] if resume else [])])


#: what a value of ``KEY:VALUE`` may be, as the refusals say it
VALUE_FORMS = "a number, True/False/None, a quoted string, a list [...] or dict(...)"
EXAMPLE_ITEMS = {"--env-kwargs": "image_size:64", "--eval-env-kwargs": "image_size:64"}


def _dotted_name(node: ast.AST) -> list[str] | None:
    """``nn.ReLU`` as ``["nn", "ReLU"]``; None when ``node`` is not a (dotted) name."""
    parts: list[str] = []
    while isinstance(node, ast.Attribute):
        parts.insert(0, node.attr)
        node = node.value
    return [node.id, *parts] if isinstance(node, ast.Name) else None


def _dotted_names(node: ast.AST) -> Iterator[list[str]]:
    """Every (dotted) name of an expression, outermost first: ``dict(activation_fn=nn.ReLU)``: dict, nn.ReLU."""
    parts = _dotted_name(node)
    if parts is not None:
        yield parts
        return
    for child in ast.iter_child_nodes(node):
        yield from _dotted_names(child)


def _undefined_name(tree: ast.AST, namespace: Mapping[str, Any] | None) -> str | None:
    """The first (dotted) name in ``tree`` that neither Python's builtins nor ``namespace`` define, found by
    looking names up (modules' and classes' attributes only), never by running the value."""
    for head, *attributes in _dotted_names(tree):
        if hasattr(builtins, head):
            found: Any = getattr(builtins, head)
        else:
            if namespace is None:
                import rl_zoo3.utils  # the namespace rl-zoo3 evaluates KEY:VALUE in (th, nn, spaces, ...)

                namespace = vars(rl_zoo3.utils)
            if head not in namespace:
                return head
            found = namespace[head]
        for depth, attribute in enumerate(attributes, start=1):
            if not isinstance(found, (ModuleType, type)):
                break  # an instance's attribute may run code to be found: left to rl-zoo3
            if not hasattr(found, attribute):
                return ".".join([head, *attributes[:depth]])
            found = getattr(found, attribute)
    return None


def check_key_values(flag: str, items: Sequence[str] | None, namespace: Mapping[str, Any] | None = None) -> None:
    """A ZooError naming the flag and the key of the first of ``items`` that rl-zoo3 could not read, before rl-zoo3
    evaluates them as Python (its ``StoreDict``): an item without ``KEY:``, a value that is not Python
    (``learning_rate:1e-3x``), or one naming what is not defined (``obs_type:pixels``, where a string needs quotes).
    The value is parsed and its names are looked up, never run.

    :param flag: the option, e.g. ``--env-kwargs``
    :param items: its ``KEY:VALUE`` items as given
    :param namespace: where names are looked up beside Python's builtins (default: rl-zoo3's, where it evaluates)
    """
    for item in items or ():
        key, colon, text = item.partition(":")
        if not colon or not key:
            example = EXAMPLE_ITEMS.get(flag, "batch_size:64")
            raise ZooError(f"{flag} {item!r}: expected KEY:VALUE, e.g. {flag} {example}")
        if not text.strip():
            raise ZooError(f"{flag} {key}: no value after the colon; expected {VALUE_FORMS}")
        try:
            tree = ast.parse(text.lstrip(" \t"), mode="eval")
        except SyntaxError as error:
            raise ZooError(f"{flag} {key}:{text}: not a Python value ({error.msg}); expected {VALUE_FORMS}") from None
        undefined = _undefined_name(tree, namespace)
        if undefined is None:
            continue
        if "." in undefined or isinstance(tree.body, (ast.Call, ast.List, ast.Tuple, ast.Dict, ast.Set)):
            raise ZooError(f"{flag} {key}:{text}: {undefined} is not defined; expected {VALUE_FORMS}")
        # a bare word: a string whose quotes the shell took away
        quoted = f'{key}:"{text!r}"' if not set(text) & set('"$`\\!') else shlex.quote(f"{key}:{text!r}")
        raise ZooError(
            f"{flag} {key}:{text}: {undefined} is not defined; a string needs quotes that reach Python, "
            f"e.g. {flag} {quoted}"
        )
