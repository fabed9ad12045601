"""Every sysid_msgs message round-trips through real DDS and through rosbag2 (mcap and sqlite3).

Messages are filled generically from their field types (so a new field is covered too), with
NaN in floats, empty and non-empty sequences and nested messages. The bag round-trip crosses
implementations: rclpy serializes, rosbags (typestore built from the .msg files) writes, reads
and deserializes, and the rosbags serialization is read back by rclpy.
"""

from __future__ import annotations

import dataclasses
import math
import os
import time
from pathlib import Path

import numpy as np
import pytest
from sysid_node.tools import msg_class

from sysid_node import bag_io

rclpy = pytest.importorskip("rclpy")
from rclpy.serialization import deserialize_message, serialize_message  # noqa: E402

TYPES = bag_io.msg_names()


def test_all_message_types_found() -> None:
    names = {t.rsplit("/", 1)[1] for t in TYPES}
    assert {"ModalEstimate", "Mode", "Notch", "NotchBank", "SignalBlock", "SignalSample"} <= names


def _fill(msg, seed: int):
    """Set every field of an rclpy message from its declared type (recursively)."""
    rng = np.random.default_rng(seed)
    for k, (name, typ) in enumerate(msg.get_fields_and_field_types().items()):
        setattr(msg, name, _value(getattr(msg, name), typ, rng, k))
    return msg


def _scalar(typ: str, rng: np.random.Generator, k: int):
    if typ in ("double", "float"):
        return float("nan") if k % 4 == 3 else float(rng.normal() * 10 ** int(rng.integers(-3, 4)))
    if typ == "boolean":
        return bool(k % 2)
    if typ.startswith("uint") or typ.startswith("int") or typ in ("octet", "char"):
        bits = 8 if typ in ("octet", "char") else int(typ.lstrip("uint"))
        return int(rng.integers(0, 2 ** min(bits - 1, 31)))
    if typ.startswith("string"):
        return f"ch_{k}[m/s^2] é"
    return None


def _value(current, typ: str, rng: np.random.Generator, k: int):
    if typ.startswith("sequence<"):
        inner = typ[len("sequence<") : -1].split(",")[0]
        n = int(rng.integers(2, 5))
        if inner in ("double", "float"):
            arr = rng.normal(size=n)
            arr[0] = float("nan")
            return arr.tolist() if not isinstance(current, np.ndarray) else arr
        items = [_value(None, inner, rng, k + i) for i in range(n)]
        return items
    s = _scalar(typ, rng, k)
    if s is not None:
        return s
    cls = msg_class(typ)  # nested message, e.g. std_msgs/Header or sysid_msgs/Mode
    return _fill(cls(), int(rng.integers(0, 2**31)))


def _plain(x):
    """rclpy or rosbags message -> nested dicts/lists of plain values (NaN as the string 'nan')."""
    if hasattr(x, "get_fields_and_field_types"):  # rclpy
        return {n: _plain(getattr(x, n)) for n in x.get_fields_and_field_types()}
    if hasattr(x, "__dataclass_fields__"):  # rosbags
        return {
            f.name: _plain(getattr(x, f.name))
            for f in dataclasses.fields(x)
            if f.name[0] != "_" and not f.name.isupper()  # not __msgtype__, not constants
        }
    if isinstance(x, (list, tuple, np.ndarray)) or type(x).__name__ == "array":
        return [_plain(v) for v in x]
    if isinstance(x, (float, np.floating)):
        return "nan" if math.isnan(x) else float(x)
    if isinstance(x, (bool, np.bool_)):
        return bool(x)
    if isinstance(x, (int, np.integer)):
        return int(x)
    return x


def _equal(a, b, what: str) -> None:
    pa, pb = _plain(a), _plain(b)
    assert pa == pb, what


@pytest.fixture(scope="module")
def messages() -> dict[str, object]:
    return {t: _fill(msg_class(t)(), seed=i) for i, t in enumerate(TYPES)}


def test_fill_is_not_trivial(messages: dict[str, object]) -> None:
    est = messages["sysid_msgs/msg/ModalEstimate"]
    assert len(est.modes) >= 2 and len(est.modes[0].shape_magnitude) >= 2
    assert est.header.frame_id and est.header.stamp.sec > 0
    assert math.isnan(est.modes[0].shape_phase[0])


@pytest.mark.parametrize("storage", ["mcap", "sqlite3"])
def test_bag_round_trip(tmp_path: Path, storage: str, messages: dict[str, object]) -> None:
    path = tmp_path / "bag"
    with bag_io.BagWriter(path, storage=storage) as w:
        for i, (t, msg) in enumerate(messages.items()):
            topic = "/" + t.rsplit("/", 1)[1].lower()
            w.add_topic(topic, t)
            w.write_raw(topic, 1_000 + i, serialize_message(msg))
    ts = bag_io.typestore()
    seen = 0
    for conn, _, raw in bag_io.iter_messages(path):
        msg = messages[conn.msgtype]
        # no byte comparison with a fresh serialize_message: rclpy leaves CDR alignment padding
        # uninitialised (e.g. after NotchBank.fallback_active), so equal messages can differ there
        back = ts.deserialize_cdr(raw, conn.msgtype)  # rosbags reads what rclpy wrote
        _equal(msg, back, conn.msgtype)
        again = deserialize_message(bytes(ts.serialize_cdr(back, conn.msgtype)), type(msg))
        _equal(msg, again, conn.msgtype)  # rclpy reads what rosbags wrote
        seen += 1
    assert seen == len(messages)


def test_dds_round_trip(messages: dict[str, object]) -> None:
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.qos import QoSProfile, ReliabilityPolicy

    os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    ctx = rclpy.Context()
    rclpy.init(context=ctx, domain_id=int(os.environ.get("ROS_DOMAIN_ID", "0") or 0))
    try:
        talker = rclpy.create_node("iface_talker", context=ctx)
        listener = rclpy.create_node("iface_listener", context=ctx)
        ex = SingleThreadedExecutor(context=ctx)
        ex.add_node(talker)
        ex.add_node(listener)
        qos = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
        got: dict[str, object] = {}
        pubs = {}
        for t, msg in messages.items():
            topic = "/iface_test/" + t.rsplit("/", 1)[1].lower()
            pubs[t] = talker.create_publisher(type(msg), topic, qos)
            listener.create_subscription(type(msg), topic, lambda m, t=t: got.setdefault(t, m), qos)
        deadline = time.monotonic() + 10.0
        while time.monotonic() < deadline and any(
            p.get_subscription_count() == 0 for p in pubs.values()
        ):
            ex.spin_once(timeout_sec=0.05)
        for t, p in pubs.items():
            p.publish(messages[t])
        deadline = time.monotonic() + 10.0
        while time.monotonic() < deadline and len(got) < len(messages):
            ex.spin_once(timeout_sec=0.05)
        assert set(got) == set(messages)
        for t, msg in messages.items():
            _equal(msg, got[t], t)
        ex.shutdown()
        talker.destroy_node()
        listener.destroy_node()
    finally:
        rclpy.shutdown(context=ctx)
