"""What produced a number: the package's source (its git commit, when it runs from a checkout) and the versions
of the packages that decide the results. Written into every run's folder when it starts (``versions.txt``, one
block per start: a resumed run may continue under other code) and with a study's exported tables."""

from __future__ import annotations

import platform
import subprocess
from importlib import metadata
from pathlib import Path

PACKAGES = ("sb3-sgfd", "stable-baselines3", "rl-zoo3", "torch", "numpy", "gymnasium", "dm-control", "mujoco", "ray")
SOURCE_FOLDERS = ("sb3_sgfd", "sgfd_envs", "sgfd_zoo")
_ROOT = Path(__file__).resolve().parents[2]  # the checkout holding sgfd_zoo/runs/


def _git(*args: str) -> str | None:
    try:
        result = subprocess.run(["git", "-C", str(_ROOT), *args], capture_output=True, text=True, timeout=10)
    except (OSError, subprocess.SubprocessError):
        return None
    return result.stdout.strip() if result.returncode == 0 else None


def source() -> str:
    """The commit the package's code is at, and which of its folders differ from it (a changed file, or a new one
    git does not ignore); or that it is not a checkout (an installed wheel, say: its version line says which)."""
    top = _git("rev-parse", "--show-toplevel")
    # A wheel installed in a virtual environment inside some checkout is not that checkout's code.
    if top is None or Path(top).resolve() != _ROOT:
        return "source: not a git checkout"
    commit = _git("rev-parse", "HEAD") or "unknown"
    changed = _git("status", "--porcelain", "--", *SOURCE_FOLDERS)  # changed, and new files git does not ignore
    if changed is None:
        dirty = " (whether its folders differ from it is unknown)"
    else:
        # porcelain lines are "XY path" (the first one stripped here), the path from the checkout's root, quoted
        # when it has odd characters
        folders = sorted({line.split(maxsplit=1)[1].strip('"').split("/")[0] for line in changed.splitlines()})
        dirty = f" with uncommitted changes in {', '.join(folders)}" if folders else ""
    return f"source: git commit {commit}{dirty}"


def versions() -> str:
    """The source, Python, the platform and the versions of :data:`PACKAGES`, a line each."""
    lines = [source(), f"python {platform.python_version()}", f"platform {platform.platform()}"]
    for package in PACKAGES:
        try:
            lines.append(f"{package}=={metadata.version(package)}")
        except metadata.PackageNotFoundError:
            lines.append(f"{package}: not installed")
    return "\n".join(lines) + "\n"
