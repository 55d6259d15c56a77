"""bench/device_check.py: its smoke run (CI runs it so that the GPU session's script cannot rot), its time
limits, and its table kept row by row."""

from __future__ import annotations

import importlib.util
import subprocess
import sys
import time
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]


def device_check():
    spec = importlib.util.spec_from_file_location("device_check", REPO / "bench" / "device_check.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def rows_of(table: Path) -> list[str]:
    return [line for line in table.read_text().splitlines() if line.startswith("| ") and "---" not in line][1:]


def limits_the_parts_run_with(check, budgets: dict[str, float], smoke: bool, monkeypatch) -> list[tuple[str, float]]:
    """Every part run as the check runs it, each subprocess replaced by a record of (its command, its limit)."""
    calls: list[tuple[str, float]] = []

    def record(command: list[str], budget: float) -> tuple[int, str, float]:
        calls.append((" ".join(command), budget))
        return 0, "", 0.0

    def record_together(commands: list[list[str]], budget: float) -> tuple[list[str], float]:
        calls.append((f"{len(commands)} x " + " ".join(commands[0]), budget))
        return [""] * len(commands), 0.0

    monkeypatch.setattr(check, "run", record)
    monkeypatch.setattr(check, "run_together", record_together)
    for part in check.PARTS:
        list(part(budgets, smoke))
    return calls


def test_the_parts_time_limits_add_up_to_the_checks_worst_case():
    check = device_check()
    assert sum(check.BUDGETS.values()) + check.OWN_SECONDS <= check.TOTAL_SECONDS
    assert set(check.BUDGETS) == {"cuda", "throughput", "learning sgfd_sac", "concurrent 4", "concurrent 8"} | {
        f"overhead {policy}" for policy in ("mlp", "cnn", "agents")
    }


@pytest.mark.parametrize("smoke", [False, True])
def test_every_part_runs_with_its_own_limit(smoke, monkeypatch):
    check = device_check()
    names = list(check.SMOKE_BUDGETS if smoke else check.BUDGETS)
    # distinct limits, so that each subprocess's limit says which entry it came from
    budgets = {name: 1000.0 + index for index, name in enumerate(names)}
    calls = limits_the_parts_run_with(check, budgets, smoke, monkeypatch)
    # each limit bounds exactly one subprocess, and that subprocess is its part's (every word of the name in it)
    assert sorted(budget for _, budget in calls) == sorted(budgets.values())
    command_of = {budget: command for command, budget in calls}
    for name, budget in budgets.items():
        # each word of the part's name in its command (the concurrent runs' count as "N x")
        words = [f"{word} x" if word.isdigit() and name.startswith("concurrent") else word for word in name.split()]
        words = [word for word in words if word != "concurrent"]
        assert all(word in command_of[budget] for word in words), (name, command_of[budget])


@pytest.mark.slow
def test_a_check_stopped_from_outside_keeps_the_rows_it_measured(tmp_path):
    out = tmp_path / "device_check.md"
    process = subprocess.Popen([sys.executable, "bench/device_check.py", "--smoke", "--out", str(out)], cwd=REPO)
    try:
        deadline = time.monotonic() + 300
        while time.monotonic() < deadline and process.poll() is None and not (out.exists() and rows_of(out)):
            time.sleep(0.2)
        assert out.exists() and rows_of(out), "no row within 300 s"
    finally:
        process.kill()
        process.wait(timeout=60)
    rows = rows_of(out)
    assert rows[0].startswith("| CUDA tests (`pytest -m cuda`) | ")  # the first part's row, whole
    assert out.read_text().startswith("device check, ") and "parts stopped at " in out.read_text()


@pytest.mark.slow
def test_the_device_checks_smoke_run_fills_its_table(tmp_path):
    out = tmp_path / "device_check.md"
    done = subprocess.run(
        [sys.executable, "bench/device_check.py", "--smoke", "--out", str(out)],
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=900,
    )
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-3000:]
    rows = rows_of(out)
    checks = [row.split("|")[1].strip() for row in rows]
    assert [check.split(" ")[0] for check in checks] == ["CUDA", "update_overhead", "env_throughput", "sgfd_sac", "2"]
    assert all(row.split("|")[2].strip() == "ok" for row in rows), rows
    assert "env steps per update; collecting" in rows[3] and "a paper-scale run (200,800 updates" in rows[3]
    assert "SGFD's phase" in rows[3]
    assert "env step" in rows[3] and "sample and transfer" in rows[3]
    assert "updates/s in all, " in rows[4] and " env steps per update" in rows[4]


def test_the_learning_rows_become_rows_of_the_zoos_rate_table(tmp_path):
    check = device_check()
    table = tmp_path / "rates.csv"
    table.write_text((REPO / "sgfd_zoo" / "sweep" / "device_rates.csv").read_text().splitlines()[0] + "\n")
    rows = [
        "| sgfd_sac on SGFD/walker-walk-v0, paper scale, cuda, update captured, SGFD's phase | ok | 95.2 updates/s, "
        "5.01 env steps per update; collecting 1830 env steps/s: a paper-scale run |",
        "| 8 concurrent sgfd_sac runs, 4 env processes and 1 torch thread each | ok | 310.5 updates/s in all, 4.98 env "
        "steps per update (each |",
        "| update_overhead mlp | ok | SAC 1.0 ms |",
    ]
    check.append_rates(table, rows, "NVIDIA H200")
    import csv

    from sgfd_zoo.sweep import cost

    written = list(csv.DictReader(table.open()))
    figures = ("algo", "runs_at_once", "updates_per_s", "env_steps_per_update", "env_steps_per_s", "update")
    assert [tuple(r[key] for key in figures) for r in written] == [
        ("sgfd_sac", "1", "95.2", "5.01", "", "captured"),
        ("envs", "1", "", "", "1830", ""),
        ("sgfd_sac", "8", "310.5", "4.98", "", "captured"),
    ]
    assert all(r["machine"] == "NVIDIA H200" for r in written)
    assert len(cost.read_rates(table)) == 3  # rows the plan reads
