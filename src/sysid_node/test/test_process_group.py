"""process_group: SIGINT reaches the whole group; a group that ignores it is killed."""

from __future__ import annotations

import os
import signal
import sys
import time

from sysid_node.process_group import start_group, stop_group

# a parent that starts a grandchild in its group, tells its pid, and waits
SCRIPT = """
import signal, subprocess, sys, time
if sys.argv[1] == "ignore":
    signal.signal(signal.SIGINT, signal.SIG_IGN)
child = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"])
print(child.pid, flush=True)
try:
    time.sleep(60)
except KeyboardInterrupt:
    child.wait()
    sys.exit(0)
"""


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    with open(f"/proc/{pid}/stat") as fh:  # a zombie (not yet reaped by its parent) is gone
        return fh.read().rsplit(")", 1)[1].split()[0] != "Z"


def _child_pid(log) -> int:
    deadline = time.monotonic() + 20
    while time.monotonic() < deadline:
        text = log.read_text().strip()
        if text:
            return int(text.splitlines()[0])
        time.sleep(0.05)
    raise AssertionError("the group did not start")


def _stops(proc, log, timeout: float) -> int | None:
    """stop_group's status; the grandchild is gone within 5 s after it."""
    child = _child_pid(log)
    status = stop_group(proc, timeout=timeout)
    deadline = time.monotonic() + 5
    while _alive(child) and time.monotonic() < deadline:
        time.sleep(0.05)
    assert not _alive(child)
    return status


def test_sigint_stops_the_group_cleanly(tmp_path):
    log = tmp_path / "out.log"
    proc = start_group([sys.executable, "-c", SCRIPT, "obey"], log)
    assert _stops(proc, log, timeout=10) == 0


def test_sigint_stops_a_group_started_with_sigint_ignored(tmp_path):
    """A caller that ignores SIGINT (a background job of a script) must not pass that on."""
    log = tmp_path / "out.log"
    previous = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        proc = start_group([sys.executable, "-c", SCRIPT, "obey"], log)
    finally:
        signal.signal(signal.SIGINT, previous)
    assert _stops(proc, log, timeout=10) == 0


def test_group_ignoring_sigint_is_killed(tmp_path):
    log = tmp_path / "out.log"
    proc = start_group([sys.executable, "-c", SCRIPT, "ignore"], log)
    assert _stops(proc, log, timeout=0.5) == -signal.SIGKILL


def test_finished_process_returns_its_status(tmp_path):
    proc = start_group([sys.executable, "-c", "raise SystemExit(3)"], tmp_path / "out.log")
    proc.wait(timeout=20)
    assert stop_group(proc) == 3
