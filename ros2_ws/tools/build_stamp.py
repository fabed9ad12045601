"""Print a hash of the build inputs of one package, so setup rebuilds only what changed.

With ``colcon build --symlink-install`` edits to existing Python files need no rebuild, so for
an ament_python package the inputs are its file list plus the contents of its metadata, launch
and config files; for any other package (the rosidl one) they are the contents of all files.
"""

from __future__ import annotations

import hashlib
import sys
from pathlib import Path

METADATA = {"package.xml", "setup.py", "setup.cfg", "CMakeLists.txt"}


def stamp(pkg_dir: Path, extra: str = "") -> str:
    h = hashlib.sha256(extra.encode())
    python_pkg = (pkg_dir / "setup.py").exists()
    for path in sorted(pkg_dir.rglob("*")):
        rel = path.relative_to(pkg_dir)
        if not path.is_file() or "__pycache__" in rel.parts or path.suffix == ".pyc":
            continue
        h.update(str(rel).encode())
        if (
            not python_pkg
            or rel.name in METADATA
            or rel.parts[0] in {"launch", "config", "resource"}
        ):
            h.update(path.read_bytes())
    return h.hexdigest()[:16]


if __name__ == "__main__":
    print(stamp(Path(sys.argv[1]), sys.argv[2] if len(sys.argv) > 2 else ""))
