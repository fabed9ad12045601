"""rosbag2 access through the pure-Python ``rosbags`` library (no rclpy, no rosbag2).

The ``sysid_msgs`` definitions are registered from their ``.msg`` files: the installed copies
(``share/sysid_msgs/msg`` found through the ament index) or, in a source checkout, the package
sources. Messages read here are ``rosbags`` dataclasses, not rclpy messages.
"""

from __future__ import annotations

import os
from functools import cache
from pathlib import Path

from rosbags.typesys import Stores, get_types_from_msg, get_typestore
from rosbags.typesys.store import Typestore

MSG_PACKAGE = "sysid_msgs"
_SOURCE_MSG_DIR = Path(__file__).resolve().parents[2] / MSG_PACKAGE / "msg"


class BagError(RuntimeError):
    """A bag cannot be used; ``str(err)`` is a one-line reason for the user."""


def msg_dir() -> Path:
    """Directory holding ``sysid_msgs/msg/*.msg`` (installed share first, then the sources)."""
    try:
        from ament_index_python.packages import get_package_share_directory

        installed = Path(get_package_share_directory(MSG_PACKAGE)) / "msg"
        if any(installed.glob("*.msg")):
            return installed
    except (ImportError, LookupError, ValueError):
        pass
    if any(_SOURCE_MSG_DIR.glob("*.msg")):
        return _SOURCE_MSG_DIR
    raise BagError(f"cannot find the {MSG_PACKAGE} .msg files (workspace not built?)")


@cache
def typestore(store: Stores = Stores.ROS2_KILTED) -> Typestore:
    """A typestore with the ROS 2 standard types plus every ``sysid_msgs`` message."""
    ts = get_typestore(store)
    types: dict = {}
    for path in sorted(msg_dir().glob("*.msg")):
        types.update(get_types_from_msg(path.read_text(), f"{MSG_PACKAGE}/msg/{path.stem}"))
    ts.register(types)
    return ts


def msg_names() -> list[str]:
    """Full type names of the ``sysid_msgs`` messages, e.g. ``sysid_msgs/msg/Mode``."""
    return [f"{MSG_PACKAGE}/msg/{p.stem}" for p in sorted(msg_dir().glob("*.msg"))]


def bag_exists(path: str | os.PathLike) -> Path:
    """Return ``path`` as a Path if it looks like a rosbag2 directory or file, else raise."""
    p = Path(path)
    if not p.exists():
        raise BagError(f"bag not found: {p}")
    return p
