"""The wheel carries everything the commands need: built, installed into a fresh environment, it runs the
quick job from another folder (so nothing is read from this checkout)."""

from __future__ import annotations

import subprocess
import sys
import sysconfig
import zipfile
from pathlib import Path

import pytest

pytestmark = pytest.mark.ray

REPO = Path(__file__).resolve().parents[1]


@pytest.mark.slow
def test_the_wheel_installed_in_a_fresh_environment_runs_the_quick_job(tmp_path: Path) -> None:
    subprocess.run(
        [
            sys.executable,
            "-m",
            "pip",
            "wheel",
            "--no-deps",
            "--no-build-isolation",
            "-q",
            "-w",
            str(tmp_path),
            str(REPO),
        ],
        check=True,
        capture_output=True,
    )
    (wheel,) = tmp_path.glob("sb3_sgfd-*.whl")
    names = set(zipfile.ZipFile(wheel).namelist())
    shipped = {str(path.relative_to(REPO)) for path in (REPO / "sgfd_zoo" / "hyperparams").rglob("*.yml")}
    assert shipped and shipped <= names, sorted(shipped - names)
    assert {"sgfd_analysis/correlation.py", "sgfd_zoo/cli.py", "sb3_sgfd/encoder_sac.py"} <= names

    # A fresh environment with the wheel; its dependencies are this environment's packages, behind its own
    # site-packages (a plain path in a .pth file: the editable install's finder there is not run).
    venv = tmp_path / "venv"
    subprocess.run([sys.executable, "-m", "venv", "--without-pip", str(venv)], check=True)
    python = venv / "bin" / "python"
    site = subprocess.run(
        [str(python), "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
        check=True, capture_output=True, text=True,
    ).stdout.strip()  # fmt: skip
    dependencies = {sysconfig.get_paths()["purelib"], sysconfig.get_paths()["platlib"]}
    (Path(site) / "dependencies.pth").write_text("\n".join(sorted(dependencies)) + "\n")
    subprocess.run(
        [sys.executable, "-m", "pip", "--python", str(python), "install", "--no-deps", "-q", str(wheel)],
        check=True,
        capture_output=True,
    )
    work = tmp_path / "elsewhere"
    work.mkdir()
    where = subprocess.run(
        [str(python), "-c", "import sgfd_zoo, sb3_sgfd, sgfd_analysis; print(sgfd_zoo.__file__, sgfd_analysis.__file__)"],  # noqa: E501
        check=True, capture_output=True, text=True, cwd=work,
    ).stdout  # fmt: skip
    assert all(path.startswith(str(venv)) for path in where.split()), where

    result = subprocess.run(
        [str(venv / "bin" / "sgfd-zoo"), "quick", "-n", "300", "--seeds", "0", "--eval-episodes", "1", "-f", "out"],
        capture_output=True, text=True, cwd=work, timeout=900,
    )  # fmt: skip
    assert result.returncode == 0, result.stdout[-3000:] + result.stderr[-3000:]
    assert "sweep: 2 trained, 0 already finished, 0 failed" in result.stdout
    assert (work / "out" / "results.md").exists() and (work / "out" / "aggregate.md").exists()
