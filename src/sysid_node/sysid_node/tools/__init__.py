"""Executables of sysid_node (replay, record, offline, validate) and what they share.

Every tool ends a failure with one line on stderr and a non-zero exit, never a traceback.
"""

from __future__ import annotations

import importlib
import signal
import sys
from collections.abc import Callable, Sequence
from typing import Any

from sysid_node.bag_io import BagError
from sysid_node.topics import split_ros_args


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


def run_tool(prog: str, parse: Callable[[list[str] | None], Any], run: Callable[[Any], int],
             argv: list[str] | None) -> int:
    """``run(parse(argv))``; a bag or tool error, or anything unexpected, ends with one line
    ``prog: error: ...`` and exit status 1, never a traceback (``--help`` and usage errors exit as
    argparse says). ROS arguments (``--ros-args ... [--]``) are taken out before parsing and kept
    in ``args.ros_args`` for :func:`start_node`, as ``ros2 run`` passes them."""
    own, ros_args = split_ros_args(sys.argv[1:] if argv is None else list(argv))
    try:
        args = parse(own)
    except SystemExit as exit_:
        return int(exit_.code or 0)
    args.ros_args = ros_args
    try:
        return run(args)
    except (BagError, ToolError) as err:
        return fail(prog, str(err))
    except Exception as err:  # a CLI ends with one line, never a traceback
        return fail(prog, f"{type(err).__name__}: {err}")


def start_node(name: str, ros_args: Sequence[str] = ()) -> tuple[Any, dict[str, bool]]:
    """rclpy without its own signal handlers, and a node ``name``: SIGINT and SIGTERM set
    ``stop["flag"]`` so the tool's loop ends and it cleans up. ``ros_args`` (``--ros-args -r
    __ns:=/left_wing ...``) apply to the node. Returns ``(node, stop)``."""
    import rclpy
    from rclpy.signals import SignalHandlerOptions

    stop = {"flag": False}

    def on_signal(signum, frame) -> None:
        stop["flag"] = True

    rclpy.init(args=[name, *ros_args], signal_handler_options=SignalHandlerOptions.NO)
    signal.signal(signal.SIGINT, on_signal)
    signal.signal(signal.SIGTERM, on_signal)
    return rclpy.create_node(name), stop


def stop_node(node: Any) -> None:
    """Destroy the node of :func:`start_node` and shut rclpy down."""
    import rclpy

    node.destroy_node()
    if rclpy.ok():
        rclpy.shutdown()
