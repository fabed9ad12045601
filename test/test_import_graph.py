"""No import cycle inside the sysid_node and notch_filter_node packages (static, via ast), and
no ROS import when a pure module is imported (pure core, thin nodes).

Every import counts, also the ones inside functions (a lazy import hides a cycle, it does not
remove it). ``from pkg import name`` is an edge to ``pkg.name`` when that is a module, else to
``pkg``.
"""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
PACKAGES = [REPO / "src" / "sysid_node" / "sysid_node",
            REPO / "src" / "notch_filter_node" / "notch_filter_node"]
#: The modules that adapt the core to ROS (nodes, message conversion, the executables' entry);
#: every other module of the two packages is pure. ``tools`` (CLIs) may use either.
ROS_ADAPTERS = {"sysid_node.node", "sysid_node.entry", "sysid_node.msg_convert",
                "notch_filter_node.node"}
ROS_PACKAGES = ("rclpy", "rosidl_runtime_py", "sysid_msgs", "diagnostic_msgs", "sensor_msgs",
                "std_msgs", "rcl_interfaces", "builtin_interfaces")


def _modules(roots: list[Path]) -> dict[str, Path]:
    out = {}
    for root in roots:
        for path in root.rglob("*.py"):
            parts = path.relative_to(root.parent).with_suffix("").parts
            name = ".".join(parts[:-1] if parts[-1] == "__init__" else parts)
            out[name] = path
    return out


def import_graph(roots: list[Path]) -> dict[str, set[str]]:
    """Module -> the modules of the same packages it imports."""
    mods = _modules(roots)
    graph: dict[str, set[str]] = {m: set() for m in mods}
    for mod, path in mods.items():
        package = mod if path.name == "__init__.py" else mod.rpartition(".")[0]
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            targets: list[str] = []
            if isinstance(node, ast.Import):
                targets = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom):
                if node.level:
                    base = package.split(".")
                    base = base[: len(base) - node.level + 1]
                    stem = ".".join(base + ([node.module] if node.module else []))
                else:
                    stem = node.module or ""
                targets = [f"{stem}.{a.name}" if f"{stem}.{a.name}" in mods else stem
                           for a in node.names]
            for t in targets:
                while t and t not in mods:  # import a.b.c of a module a.b -> a.b
                    t = t.rpartition(".")[0]
                if t and t != mod:
                    graph[mod].add(t)
    return graph


def cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components with more than one module (Tarjan)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on: set[str] = set()
    out: list[list[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on.add(v)
        for w in sorted(graph[v]):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append(sorted(comp))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return out


def test_no_import_cycle_in_the_node_packages():
    graph = import_graph(PACKAGES)
    assert "sysid_node.pipeline" in graph and "notch_filter_node.node" in graph
    assert "sysid_node.records" in graph["sysid_node.msg_convert"]
    found = cycles(graph)
    assert not found, "import cycles: " + "; ".join(" <-> ".join(c) for c in found)


def test_the_checker_finds_a_lazy_cycle(tmp_path):
    pkg = tmp_path / "pkg"
    (pkg / "sub").mkdir(parents=True)
    (pkg / "__init__.py").write_text("")
    (pkg / "sub" / "__init__.py").write_text("")
    (pkg / "a.py").write_text("from pkg.sub import b\n")
    (pkg / "sub" / "b.py").write_text("def f():\n    from ..a import x\n")
    (pkg / "c.py").write_text("from . import a\n")
    assert cycles(import_graph([pkg])) == [["pkg.a", "pkg.sub.b"]]


def test_pure_modules_import_no_ros():
    """Importing every module but the ROS adapters (and the CLIs) loads no ROS package: the
    numerics, ingest, pipeline, validation and notch design run without rclpy. Lazy imports
    inside functions that only the nodes call are allowed (node_params' ROS side)."""
    pure = sorted(m for m in _modules(PACKAGES)
                  if m not in ROS_ADAPTERS and not m.startswith("sysid_node.tools"))
    assert "sysid_node.core.recursive" in pure and "notch_filter_node.sections" in pure
    code = (
        "import importlib, sys\n"
        f"ROS = {ROS_PACKAGES!r}\n"
        f"for m in {pure!r}:\n"
        "    before = set(sys.modules)\n"
        "    importlib.import_module(m)\n"
        "    ros = sorted(k for k in set(sys.modules) - before if k.split('.')[0] in ROS)\n"
        "    if ros:\n"
        "        print(m, 'imports', ', '.join(ros[:3]))\n"
    )
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert res.returncode == 0, res.stderr[-2000:]
    assert not res.stdout.strip(), res.stdout
