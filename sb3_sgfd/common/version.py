"""This package's version, and the check that a saved model was not written by a newer one.

The installed distribution's version is the one pip took from sgfd_envs/version.txt (the one file both distributions
read), so an install and the file cannot disagree; a checkout used without installing it reads that same file."""

from __future__ import annotations

from importlib import metadata
from pathlib import Path

try:
    __version__ = metadata.version("sb3-sgfd")
except metadata.PackageNotFoundError:  # pragma: no cover - a checkout on sys.path without an install
    __version__ = (Path(__file__).resolve().parents[2] / "sgfd_envs" / "version.txt").read_text().strip()


def release(version: str) -> tuple[int, ...]:
    """The numeric release of a version string (``"0.3.0"`` -> (0, 3, 0); a suffix such as ``.dev1`` is ignored)."""
    parts = []
    for part in version.split("."):
        digits = "".join(c for c in part if c.isdigit()) if part[:1].isdigit() else ""
        if not digits:
            break
        parts.append(int(digits))
    return tuple(parts)


def check_saved_version(saved: str | None, what: str = "this model") -> None:
    """Refuse, in one line, a file written by a newer version of sb3-sgfd than this one (its format may hold what this
    version cannot read); a file without a version (written before versions were saved) or of this or an older
    version passes.

    :param saved: the version the file records, or None
    :param what: the file, for the message
    """
    if saved is not None and release(saved) > release(__version__):
        raise ValueError(
            f"{what} was written by sb3-sgfd {saved}, newer than this sb3-sgfd {__version__}: install {saved} or newer "
            "to load it"
        )
