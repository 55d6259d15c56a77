"""The Makefile is the one place the project's commands live: its install and test targets run README.md's two
commands, its ci target runs every gate and the tests, and .ci/run runs CI through it."""

from __future__ import annotations

import os
import re
import subprocess
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]


def planned(target: str) -> list[str]:
    """The commands ``make TARGET`` would run (``make -n``), with ``python -m pip`` written as README writes it."""
    # a clean make: under `make ci` this test inherits MAKELEVEL, which would add "Entering directory" lines
    env = {name: value for name, value in os.environ.items() if name not in ("MAKEFLAGS", "MAKELEVEL", "MFLAGS")}
    command = ["make", "--no-print-directory", "-n", target]
    result = subprocess.run(command, capture_output=True, text=True, cwd=REPO, check=True, env=env)
    return [line.strip().replace("python -m pip ", "pip ") for line in result.stdout.splitlines()]


def readme_commands(heading_words: str) -> list[str]:
    """The commands of README.md's code block that follows the sentence starting with ``heading_words``."""
    text = (REPO / "README.md").read_text()
    after = text[text.index(heading_words) :]
    block = re.search(r"```bash\n(.*?)\n```", after, flags=re.DOTALL)
    assert block is not None
    return [command.strip() for command in block.group(1).split("&&")]


def test_make_install_and_test_run_the_readmes_test_commands() -> None:
    install, test = readme_commands("Run the tests")
    assert planned("install") == [install]
    assert planned("test") == [test] == ["python -m pytest"]


def test_make_ci_runs_every_gate_then_the_tests() -> None:
    commands = planned("ci")
    assert commands[:3] == ["python -m ruff check .", "python -m ruff format --check .", planned("type")[0]]
    assert planned("type")[0] == "python -m mypy sb3_sgfd sgfd_envs sgfd_zoo sgfd_analysis sgfd_cli"
    assert commands[3].startswith("python -m mkdocs build --strict --site-dir ")
    assert commands[4:] == ["python -m pytest"]


def test_ci_runs_through_the_makefile() -> None:
    script = (REPO / ".ci" / "run").read_text()
    lines = [line.strip() for line in script.splitlines() if line.strip() and not line.lstrip().startswith("#")]
    assert "make install" in lines and any(line.startswith("make ci") for line in lines)
    # no gate or test command of its own: they are the Makefile's
    assert not [line for line in lines if re.search(r"\b(ruff|mypy|mkdocs|pytest|pip)\b", line)]
