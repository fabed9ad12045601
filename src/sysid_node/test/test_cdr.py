"""Serialized bursts -> arrays (cdr.decode_burst, msg_convert.serialized_burst_to_blocks)
against rclpy's own serializer and deserializer, for every signal type and byte layout."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("rclpy")

from rclpy.serialization import deserialize_message, serialize_message

from sysid_node import cdr
from sysid_node import msg_convert as mc

T0 = 1_700_000_123_456_789_012


def _name(rng) -> str:
    return "".join(rng.choice(list("abcxyz_0[]/^2"), int(rng.integers(0, 12))))


def _layout(rng, kind: str) -> dict:
    """A random byte layout: frame_id length (alignment), channel count, names or none,
    samples per block, period (also the odd and invalid ones msg_convert must reject)."""
    width = int(rng.integers(0, 8))
    lay = {"frame": "f" * int(rng.integers(0, 10)), "width": width,
           "names": [_name(rng) for _ in range(width)] if rng.random() < 0.5 else []}
    if kind == "SignalBlock":
        lay["rows"] = int(rng.integers(0, 6))
        lay["count"] = width if rng.random() < 0.85 else int(rng.integers(0, 9))
        lay["period"] = float(rng.choice([1e-3, 1 / 3, 0.01, 0.0, -1e-3, np.nan, np.inf]))
    return lay


def _message(rng, kind: str, lay: dict, k: int):
    stamp = T0 + k * 1_000_003 + int(rng.integers(-5, 5))
    if kind == "SignalSample":
        m = mc.signal_sample_msg(stamp, rng.standard_normal(lay["width"]), lay["names"])
    else:
        m = mc.signal_block_msg(stamp, lay["period"],
                                rng.standard_normal((lay["rows"], max(lay["width"], 1))),
                                lay["names"])
        m.data = m.data[: lay["rows"] * lay["width"]]
        m.channel_count = lay["count"]
    m.header.frame_id = lay["frame"]
    return m


def _burst(rng, kind: str, n_layouts: int) -> list:
    """Messages in runs of ``n_layouts`` random layouts (a burst that changes layout)."""
    msgs = []
    for _ in range(n_layouts):
        lay = _layout(rng, kind)
        msgs += [_message(rng, kind, lay, len(msgs) + k) for k in range(int(rng.integers(1, 9)))]
    return msgs


def _assert_same(got, want) -> None:
    (g_blocks, g_err), (w_blocks, w_err) = got, want
    assert len(g_err) == len(w_err)
    assert len(g_blocks) == len(w_blocks)
    for (gt, gv, gn), (wt, wv, wn) in zip(g_blocks, w_blocks, strict=True):
        np.testing.assert_allclose(gt, wt, rtol=0, atol=1)  # [ns]
        assert gv.shape == wv.shape
        np.testing.assert_allclose(gv, wv, rtol=1e-15, atol=0)
        assert gn == wn


@pytest.mark.parametrize("kind", ["SignalSample", "SignalBlock"])
@pytest.mark.parametrize("seed", range(40))
def test_serialized_bursts_decode_as_rclpy_deserializes_them(kind, seed):
    rng = np.random.default_rng(seed)
    msgs = _burst(rng, kind, 1 if seed % 2 else int(rng.integers(2, 4)))
    raws = [serialize_message(m) for m in msgs]
    back = [deserialize_message(r, type(msgs[0])) for r in raws]
    _assert_same(mc.serialized_burst_to_blocks(raws, kind), mc.burst_to_blocks(back, kind))


@pytest.mark.parametrize("kind", ["SignalSample", "SignalBlock"])
def test_one_layout_takes_the_vectorised_path(kind):
    rng = np.random.default_rng(7)
    for _ in range(30):
        lay = _layout(rng, kind)
        if kind == "SignalBlock":  # valid blocks (the others are the per-message path's)
            if not lay["width"]:
                lay.update(width=1, names=[])
            lay.update(count=lay["width"], period=1e-3)
        msgs = [_message(rng, kind, lay, k) for k in range(int(rng.integers(1, 30)))]
        got = cdr.decode_burst([serialize_message(m) for m in msgs], kind)
        assert got is not None, lay
        _assert_same(([got], []), mc.burst_to_blocks(msgs, kind))


def test_other_bytes_are_left_to_the_per_message_path():
    rng = np.random.default_rng(1)
    lay = _layout(rng, "SignalSample")
    lay["width"], lay["names"] = 2, []
    raws = [serialize_message(_message(rng, "SignalSample", lay, k)) for k in range(3)]
    renamed = serialize_message(mc.signal_sample_msg(T0, [1.0, 2.0], ["p", "q"]))
    assert cdr.decode_burst(raws + [renamed], "SignalSample") is None  # other names
    assert cdr.decode_burst([raws[0][:10]], "SignalSample") is None  # truncated
    assert cdr.decode_burst([b"\x00\x00\x00\x00" + raws[0][4:]], "SignalSample") is None
    assert cdr.decode_burst(raws, "Imu") is None
    assert cdr.decode_burst([], "SignalSample") is None
    # a truncated message among good ones: dropped with a reason, the others kept
    blocks, errors = mc.serialized_burst_to_blocks(raws[:2] + [raws[2][:13]], "SignalSample")
    assert len(errors) == 1 and "cannot deserialize" in errors[0]
    assert sum(len(b[0]) for b in blocks) == 2


def test_imu_bursts_go_through_rclpy():
    from sensor_msgs.msg import Imu

    msgs = []
    for k in range(5):
        m = Imu()
        m.header.stamp.sec, m.header.stamp.nanosec = mc.split_ns(T0 + k * 10**7)
        m.linear_acceleration.z = 0.5 * k
        m.angular_velocity.x = -float(k)
        msgs.append(m)
    raws = [serialize_message(m) for m in msgs]
    _assert_same(mc.serialized_burst_to_blocks(raws, "Imu", ["az", "wx"]),
                 mc.burst_to_blocks(msgs, "Imu", ["az", "wx"]))
