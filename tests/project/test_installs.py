"""The installs are sized to the use: the environments' distribution needs neither torch nor Stable-Baselines3, the
agents' needs neither Ray nor rl-zoo3 nor TensorBoard, and a part that is not installed is one line naming the
install that brings it."""

from __future__ import annotations

import json
import subprocess
import sys
import zipfile
from email.parser import Parser
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]

# A Python that cannot import the named top-level modules, as if they were not installed.
WITHOUT = """
import importlib.abc, sys
class Missing(importlib.abc.MetaPathFinder):
    def find_spec(self, name, path=None, target=None):
        if name.partition('.')[0] in {blocked!r}:
            raise ModuleNotFoundError(f"No module named {{name!r}}", name=name)
sys.meta_path.insert(0, Missing())
"""


def run_without(blocked: set[str], code: str, *args: str) -> subprocess.CompletedProcess:
    program = WITHOUT.format(blocked=sorted(blocked)) + code
    return subprocess.run([sys.executable, "-c", program, *args], capture_output=True, text=True, timeout=300, cwd=REPO)


def loaded_after(statement: str, watched: set[str]) -> list[str]:
    """The ``watched`` top-level modules that an unblocked Python (this one, same packages installed) has in
    ``sys.modules`` after running ``statement``: an optional import wrapped in try/except shows up here."""
    report = f"print(json.dumps(sorted(m for m in {sorted(watched)!r} if m in sys.modules)))"
    code = f"import json, sys\n{statement}\n{report}"
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300, cwd=REPO)
    assert result.returncode == 0, result.stderr[-2000:]
    return json.loads(result.stdout.strip().splitlines()[-1])


def requirements(project: Path, tmp_path: Path) -> list[str]:
    """The Requires-Dist lines of the wheel built from ``project``."""
    build = [sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation", "-q", "-w", str(tmp_path)]
    subprocess.run(
        [*build, str(project)],
        check=True,
        capture_output=True,
    )
    (wheel,) = tmp_path.glob("*.whl")
    with zipfile.ZipFile(wheel) as archive:
        name = next(n for n in archive.namelist() if n.endswith(".dist-info/METADATA"))
        metadata = Parser().parsestr(archive.read(name).decode())
    return metadata.get_all("Requires-Dist") or []


def names(requires: list[str], extra: str | None = None) -> set[str]:
    """The distributions required, unconditionally (``extra`` None) or by that extra."""
    chosen = set()
    for line in requires:
        requirement, _, marker = line.partition(";")
        if (extra is None) == (not marker.strip()) and (extra is None or f'extra == "{extra}"' in marker):
            chosen.add(requirement.split("[")[0].split("<")[0].split(">")[0].split("=")[0].strip().lower())
    return chosen


@pytest.mark.slow
def test_the_environments_distribution_needs_neither_torch_nor_stable_baselines3(tmp_path: Path) -> None:
    required = names(requirements(REPO / "sgfd_envs", tmp_path))
    assert {"gymnasium", "dm-control", "mujoco", "opencv-python-headless"} <= required
    assert not required & {"torch", "stable-baselines3", "ray", "rl-zoo3", "tensorboard", "sb3-sgfd"}


@pytest.mark.slow
def test_the_agents_distribution_leaves_the_zoo_to_its_extra(tmp_path: Path) -> None:
    requires = requirements(REPO, tmp_path)
    base, zoo = names(requires), names(requires, "zoo")
    assert {"sgfd-envs", "stable-baselines3", "torch"} <= base
    assert not base & {"ray", "rl-zoo3", "rliable", "tensorboard", "optuna", "matplotlib", "pandas"}
    assert {"rl-zoo3", "ray", "rliable", "matplotlib"} <= zoo
    assert not any("==" in line and line.lower().startswith("torch") for line in requires)  # a range, not a pin


def test_the_environments_run_without_torch_or_stable_baselines3() -> None:
    code = (
        "import gymnasium as gym, sgfd_envs\n"
        "env = gym.make('DMCGB/walker-walk-v0', split='color_hard', image_size=32)\n"
        "obs, info = env.reset(seed=0); env.step(env.action_space.sample())\n"
        "print(obs.shape, info['domain'])\n"
    )
    result = run_without({"torch", "stable_baselines3"}, code)
    assert result.returncode == 0, result.stderr[-2000:]
    assert result.stdout.split("\n")[0].endswith(" 0"), result.stdout
    assert loaded_after(code, {"torch", "stable_baselines3"}) == []


@pytest.mark.slow
def test_the_agents_import_without_the_zoo() -> None:
    zoo = {"ray", "rl_zoo3", "tensorboard", "rliable", "optuna"}
    result = run_without(zoo, "import sb3_sgfd")
    assert result.returncode == 0, result.stderr[-2000:]
    # Stable-Baselines3's logger imports TensorBoard itself when it is installed; sb3_sgfd adds none of the zoo's.
    by_sb3 = loaded_after("import stable_baselines3", zoo)
    assert set(by_sb3) <= {"tensorboard"}
    assert loaded_after("import sb3_sgfd", zoo) == by_sb3


def test_a_zoo_command_without_the_zoo_installed_names_the_install_in_one_line() -> None:
    code = "from sgfd_cli import main; sys.exit(main(sys.argv[1:]))"
    result = run_without({"rl_zoo3", "ray"}, code, "train", "--algo", "sac", "--env", "SGFD/MT-walker-walk-v0")
    assert result.returncode == 2
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and "pip install -e ./sgfd_envs -e '.[zoo]' -c constraints.txt" in lines[0], result.stderr
    assert "sb3-sgfd" not in lines[0]  # the distribution is not on a package index: the clone is where it comes from
