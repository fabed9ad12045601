"""ROS 2 parameter files read as a node will read them, with one-line reasons (pure).

rcl silently ignores a misspelt parameter (``forgeting_factor``) or a section whose node name
is misspelt (``sysid_nod:``), and an unparseable file ends ``rclpy.init`` with an RCLError
traceback. :func:`node_values` finds every section that applies to a node (``/**``, ``**``, its
name, ``/its_name`` or ``/namespace/its_name``) and refuses unknown parameters and sections
whose name is close to the node's, each with the closest valid name. Used by the node at
start-up and by ``offline`` (same file, same answer).
"""

from __future__ import annotations

import difflib
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any

#: Parameters every ROS node has (rclpy declares them).
ROS_OWN = ("use_sim_time", "start_type_description_service")


class ParamsFileError(ValueError):
    """A parameter file a node cannot use; ``str(err)`` is a one-line reason."""


def read(path: Path | str) -> dict[str, Any]:
    """The YAML document of a parameter file (a mapping)."""
    import yaml

    path = Path(path)
    try:
        doc = yaml.safe_load(path.read_text()) or {}
    except OSError as err:
        raise ParamsFileError(f"cannot read parameter file {path}: {err.strerror}") from None
    except yaml.YAMLError as err:
        mark = getattr(err, "problem_mark", None)
        where = f" (line {mark.line + 1}, column {mark.column + 1})" if mark else ""
        problem = getattr(err, "problem", None) or "syntax error"
        raise ParamsFileError(f"parameter file {path} is not valid YAML{where}: {problem}") \
            from None
    if not isinstance(doc, dict):
        raise ParamsFileError(f"parameter file {path}: expected 'NODE: ros__parameters: ...'")
    return doc


def _closest(word: str, candidates: Iterable[str]) -> str:
    match = difflib.get_close_matches(word, list(candidates), n=1, cutoff=0.75)
    return f" (did you mean '{match[0]}'?)" if match else ""


def node_values(doc: Mapping[str, Any], node_name: str, names: Iterable[str], path: Any = "",
                allowed: Iterable[str] = ROS_OWN) -> dict[str, Any]:
    """Parameters that apply to ``node_name`` from a parameter file's document; unknown
    parameters (not in ``names`` nor ``allowed``) and near-miss node names raise
    :class:`ParamsFileError` with the closest valid name."""
    names = set(names)
    where = f"parameter file {path}: " if path else ""
    values: dict[str, Any] = {}
    for key, section in doc.items():
        key = str(key)
        last = key.strip("/").split("/")[-1]
        applies = key in ("/**", "**") or last == node_name
        params = section.get("ros__parameters") if isinstance(section, dict) else None
        if not applies:
            if last != node_name and _closest(last, [node_name]):
                raise ParamsFileError(f"{where}section '{key}' matches no node"
                                      f"{_closest(last, [node_name])}")
            continue
        if not isinstance(params, dict):
            raise ParamsFileError(f"{where}section '{key}' has no 'ros__parameters:' mapping")
        values.update(params)
    for k in values:
        if k not in names and k not in allowed:
            raise ParamsFileError(f"{where}unknown parameter '{k}' for {node_name}"
                                  f"{_closest(k, names)}")
    return values


def files_in_args(args: Iterable[str]) -> tuple[list[str], str | None]:
    """``--params-file FILE`` arguments after ``--ros-args``, and a ``__node:=NAME`` remap."""
    files, node = [], None
    args = list(args)
    inside = False
    for i, a in enumerate(args):
        if a == "--ros-args":
            inside = True
        elif a == "--":
            inside = False
        elif inside and a == "--params-file" and i + 1 < len(args):
            files.append(args[i + 1])
        elif inside and a.startswith("__node:="):
            node = a.split(":=", 1)[1]
        elif inside and a in ("-r", "--remap") and i + 1 < len(args) \
                and args[i + 1].startswith("__node:="):
            node = args[i + 1].split(":=", 1)[1]
    return files, node
