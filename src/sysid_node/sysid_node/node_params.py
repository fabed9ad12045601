"""Node parameters shared by sysid_node and notch_filter_node: the spec of one parameter, the check
of one value, and its ROS side (descriptor, declaration, integer overrides of float parameters).

:class:`ParamSpec` and :func:`check_value` are pure; :func:`descriptor`, :func:`declare` and
:func:`coerce_int_overrides` import rclpy when called (only the nodes call them). Each node keeps
its own table (``params.py``: ``PARAMS``, node-specific checks and cross checks).
"""

from __future__ import annotations

import difflib
import math
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any, Literal

Kind = Literal["live", "structural", "read_only"]

#: Vocabulary of both nodes' signal parameters.
SIGNAL_TYPES = ("SignalSample", "SignalBlock", "Imu")
QOS_CHOICES = ("sensor_data", "reliable")
IMU_AXES = ("ax", "ay", "az", "wx", "wy", "wz")
#: Parameters every ROS node has (never unknown).
ROS_PARAMS = ("use_sim_time", "start_type_description_service")
#: Python type -> ROS parameter type name (as ``ros2 param`` prints them).
ROS_TYPE_NAMES = {bool: "bool", int: "integer", float: "double", str: "string"}


@dataclass(frozen=True)
class ParamSpec:
    """One node parameter: its type, default, range (``lo``/``hi`` inclusive) and kind:
    ``live`` (applied at run time), ``structural`` (applied by a rebuild or reset, the caller
    logs a line) or ``read_only`` (start-up only)."""

    name: str
    type: type
    default: Any
    description: str
    kind: Kind = "live"
    lo: float | None = None
    hi: float | None = None
    choices: tuple[str, ...] | None = None
    unit: str = ""


def signal_type_spec(name: str, topic_param: str, kind: Kind) -> ParamSpec:
    """The message-type parameter of a signal topic (SignalSample, SignalBlock or Imu)."""
    return ParamSpec(name, str, "SignalSample", f"Message type of {topic_param}", kind,
                     choices=SIGNAL_TYPES)


def imu_axes_spec(kind: Kind, note: str = "") -> ParamSpec:
    """The ``imu_axes`` parameter (channels taken from sensor_msgs/Imu), ``note`` appended."""
    return ParamSpec("imu_axes", str, "az",
                     "For sensor_msgs/Imu: comma-separated channels among ax,ay,az (linear "
                     "acceleration) and wx,wy,wz (angular velocity)" + note, kind)


def type_name(value_or_type: Any) -> str:
    """ROS and Python type names of a value or Python type: 'double (type float)'."""
    t = value_or_type if isinstance(value_or_type, type) else type(value_or_type)
    return f"{ROS_TYPE_NAMES.get(t, t.__name__)} (type {t.__name__})"


def check_value(spec: ParamSpec, value: Any) -> str:
    """'' if ``value`` fits ``spec`` (type, finite, range, choices), else the reason. An integer
    is accepted for a double parameter."""
    name = spec.name
    if spec.type is float and isinstance(value, int) and not isinstance(value, bool):
        value = float(value)
    if not isinstance(value, spec.type) or (spec.type is int and isinstance(value, bool)):
        return f"{name}: expected {type_name(spec.type)}, got {type_name(value)}"
    if spec.type is float and not math.isfinite(value):
        return f"{name} must be finite, got {value}"
    unit = f" {spec.unit}" if spec.unit else ""
    if spec.lo is not None and value < spec.lo:
        return f"{name}={value} is below the minimum {spec.lo:g}{unit}"
    if spec.hi is not None and value > spec.hi:
        return f"{name}={value} is above the maximum {spec.hi:g}{unit}"
    if spec.choices is not None and value not in spec.choices:
        return f"{name}='{value}' is not one of {', '.join(spec.choices)}"
    return ""


def check(specs: Mapping[str, ParamSpec], name: str, value: Any) -> str:
    """:func:`check_value` of parameter ``name`` of the table ``specs`` ('' if valid)."""
    spec = specs.get(name)
    return f"unknown parameter '{name}'" if spec is None else check_value(spec, value)


def closest(name: str, candidates: Iterable[str]) -> str:
    """" (did you mean 'X'?)" for the closest candidate, or ''."""
    match = difflib.get_close_matches(name, list(candidates), n=1, cutoff=0.6)
    return f" (did you mean '{match[0]}'?)" if match else ""


def unknown_names(specs: Mapping[str, ParamSpec], names: Iterable[str]) -> str:
    """'' unless a name is neither in ``specs`` nor a standard ROS parameter; then the reason
    with the closest valid name."""
    for name in names:
        if name not in specs and name not in ROS_PARAMS and not name.startswith("qos_overrides."):
            return f"unknown parameter '{name}'" + closest(name, specs)
    return ""


def check_params_file(path: str, node_name: str, specs: Mapping[str, ParamSpec],
                      other_nodes: Sequence[str] = ()) -> str:
    """A ROS 2 parameter file as node ``node_name`` reads it: '' when fine, else a one-line
    reason (unreadable, not YAML (with the line), not a mapping, a section named like this node
    but misspelt, an unknown parameter in this node's section, with the closest valid name).
    Sections of ``other_nodes``, of unrelated nodes and wildcard sections (``/**``, ``/**/name``
    for this node is checked) are left to their nodes. Run before ``rclpy.init``, which ends an
    unparseable file with a traceback."""
    import yaml

    try:
        with open(path, encoding="utf-8") as fh:
            doc = yaml.safe_load(fh)
    except OSError as err:
        return f"cannot read parameter file {path}: {err.strerror}"
    except yaml.YAMLError as err:
        mark = getattr(err, "problem_mark", None)
        where = f" at line {mark.line + 1}" if mark is not None else ""
        problem = getattr(err, "problem", None) or "syntax error"
        return f"parameter file {path} is not valid YAML{where}: {problem}"
    if doc is None:
        return ""
    if not isinstance(doc, dict):
        return f"parameter file {path}: expected 'NODE_NAME: ros__parameters: ...' at the top"
    for key, section in doc.items():
        name = str(key).strip("/").split("/")[-1]
        if name in ("**", "*"):
            continue
        if name != node_name:
            if name not in other_nodes and difflib.SequenceMatcher(
                    None, name, node_name).ratio() >= 0.75:
                return (f"parameter file {path}: section '{key}' matches no node "
                        f"(did you mean '{node_name}'?)")
            continue
        params = section.get("ros__parameters") if isinstance(section, dict) else None
        if not isinstance(params, dict):
            return f"parameter file {path}: section '{key}' has no 'ros__parameters:' mapping"
        reason = unknown_names(specs, [str(k) for k in params])
        if reason:
            return f"parameter file {path}: {reason} for {node_name}"
    return ""


def parse_list(text: str) -> list[str]:
    """'ax, az' -> ['ax', 'az']."""
    return [a.strip() for a in str(text).split(",") if a.strip()]


def check_imu_axes(value: str) -> str:
    """'' if ``value`` is a comma-separated list of distinct IMU axes, else the reason."""
    axes = parse_list(value)
    if not axes or any(a not in IMU_AXES for a in axes) or len(set(axes)) != len(axes):
        return f"imu_axes='{value}': use a comma-separated subset of {','.join(IMU_AXES)}"
    return ""


def read_only_changes(specs: Mapping[str, ParamSpec], old: Mapping[str, Any],
                      changes: Mapping[str, Any]) -> str:
    """'' unless ``changes`` alter a read-only parameter; then the reason."""
    ro = [k for k, v in changes.items() if specs[k].kind == "read_only" and v != old[k]]
    return f"{', '.join(ro)} can only be set at start-up" if ro else ""


# ---- ROS side (rclpy imported on use) ----
class ParameterError(ValueError):
    """A parameter could not be declared; ``str(err)`` is a one-line reason."""


def descriptor(spec: ParamSpec, kind_notes: Mapping[str, str]):
    """``rcl_interfaces/ParameterDescriptor`` of ``spec``: description (with the choices and
    ``kind_notes[spec.kind]``), range, read-only flag."""
    from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor

    text = spec.description
    if spec.choices:
        text += f" [{'|'.join(spec.choices)}]"
    text += kind_notes.get(spec.kind, "")
    d = ParameterDescriptor(description=text, read_only=spec.kind == "read_only")
    if spec.type is float:
        d.floating_point_range = [FloatingPointRange(from_value=float(spec.lo),
                                                     to_value=float(spec.hi))]
    elif spec.type is int:
        d.integer_range = [IntegerRange(from_value=int(spec.lo), to_value=int(spec.hi))]
    if spec.choices:
        d.additional_constraints = "one of: " + ", ".join(spec.choices)
    return d


def coerce_int_overrides(node: Any, specs: Mapping[str, ParamSpec]) -> None:
    """Accept ``sample_rate: 100`` (an integer, as users write it) for a double parameter: turn
    the node's integer overrides of float parameters into doubles before they are declared."""
    from rclpy.parameter import Parameter

    overrides = getattr(node, "_parameter_overrides", None)
    if not isinstance(overrides, dict):
        return
    for name, p in list(overrides.items()):
        spec = specs.get(name)
        if spec and spec.type is float and p.type_ == Parameter.Type.INTEGER:
            overrides[name] = Parameter(name, Parameter.Type.DOUBLE, float(p.value))


def check_overrides(node: Any, specs: Mapping[str, ParamSpec]) -> None:
    """The node's start-up values (parameter files, ``-p``): an unknown name (with the closest
    valid one) or a value of the wrong type (naming both types) raises
    :class:`ParameterError` with a one-line reason (rclpy ignores the first and says
    "expected '3' got '4'" for the second)."""
    overrides = getattr(node, "_parameter_overrides", None)
    if not isinstance(overrides, dict):
        return
    reason = unknown_names(specs, overrides)
    if reason:
        raise ParameterError(reason)
    for name, p in overrides.items():
        if name in specs:
            value = p.value
            if specs[name].type is float and isinstance(value, int) and not isinstance(
                    value, bool):
                continue
            if not isinstance(value, specs[name].type) or (
                    specs[name].type is int and isinstance(value, bool)):
                raise ParameterError(check_value(specs[name], value))


def declare(node: Any, specs: Iterable[ParamSpec], kind_notes: Mapping[str, str]) -> dict:
    """Declare every parameter (integer overrides of doubles coerced first) and return
    name -> value; a value rclpy refuses raises :class:`ParameterError` with a one-line reason."""
    from rclpy.exceptions import (
        InvalidParameterTypeException,
        InvalidParameterValueException,
        ParameterException,
    )

    specs = list(specs)
    coerce_int_overrides(node, {s.name: s for s in specs})
    try:
        for spec in specs:
            node.declare_parameter(spec.name, spec.default, descriptor(spec, kind_notes))
    except (InvalidParameterValueException, InvalidParameterTypeException,
            ParameterException) as err:
        raise ParameterError(str(err).splitlines()[0]) from None
    return {s.name: node.get_parameter(s.name).value for s in specs}
