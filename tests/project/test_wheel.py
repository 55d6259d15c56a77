"""The wheels carry everything the commands need: sb3-sgfd's and sgfd-envs', built and installed into a fresh
environment, run the quick job from another folder (so nothing is read from this checkout)."""

from __future__ import annotations

import subprocess
import sys
import sysconfig
import zipfile
from pathlib import Path

import pytest

pytestmark = pytest.mark.ray

REPO = Path(__file__).resolve().parents[2]


@pytest.mark.slow
def test_the_wheels_installed_in_a_fresh_environment_run_the_quick_job(tmp_path: Path) -> None:
    build = [sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation", "-q", "-w", str(tmp_path)]
    for project in (REPO, REPO / "sgfd_envs"):
        subprocess.run(
            [*build, str(project)],
            check=True,
            capture_output=True,
        )
    (wheel,) = tmp_path.glob("sb3_sgfd-*.whl")
    (envs_wheel,) = tmp_path.glob("sgfd_envs-*.whl")
    names = set(zipfile.ZipFile(wheel).namelist())
    shipped = {str(path.relative_to(REPO)) for path in (REPO / "sgfd_zoo" / "hyperparams").rglob("*.yml")}
    assert shipped and shipped <= names, sorted(shipped - names)
    assert {"sgfd_analysis/correlation.py", "sgfd_cli/commands.py", "sb3_sgfd/common/encoder_sac.py"} <= names
    assert "sb3_sgfd/py.typed" in names and not any(n.startswith("sgfd_envs/") for n in names)
    envs_names = set(zipfile.ZipFile(envs_wheel).namelist())
    assert {"sgfd_envs/__init__.py", "sgfd_envs/benchmarks/dcs.py", "sgfd_envs/domains/walker.py"} <= envs_names
    assert "sgfd_envs/version.txt" in envs_names and "sgfd_envs/pyproject.toml" not in envs_names
    # One version, written once: both wheels carry sgfd_envs/version.txt's.
    version = (REPO / "sgfd_envs" / "version.txt").read_text().strip()
    assert wheel.name.startswith(f"sb3_sgfd-{version}-") and envs_wheel.name.startswith(f"sgfd_envs-{version}-"), (
        wheel.name,
        envs_wheel.name,
        version,
    )

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
        [
            sys.executable,
            "-m",
            "pip",
            "--python",
            str(python),
            "install",
            "--no-deps",
            "-q",
            str(wheel),
            str(envs_wheel),
        ],
        check=True,
        capture_output=True,
    )
    work = tmp_path / "elsewhere"
    work.mkdir()
    where = subprocess.run(
        [str(python), "-c", "import sgfd_zoo, sb3_sgfd, sgfd_envs; print(sgfd_zoo.__file__, sgfd_envs.__file__)"],
        check=True, capture_output=True, text=True, cwd=work,
    ).stdout  # fmt: skip
    assert all(path.startswith(str(venv)) for path in where.split()), where
    installed = subprocess.run(
        [str(python), "-c", "import sb3_sgfd; print(sb3_sgfd.__version__)"],
        check=True, capture_output=True, text=True, cwd=work,
    ).stdout.strip()  # fmt: skip
    assert installed == version, (installed, version)

    result = subprocess.run(
        [str(venv / "bin" / "sgfd-zoo"), "quick", "-n", "300", "--seeds", "0", "--eval-episodes", "1", "-f", "out"],
        capture_output=True, text=True, cwd=work, timeout=900,
    )  # fmt: skip
    assert result.returncode == 0, result.stdout[-3000:] + result.stderr[-3000:]
    assert "sweep: 2 trained, 0 already finished, 0 failed" in result.stdout
    assert (work / "out" / "results.md").exists() and (work / "out" / "aggregate.md").exists()
