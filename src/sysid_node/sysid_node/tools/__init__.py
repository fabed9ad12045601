"""Executables of sysid_node (replay, record, offline, validate) and what they share.

Every tool ends a failure with one line on stderr and a non-zero exit, never a traceback.
"""

from __future__ import annotations

import importlib
import sys


class ToolError(RuntimeError):
    """Ends a tool with a one-line reason (``str(err)``) and exit status 1."""


def msg_class(msgtype: str) -> type:
    """The rclpy message class of ``pkg/msg/Name`` (or ``pkg/Name``), imported from ``pkg.msg``.

    rosidl_runtime_py is not available everywhere, so the generated module is imported directly.
    """
    parts = msgtype.split("/")
    if len(parts) == 2:
        parts = [parts[0], "msg", parts[1]]
    if len(parts) != 3 or not all(parts):
        raise ToolError(f"malformed message type {msgtype!r} (expected pkg/msg/Name)")
    pkg, kind, name = parts
    try:
        module = importlib.import_module(f"{pkg}.{kind}")
        cls = getattr(module, name)
    except (ImportError, AttributeError):
        raise ToolError(
            f"unknown message type {msgtype}: no rclpy class {pkg}.{kind}.{name} is installed"
        ) from None
    return cls


def fail(prog: str, reason: str, status: int = 1) -> int:
    """Print ``prog: error: reason`` on one line to stderr and return ``status``."""
    line = " ".join(str(reason).split())
    print(f"{prog}: error: {line}", file=sys.stderr, flush=True)
    return status
