"""Child processes run as process groups, stopped as ``ros2 launch`` and a terminal stop them.

Tests, benchmarks and the demo start nodes, replays and recorders in a session of their own
(``start_new_session=True``) and stop them with SIGINT to the whole group (Ctrl-C), escalating to
SIGKILL when the group has not finished within a timeout. No rclpy import: usable anywhere.
"""

from __future__ import annotations

import os
import signal
import subprocess
from pathlib import Path

#: Seconds a killed group gets to be reaped.
KILL_WAIT_S = 5.0


def start_group(argv: list[str], log: Path | None = None,
                env: dict[str, str] | None = None) -> subprocess.Popen:
    """Start ``argv`` as the leader of a new process group, its output (stdout and stderr) into
    ``log`` (a file path; None: inherited)."""
    out = log.open("w") if log is not None else None
    try:
        return subprocess.Popen(argv, stdout=out, stderr=subprocess.STDOUT if out else None,
                                start_new_session=True, env=env)
    finally:
        if out is not None:
            out.close()  # the child holds its own descriptor


def stop_group(proc: subprocess.Popen, timeout: float = 10.0) -> int | None:
    """SIGINT to ``proc``'s process group, wait up to ``timeout`` [s], then SIGKILL the group.
    Returns the leader's exit status (negative: killed by that signal; None: not reaped)."""
    if proc.poll() is not None:
        return proc.returncode
    try:
        os.killpg(proc.pid, signal.SIGINT)
        proc.wait(timeout=timeout)
    except subprocess.TimeoutExpired:
        try:
            os.killpg(proc.pid, signal.SIGKILL)
        except ProcessLookupError:
            pass
        try:
            proc.wait(timeout=KILL_WAIT_S)
        except subprocess.TimeoutExpired:
            return None
    except ProcessLookupError:
        proc.wait(timeout=KILL_WAIT_S)
    return proc.returncode
