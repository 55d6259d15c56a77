"""bench/device_check.py's smoke run (CI runs it so that the GPU session's script cannot rot)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]


@pytest.mark.slow
def test_the_device_checks_smoke_run_fills_its_table(tmp_path):
    out = tmp_path / "device_check.md"
    done = subprocess.run(
        [sys.executable, "bench/device_check.py", "--smoke", "--out", str(out)],
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-3000:]
    rows = [line for line in out.read_text().splitlines() if line.startswith("| ") and "---" not in line][1:]
    checks = [row.split("|")[1].strip() for row in rows]
    assert [check.split(" ")[0] for check in checks] == [
        "CUDA",
        "update_overhead",
        "env_throughput",
        "sgfd_sac",
        "ambs",
    ]
    assert all(row.split("|")[2].strip() == "ok" for row in rows), rows
    assert "updates/s: a 500k-update run in" in rows[-1]
