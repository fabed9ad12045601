"""Repository-wide pytest hook: which tests may run in parallel.

``ros2_ws/test`` runs the suite in two phases: the pure tests (numerics, CLIs on files) on two
pytest-xdist workers, then the process-level tests alone, one after the other, so that DDS
delivery and the nodes' real-time behaviour are checked on a machine that only runs them (the
stressed ones start their own CPU hogs). A module holding any test marked ``dds`` or ``serial``
goes wholly to the second phase (its module fixtures are computed once).
"""

from __future__ import annotations

import pytest


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    alone = {item.module for item in items
             if item.get_closest_marker("dds") or item.get_closest_marker("serial")}
    for item in items:
        if item.module in alone and not item.get_closest_marker("serial"):
            item.add_marker(pytest.mark.serial)
