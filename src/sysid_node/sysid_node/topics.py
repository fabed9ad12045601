"""Topic names as ROS 2 writes them (pure, no rclpy): checks, resolution, ``--ros-args``.

Default topic names of both nodes are *relative* (``vibration``, ``modal_estimate``, ...), so a
namespace (``--ros-args -r __ns:=/left_wing``, ``PushRosNamespace``, ``namespace=`` of a launch
``Node``) moves them with the node: ``/left_wing/vibration``. ``/diagnostics`` stays absolute
by convention (one aggregator for the whole robot). A bag stores fully qualified names, so
offline tools resolve a relative name against a namespace (the root by default) before looking
it up in a bag.
"""

from __future__ import annotations

import re

_SUBST = r"\{[A-Za-z_]\w*\}"
_TOKEN = re.compile(rf"^(?:[A-Za-z_]|{_SUBST})(?:\w|{_SUBST})*$", re.ASCII)


def topic_name_error(name: str) -> str:
    """Why ``name`` is not a valid ROS 2 topic name ('' when it is).

    Absolute (``/a/b``), relative (``a/b``) and private (``~/a``) names are accepted; tokens
    start with a letter or underscore and hold letters, digits and underscores (or a
    ``{substitution}``); no empty token, no trailing slash.
    """
    if not isinstance(name, str) or not name:
        return "a topic name must not be empty"
    body = name
    if body.startswith("~"):
        body = body[1:]
        if body and not body.startswith("/"):
            return f"'{name}': '~' must be followed by '/'"
        body = body[1:]
        if not body:
            return ""
    elif body.startswith("/"):
        body = body[1:]
    if not body:
        return f"'{name}': no name after the namespace separator"
    for token in body.split("/"):
        if not token:
            return f"'{name}': empty name token ('//' or a trailing '/')"
        if not _TOKEN.match(token):
            return (f"'{name}': token '{token}' must start with a letter or '_' and hold only "
                    "letters, digits and '_'")
    return ""


def resolve(name: str, namespace: str = "/") -> str:
    """Fully qualified name of ``name`` in ``namespace`` (as a node there resolves it).

    ``resolve("vibration", "/left_wing") == "/left_wing/vibration"``; absolute names are kept.
    Private names (``~/x``) need the node name and are not resolved here (ValueError).
    """
    if name.startswith("/"):
        return name
    if name.startswith("~"):
        raise ValueError(f"cannot resolve the private topic name '{name}' without a node")
    ns = "/" + namespace.strip("/") if namespace.strip("/") else ""
    return f"{ns}/{name}"


def split_ros_args(argv: list[str]) -> tuple[list[str], list[str]]:
    """``argv`` without its ROS arguments, and those arguments (``--ros-args ... [--]``),
    so a tool parses its own options and hands the rest to ``rclpy.init``."""
    own: list[str] = []
    ros: list[str] = []
    inside = False
    for arg in argv:
        if arg == "--ros-args":
            inside = True
            ros.append(arg)
        elif inside and arg == "--":
            inside = False
        elif inside:
            ros.append(arg)
        else:
            own.append(arg)
    return own, ros
