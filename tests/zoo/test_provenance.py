"""What trained a run: the source's commit, whether its code differs from it, and the packages' versions."""

from __future__ import annotations

import subprocess
from importlib import metadata
from pathlib import Path

from sgfd_zoo.runs import provenance


def git(folder: Path, *args: str) -> str:
    command = ["git", "-C", str(folder), "-c", "user.name=t", "-c", "user.email=t@t", *args]
    return subprocess.run(command, check=True, capture_output=True, text=True).stdout.strip()


def test_the_source_is_the_checkouts_commit_and_says_when_its_code_differs(tmp_path, monkeypatch):
    checkout = tmp_path / "checkout"
    for folder in provenance.SOURCE_FOLDERS:
        (checkout / folder).mkdir(parents=True)
        (checkout / folder / "code.py").write_text("x = 1\n")
    (checkout / "README.md").write_text("notes\n")
    git(checkout, "init", "-q")
    git(checkout, "add", ".")
    git(checkout, "commit", "-q", "-m", "first")
    commit = git(checkout, "rev-parse", "HEAD")
    monkeypatch.setattr(provenance, "_ROOT", checkout.resolve())
    assert provenance.source() == f"source: git commit {commit}"
    dirty = f"source: git commit {commit} with uncommitted changes in"
    # Files outside the code, and files git ignores, do not change what the code is; a change or a new file does.
    (checkout / "README.md").write_text("more notes\n")
    (checkout / ".gitignore").write_text("*.pyc\n")
    (checkout / "sgfd_zoo" / "code.pyc").write_bytes(b"compiled")
    assert provenance.source() == f"source: git commit {commit}"
    (checkout / "sgfd_zoo" / "scratch.py").write_text("y = 2\n")
    assert provenance.source() == f"{dirty} sgfd_zoo"
    (checkout / "sgfd_zoo" / "scratch.py").unlink()
    (checkout / "sgfd_envs" / "code.py").write_text("x = 2\n")
    assert provenance.source() == f"{dirty} sgfd_envs"
    (checkout / "sb3_sgfd" / "new").mkdir()
    (checkout / "sb3_sgfd" / "new" / "module.py").write_text("z = 3\n")
    assert provenance.source() == f"{dirty} sb3_sgfd, sgfd_envs"
    # The package installed into a folder inside some checkout (a virtual environment there) is not its code.
    site = checkout / ".venv" / "site-packages"
    site.mkdir(parents=True)
    monkeypatch.setattr(provenance, "_ROOT", site.resolve())
    assert provenance.source() == "source: not a git checkout"


def test_the_versions_name_the_source_and_each_package():
    lines = provenance.versions().splitlines()
    assert lines[0] == provenance.source()
    for package in ("stable-baselines3", "dm-control", "torch"):
        assert f"{package}=={metadata.version(package)}" in lines
    assert [line.split("==")[0].split(":")[0] for line in lines[3:]] == list(provenance.PACKAGES)
