"""Repair the CMake exports of the ROS 2 PyPI wheels so that colcon can build interfaces.

The wheels' exported targets (``share/**/cmake/*.cmake``) hard-code the wheel builder's
Python include directory and numpy include directory. This rewrites both to this
interpreter's paths. Idempotent: a second run changes nothing.
"""

from __future__ import annotations

import sys
import sysconfig
from pathlib import Path

BUILDER_PYTHON_INCLUDE = "/opt/python/cp311-cp311/include/python3.11"
BUILDER_NUMPY_INCLUDE = "/opt/python/cp311-cp311/lib/python3.11/site-packages/numpy/_core/include"


def repair(prefix: Path) -> int:
    """Rewrite builder paths in every exported CMake file under ``prefix/share``."""
    import numpy

    replacements = {
        BUILDER_NUMPY_INCLUDE: numpy.get_include(),
        BUILDER_PYTHON_INCLUDE: sysconfig.get_paths()["include"],
    }
    changed = 0
    for path in (prefix / "share").rglob("*.cmake"):
        text = path.read_text(errors="surrogateescape")
        if "/opt/python/cp311-cp311" not in text:
            continue
        new = text
        for old, repl in replacements.items():
            new = new.replace(old, repl)
        if new != text:
            path.write_text(new, errors="surrogateescape")
            changed += 1
    return changed


def main() -> int:
    prefix = Path(sys.argv[1] if len(sys.argv) > 1 else sys.prefix)
    if not (prefix / "share").is_dir():
        print(f"repair_wheels: {prefix}/share does not exist", file=sys.stderr)
        return 1
    print(f"[setup]   rewrote builder paths in {repair(prefix)} CMake files")
    return 0


if __name__ == "__main__":
    sys.exit(main())
