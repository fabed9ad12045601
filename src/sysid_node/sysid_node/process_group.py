"""Child processes run as process groups, stopped as ``ros2 launch`` and a terminal stop them.

Tests, benchmarks and the demo start nodes, replays and recorders in a session of their own
(``start_new_session=True``) and stop them with SIGINT to the whole group (Ctrl-C), escalating to
SIGKILL when the group has not finished within a timeout. No rclpy import: usable anywhere.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
from pathlib import Path

#: Seconds a killed group gets to be reaped.
KILL_WAIT_S = 5.0


#: Run before ``argv``: SIGINT back to its default action, then exec. A process started from a
#: background job of a non-interactive shell (``cmd &`` in a script, CI) inherits SIGINT
#: *ignored*, exec keeps it ignored, and Python then installs no KeyboardInterrupt handler:
#: the group would ignore the stop and be killed. (A pre-exec function in the parent is not
#: safe once the parent runs threads.)
_DEFAULT_SIGINT = (
    "import os, signal, sys; signal.signal(signal.SIGINT, signal.SIG_DFL); "
    "os.execvp(sys.argv[1], sys.argv[1:])"
)


def start_group(argv: list[str], log: Path | None = None,
                env: dict[str, str] | None = None) -> subprocess.Popen:
    """Start ``argv`` as the leader of a new process group, with SIGINT at its default action
    whatever the caller's (see :data:`_DEFAULT_SIGINT`), its output (stdout and stderr) into
    ``log`` (a file path; None: inherited)."""
    out = log.open("w") if log is not None else None
    try:
        return subprocess.Popen([sys.executable, "-c", _DEFAULT_SIGINT, *argv], stdout=out,
                                stderr=subprocess.STDOUT if out else None,
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
