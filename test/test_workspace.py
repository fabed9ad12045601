"""The workspace tooling: idempotent setup, `ros2 run` stand-in, one-line failures."""

from __future__ import annotations

import os
import subprocess
import time
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
WS = REPO / "ros2_ws"


def _run(
    cmd: list[str], env: dict | None = None, timeout: float = 120
) -> subprocess.CompletedProcess:
    full_env = {**os.environ, **(env or {})}
    return subprocess.run(cmd, capture_output=True, text=True, timeout=timeout, env=full_env)


#: runs ros2_ws/setup in this checkout: never beside other tests that use the workspace
pytestmark = pytest.mark.serial


def test_second_setup_is_fast_and_changes_nothing():
    t0 = time.monotonic()
    res = _run([str(WS / "setup")])
    elapsed = time.monotonic() - t0
    assert res.returncode == 0, res.stderr
    assert "dependencies up to date" in res.stdout
    assert "packages up to date" in res.stdout
    assert elapsed < 30, f"idempotent setup took {elapsed:.1f} s"


def test_setup_rejects_wrong_python_with_one_line(tmp_path):
    fake = tmp_path / "python3"
    fake.write_text("#!/bin/sh\necho 3.10\n")
    fake.chmod(0o755)
    res = _run([str(WS / "setup")], env={"PYTHON": str(fake)})
    assert res.returncode != 0
    lines = res.stderr.strip().splitlines()
    assert len(lines) == 1 and "Python 3.11 is required" in lines[0]
    assert "Traceback" not in res.stderr


def test_setup_without_package_index_fails_with_one_line(tmp_path):
    empty = tmp_path / "no-wheels"
    empty.mkdir()
    env = {
        "SYSID_VENV": str(tmp_path / "venv"),
        "PIP_NO_INDEX": "1",
        "PIP_FIND_LINKS": str(empty),
        "PIP_EXTRA_INDEX_URL": "",
    }
    res = _run([str(WS / "setup")], env=env, timeout=300)
    assert res.returncode != 0
    lines = res.stderr.strip().splitlines()
    assert len(lines) == 1, res.stderr
    assert lines[0].startswith("setup: error: pip could not install")
    assert "Traceback" not in res.stderr


def test_run_unknown_package_and_executable_one_line():
    res = _run([str(WS / "run"), "no_such_pkg", "x"])
    assert res.returncode != 0
    assert (
        res.stderr.strip()
        == "run: error: package 'no_such_pkg' not found (built? run ros2_ws/setup)"
    )
    res = _run([str(WS / "run"), "sysid_msgs", "no_such_exe"])
    assert res.returncode != 0
    assert len(res.stderr.strip().splitlines()) == 1
    assert "no executable 'no_such_exe' in package 'sysid_msgs'" in res.stderr


def test_env_exposes_ros_and_interfaces():
    code = "import rclpy, sysid_msgs.msg, os; print(os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'])"
    res = _run([str(WS / "env"), "python", "-c", code])
    assert res.returncode == 0, res.stderr
    assert res.stdout.strip() == "LOCALHOST"
