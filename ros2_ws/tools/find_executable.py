"""Find a package executable through the ament index and run it, as ``ros2 run`` does.

``ros2 run PKG EXE`` looks the package up in the ament resource index of every prefix on
``AMENT_PREFIX_PATH`` and runs ``<prefix>/lib/<PKG>/<EXE>``. This does the same, then replaces
itself with the executable so that signals and the exit code are the executable's own.
"""

from __future__ import annotations

import os
import sys
from pathlib import Path

from ament_index_python.packages import PackageNotFoundError, get_package_prefix


def find(package: str, executable: str) -> Path:
    try:
        prefix = Path(get_package_prefix(package))
    except PackageNotFoundError:
        msg = f"run: error: package '{package}' not found (built? run ros2_ws/setup)"
        raise SystemExit(msg) from None
    lib = prefix / "lib" / package
    path = lib / executable
    if not (path.is_file() and os.access(path, os.X_OK)):
        found = (
            sorted(p.name for p in lib.iterdir() if os.access(p, os.X_OK)) if lib.is_dir() else []
        )
        raise SystemExit(
            f"run: error: no executable '{executable}' in package '{package}'"
            f" (available: {', '.join(found) or 'none'})"
        )
    return path


def main() -> None:
    args = sys.argv[1:]
    if args[:1] == ["--exec"]:
        args = args[1:]
    if len(args) < 2:
        raise SystemExit("usage: ros2_ws/run PKG EXECUTABLE [ARGS...]")
    path = find(args[0], args[1])
    os.execv(str(path), [str(path), *args[2:]])


if __name__ == "__main__":
    main()
