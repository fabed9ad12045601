"""The shipped Foxglove (JSON) and PlotJuggler (XML) layouts are well formed and every plotted
path names a real field of the message its topic carries.

Foxglove layout: ``configById`` (panel id ``Type!name`` -> config), a mosaic ``layout`` tree
(``{direction: row|column, first, second, splitPercentage}`` or a panel id) using every panel
exactly once, message paths ``/topic.field[index].field``. PlotJuggler layout: ``root >
tabbed_widget > Tab > Container > DockSplitter`` (``count`` children, ``sizes`` summing to 1) >
``DockArea > plot > curve``, series named ``/topic/field[index]/field`` and, for
``diagnostic_msgs/DiagnosticArray``, ``/diagnostics/{hardware_id}/{status name}/{key}``.
"""

from __future__ import annotations

import json
import re
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest

from sysid_node import bag_io

REPO = Path(__file__).resolve().parents[1]
LAYOUTS = REPO / "src" / "notch_filter_node" / "layouts"
TOPIC_TYPES = {
    "/vibration": "sysid_msgs/msg/SignalSample",
    "/vibration_filtered": "sysid_msgs/msg/SignalSample",
    "/modal_estimate": "sysid_msgs/msg/ModalEstimate",
    "/notch_bank": "sysid_msgs/msg/NotchBank",
    "/diagnostics": "diagnostic_msgs/msg/DiagnosticArray",
}
NUMERIC = {"float32", "float64", "int8", "uint8", "int16", "uint16", "int32", "uint32",
           "int64", "uint64", "bool"}
#: How each node fills DiagnosticStatus at the root namespace: (hardware_id, name, source file).
DIAGNOSTIC_STATUS = {
    "sysid_node": ("/vibration", "sysid_node: identification",
                   REPO / "src/sysid_node/sysid_node/node.py"),
    "notch_filter_node": ("/notch_filter_node", "notch_filter_node: notch bank",
                          REPO / "src/notch_filter_node/notch_filter_node/node.py"),
}
FOXGLOVE_PANELS = {"Plot", "DiagnosticSummary", "DiagnosticStatusPanel", "RawMessages",
                   "StateTransitions"}
FIELD = re.compile(r"^([A-Za-z_]\w*)(?:\[(\d+)\])?$")


def field_error(msgtype: str, fields: list[str]) -> str:
    """'' when ``fields`` (e.g. ['modes[0]', 'frequency']) lead to a number in ``msgtype``."""
    defs = bag_io.typestore().fielddefs
    current = msgtype
    for k, token in enumerate(fields):
        m = FIELD.match(token)
        if not m:
            return f"bad field token {token!r}"
        name, index = m.group(1), m.group(2)
        entries = dict(defs[current][1])
        if name not in entries:
            return f"{current} has no field {name!r} (fields: {', '.join(entries)})"
        kind, detail = entries[name]
        if kind.name in ("SEQUENCE", "ARRAY"):
            if index is None:
                return f"{current}.{name} is an array: give an index"
            kind, detail = detail[0]
        elif index is not None:
            return f"{current}.{name} is not an array"
        last = k == len(fields) - 1
        if kind.name == "NAME":
            if last:
                return f"{current}.{name} is a message, not a number"
            current = detail
        elif not last:
            return f"{current}.{name} has no sub-fields"
        elif detail[0] not in NUMERIC:
            return f"{current}.{name} is {detail[0]}, not a number"
    return ""


def foxglove_path_error(path: str) -> str:
    topic, _, rest = path.partition(".")
    if topic not in TOPIC_TYPES:
        return f"unknown topic {topic}"
    return field_error(TOPIC_TYPES[topic], rest.split(".")) if rest else "no field"


def plotjuggler_curve_error(curve: str) -> str:
    for topic, msgtype in TOPIC_TYPES.items():
        if not curve.startswith(topic + "/"):
            continue
        rest = curve[len(topic) + 1:]
        if msgtype.startswith("diagnostic_msgs"):
            for hw, name, source in DIAGNOSTIC_STATUS.values():
                prefix = f"{hw}/{name}/"
                if rest.startswith(prefix):
                    key = rest[len(prefix):]
                    ok = f'"{key}"' in source.read_text()
                    return "" if ok else f"{source.name} publishes no key {key!r}"
            return f"no node publishes the status {rest!r}"
        return field_error(msgtype, rest.split("/"))
    return f"unknown topic in {curve}"


def _mosaic_leaves(node, errors: list[str]) -> list[str]:
    if isinstance(node, str):
        return [node]
    if not isinstance(node, dict) or node.get("direction") not in ("row", "column"):
        errors.append(f"mosaic node without direction row/column: {node!r}")
        return []
    if not 0 < node.get("splitPercentage", 50) < 100:
        errors.append(f"splitPercentage out of (0, 100): {node['splitPercentage']}")
    return _mosaic_leaves(node.get("first"), errors) + _mosaic_leaves(node.get("second"), errors)


def foxglove_errors(doc: dict) -> list[str]:
    errors: list[str] = []
    for key, kind in (("configById", dict), ("globalVariables", dict), ("userNodes", dict),
                      ("playbackConfig", dict)):
        if not isinstance(doc.get(key), kind):
            errors.append(f"{key} missing or not an object")
    leaves = _mosaic_leaves(doc.get("layout"), errors)
    panels = doc.get("configById", {})
    if sorted(leaves) != sorted(panels):
        errors.append(f"layout shows {sorted(leaves)}, configById has {sorted(panels)}")
    for pid, cfg in panels.items():
        kind, sep, name = pid.partition("!")
        if not sep or not name or kind not in FOXGLOVE_PANELS:
            errors.append(f"panel id {pid!r} is not Type!name with a known type")
        if kind == "Plot":
            if not cfg.get("paths"):
                errors.append(f"{pid}: no paths")
            for p in cfg.get("paths", []):
                if not isinstance(p.get("enabled"), bool) or p.get("timestampMethod") not in (
                        "receiveTime", "headerStamp"):
                    errors.append(f"{pid}: path {p} needs enabled and timestampMethod")
                err = foxglove_path_error(p.get("value", ""))
                if err:
                    errors.append(f"{pid}: {p.get('value')}: {err}")
        elif kind in ("DiagnosticSummary", "DiagnosticStatusPanel"):
            if cfg.get("topicToRender") != "/diagnostics":
                errors.append(f"{pid}: topicToRender is not /diagnostics")
    return errors


def plotjuggler_errors(root: ET.Element) -> list[str]:
    errors: list[str] = []
    if root.tag != "root" or root.find("tabbed_widget/Tab/Container") is None:
        return ["not root > tabbed_widget > Tab > Container"]
    for split in root.iter("DockSplitter"):
        children = [c for c in split if c.tag in ("DockSplitter", "DockArea")]
        sizes = [float(s) for s in split.get("sizes", "").split(";") if s]
        if split.get("orientation") not in ("-", "|") or int(split.get("count", -1)) != len(
                children) or len(sizes) != len(children) or abs(sum(sizes) - 1) > 1e-6:
            errors.append(f"DockSplitter count/sizes/orientation inconsistent: {split.attrib}")
    curves = [c.get("name", "") for c in root.iter("curve")]
    if not curves or any(area.find("plot") is None for area in root.iter("DockArea")):
        errors.append("a DockArea without a plot, or no curve at all")
    errors += [f"{c}: {e}" for c in curves if (e := plotjuggler_curve_error(c))]
    used = {t for c in curves for t in TOPIC_TYPES if c.startswith(t + "/")}
    for plugin in root.iter("plugin"):
        selected = plugin.find("selected_topics")
        if selected is not None and not used <= set(selected.get("value", "").split(";")):
            errors.append(f"plugin {plugin.get('ID')} does not subscribe to {sorted(used)}")
    return errors


def test_foxglove_layout_is_valid_and_plots_the_suite():
    doc = json.loads((LAYOUTS / "notch_suite.foxglove.json").read_text())
    assert foxglove_errors(doc) == []
    paths = [p["value"] for c in doc["configById"].values() for p in c.get("paths", [])]
    for wanted in ("/vibration.", "/vibration_filtered.", ".frequency", ".damping_ratio",
                   "/notch_bank.notches[0].center_frequency"):
        assert any(wanted in p for p in paths), wanted
    assert any(k.startswith("DiagnosticSummary!") for k in doc["configById"])


def test_plotjuggler_layout_is_valid_and_plots_the_suite():
    root = ET.parse(LAYOUTS / "notch_suite.plotjuggler.xml").getroot()
    assert plotjuggler_errors(root) == []
    curves = [c.get("name") for c in root.iter("curve")]
    for wanted in ("/vibration/values[0]", "/vibration_filtered/values[0]", "/frequency",
                   "/damping_ratio", "/notch_bank/notches[0]/center_frequency", "/diagnostics/"):
        assert any(wanted in c for c in curves), wanted


@pytest.mark.parametrize(
    ("path", "fragment"),
    [("/modal_estimate.modes.frequency", "give an index"), ("/vibration.values[0].x", "no sub"),
     ("/modal_estimate.modes[0]", "a message"), ("/notch_bank.notches[0].centre", "no field"),
     ("/imu.linear_acceleration.z", "unknown topic"), ("/modal_estimate.health_reason", "string")],
)
def test_the_checks_catch_wrong_paths(path, fragment):
    assert fragment in foxglove_path_error(path)
    pj = path.replace(".", "/")
    assert plotjuggler_curve_error(pj), pj
    assert "no key" in plotjuggler_curve_error(
        "/diagnostics//vibration/sysid_node: identification/no_such_key")
