"""What the distributions say of themselves: the Python versions they install on, their licence in each built
file, and how to cite the software (CITATION.cff)."""

from __future__ import annotations

import subprocess
import sys
import tarfile
import zipfile
from pathlib import Path

import pytest
import yaml

REPO = Path(__file__).resolve().parents[2]
PROJECTS = {"sb3-sgfd": REPO, "sgfd-envs": REPO / "sgfd_envs"}
# dm_control needs labmaze, whose wheels stop at CPython 3.12 (newer ones build it with Bazel)
PYTHONS = ("3.10", "3.11", "3.12")


@pytest.mark.parametrize("name", list(PROJECTS))
def test_each_distribution_says_the_python_versions_it_installs_on(name: str) -> None:
    tomllib = pytest.importorskip("tomllib")  # Python 3.11's; the wheel's test reads the built metadata on 3.10
    project = tomllib.loads((PROJECTS[name] / "pyproject.toml").read_text())["project"]
    assert project["requires-python"] == ">=3.10,<3.13"
    python = "Programming Language :: Python :: 3."
    versions = [
        classifier.rsplit(" :: ", 1)[1] for classifier in project["classifiers"] if classifier.startswith(python)
    ]
    assert tuple(versions) == PYTHONS
    assert (
        project["license-files"] == ["LICENSE"]
        and (PROJECTS[name] / "LICENSE").read_text() == (REPO / "LICENSE").read_text()
    )
    assert "Python 3.10-3.12" in (REPO / "README.md").read_text()


@pytest.mark.slow
def test_the_environments_sdist_and_wheel_ship_the_licence(tmp_path: Path) -> None:
    project = PROJECTS["sgfd-envs"]
    build = (
        f"from setuptools import build_meta as b; b.build_sdist({str(tmp_path)!r}); b.build_wheel({str(tmp_path)!r})"
    )
    subprocess.run([sys.executable, "-c", build], cwd=project, check=True, capture_output=True, timeout=600)
    (sdist,) = tmp_path.glob("sgfd_envs-*.tar.gz")
    (wheel,) = tmp_path.glob("sgfd_envs-*.whl")
    with tarfile.open(sdist) as archive:
        members = {member.split("/", 1)[1] for member in archive.getnames() if "/" in member}
        licence = archive.extractfile(f"{sdist.name.removesuffix('.tar.gz')}/LICENSE")
        assert licence is not None and licence.read().decode() == (REPO / "LICENSE").read_text()
    assert "LICENSE" in members
    with zipfile.ZipFile(wheel) as archive:
        licences = [name for name in archive.namelist() if name.endswith(".dist-info/licenses/LICENSE")]
        assert len(licences) == 1 and archive.read(licences[0]).decode() == (REPO / "LICENSE").read_text()
        metadata = archive.read(next(n for n in archive.namelist() if n.endswith(".dist-info/METADATA"))).decode()
    assert "License-Expression: MIT" in metadata and "Requires-Python: <3.13,>=3.10" in metadata
    assert [
        line for line in metadata.splitlines() if line.startswith("Classifier: Programming Language :: Python :: 3.")
    ] == [f"Classifier: Programming Language :: Python :: {version}" for version in PYTHONS]


def test_the_citation_file_cites_this_version_and_prefers_the_paper() -> None:
    citation = yaml.safe_load((REPO / "CITATION.cff").read_text())
    assert citation["cff-version"] == "1.2.0" and citation["type"] == "software"
    assert citation["message"] and citation["title"].startswith("sb3-sgfd") and citation["authors"]
    assert citation["version"] == (REPO / "sgfd_envs" / "version.txt").read_text().strip()
    assert citation["license"] == "MIT"
    paper = citation["preferred-citation"]
    assert paper["type"] == "conference-paper" and paper["year"] == 2023 and paper["volume"] == 36
    citing = (REPO / "docs" / "citing.md").read_text()
    assert f"title     = {{{paper['title']}}}" in citing  # the same paper docs/citing.md's BibTeX names
    names = [f"{author['family-names']}, {author['given-names']}" for author in paper["authors"]]
    assert names[0] == "Huang, Sili" and len(names) == 8 and all(name.split(",")[0] in citing for name in names)
