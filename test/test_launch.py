"""The launch files through ``launch``'s Python API, as ``ros2 launch`` runs them (process level,
real DDS): a bag replayed through ``notch_filter.launch.py`` and SIGINT to the whole process
group ends both nodes with exit code 0 and no traceback; ``sysid.launch.py`` takes its topics
from the YAML unless an argument is given, and its namespace moves them.

``launch`` and ``launch_ros`` are not on PyPI: on a workspace without them (this one's CI)
these tests skip; on a ROS 2 install (or with them built from source) they run.
"""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

try:
    import launch  # noqa: F401
    import launch_ros  # noqa: F401
except ImportError:
    pytestmark = pytest.mark.skip(reason="launch/launch_ros not importable (no ROS 2 install)")

REPO = Path(__file__).resolve().parents[1]
BAG = REPO / "bags" / "paper_example"
ADAPTIVE = REPO / "src" / "notch_filter_node" / "config" / "adaptive_notch.yaml"
RUNNER = """
import sys
from launch import LaunchDescription, LaunchService
from launch.actions import GroupAction, IncludeLaunchDescription
from launch.launch_description_sources import PythonLaunchDescriptionSource
from ament_index_python.packages import get_package_share_directory

def include(pkg, name, args):
    path = f"{get_package_share_directory(pkg)}/launch/{name}"
    return GroupAction([IncludeLaunchDescription(PythonLaunchDescriptionSource(path),
                                                 launch_arguments=list(args.items()))])

ls = LaunchService()
ls.include_launch_description(LaunchDescription([include(*x) for x in INCLUDES]))
sys.exit(ls.run())
"""


def _launch(includes: list, log: Path) -> subprocess.Popen:
    env = {**os.environ, "ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST"}
    env.setdefault("ROS_DOMAIN_ID", str(10 + os.getpid() % 80))
    code = RUNNER.replace("INCLUDES", repr(includes))
    return subprocess.Popen([sys.executable, "-c", code], stdout=log.open("w"),
                            stderr=subprocess.STDOUT, env=env, start_new_session=True)


def _wait_for(log: Path, patterns: list[str], proc: subprocess.Popen, timeout: float = 150):
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        text = log.read_text()
        if all(re.search(p, text) for p in patterns):
            return text
        if proc.poll() is not None:
            break
        time.sleep(0.5)
    _interrupt(proc)
    pytest.fail(f"launch did not log {patterns} within {timeout:.0f} s:\n{log.read_text()[-3000:]}")


def _interrupt(proc: subprocess.Popen) -> int:
    """Ctrl-C as a terminal sends it: SIGINT to the whole process group."""
    os.killpg(proc.pid, signal.SIGINT)
    try:
        return proc.wait(timeout=40)
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGKILL)
        proc.wait(timeout=5)
        return -9


def _assert_clean(text: str, code: int, processes: list[str]) -> None:
    """Launch exited 0, every node it started finished cleanly, nothing died or raised."""
    assert code == 0, text[-3000:]
    started = re.findall(r"\[INFO\] \[(\w+)-\d+\]: process started", text)
    clean = re.findall(r"\[INFO\] \[(\w+)-\d+\]: process has finished cleanly", text)
    assert sorted(set(started)) == sorted(processes), started
    assert sorted(clean) == sorted(started), text[-3000:]
    assert "Traceback" not in text and "process has died" not in text, text[-3000:]
    assert "\x1b[" not in text  # no terminal colour codes in a non-terminal log


@pytest.mark.dds
@pytest.mark.slow
def test_bag_through_notch_filter_launch_then_sigint_to_the_group(tmp_path):
    log = tmp_path / "launch.log"
    proc = _launch([("notch_filter_node", "notch_filter.launch.py",
                     {"params_file": str(ADAPTIVE)})], log)
    _wait_for(log, [r"identifying modes from /vibration", r"filtering /vibration"], proc)
    replay = subprocess.run(
        [sys.executable, "-m", "sysid_node.tools.replay", "--bag", str(BAG), "--rate", "4",
         "--quiet", "--wait-subscribers", "30"],
        capture_output=True, text=True, timeout=120,
    )
    assert replay.returncode == 0, replay.stderr
    _wait_for(log, [r"notch bank ready"], proc, timeout=30)
    code = _interrupt(proc)  # first: the log must hold what happened after the SIGINT
    _assert_clean(log.read_text(), code, ["sysid_node", "notch_filter_node"])


@pytest.mark.dds
@pytest.mark.slow
def test_sysid_launch_keeps_the_yaml_unless_an_argument_is_given(tmp_path):
    params = tmp_path / "imu.yaml"
    params.write_text("/**/sysid_node:\n  ros__parameters:\n    output_topic: imu/data\n"
                      "    output_type: Imu\n    input_topic: ''\n")
    log = tmp_path / "launch.log"
    proc = _launch([
        ("sysid_node", "sysid.launch.py", {"params_file": str(params), "namespace": "a"}),
        ("sysid_node", "sysid.launch.py", {"params_file": str(params), "namespace": "b",
                                           "output_topic": "acc_b"}),
    ], log)
    text = _wait_for(log, [r"\[a\.sysid_node\]: identifying", r"\[b\.sysid_node\]: identifying"],
                     proc)
    # the YAML's topic and type (the launch file's own defaults used to replace them) ...
    assert "[a.sysid_node]: identifying modes from /a/imu/data (Imu), output-only" in text
    # ... and an argument given on the command line wins over the YAML
    assert "[b.sysid_node]: identifying modes from /b/acc_b (Imu), output-only" in text
    _interrupt(proc)  # a clean stop is the other test's business
