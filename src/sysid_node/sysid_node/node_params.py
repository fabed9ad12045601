"""Node parameters shared by sysid_node and notch_filter_node: the spec of one parameter, the check
of one value, and its ROS side (descriptor, declaration, integer overrides of float parameters).

:class:`ParamSpec` and :func:`check_value` are pure; :func:`descriptor`, :func:`declare` and
:func:`coerce_int_overrides` import rclpy when called (only the nodes call them). Each node keeps
its own table (``params.py``: ``PARAMS``, node-specific checks and cross checks).
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from typing import Any, Literal

Kind = Literal["live", "structural", "read_only"]

#: Vocabulary of both nodes' signal parameters.
SIGNAL_TYPES = ("SignalSample", "SignalBlock", "Imu")
QOS_CHOICES = ("sensor_data", "reliable")
IMU_AXES = ("ax", "ay", "az", "wx", "wy", "wz")
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
