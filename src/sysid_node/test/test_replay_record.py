"""replay -> record over real DDS: the recorded bag holds the same messages, byte for byte."""

from __future__ import annotations

import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from sysid_node.process_group import stop_group

from sysid_node import bag_io

T0 = 1_700_000_000.0
PY = [sys.executable, "-m"]


def _env() -> dict[str, str]:
    env = dict(os.environ)
    env["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    env.setdefault("ROS_DOMAIN_ID", str(10 + os.getpid() % 80))
    return env


def _start(args: list[str], log: Path) -> subprocess.Popen:
    return subprocess.Popen(
        [*PY, *args],
        stdout=log.open("w"),
        stderr=subprocess.STDOUT,
        env=_env(),
        start_new_session=True,
    )


def _run(args: list[str], timeout: float = 60.0) -> subprocess.CompletedProcess:
    return subprocess.run([*PY, *args], capture_output=True, text=True, timeout=timeout, env=_env())


def _source_bag(path: Path) -> Path:
    """A 2 s bag: SignalSample at 100 Hz on two topics, SignalBlock, one ModalEstimate."""
    rng = np.random.default_rng(7)
    t = T0 + np.arange(200) / 100.0
    ts = bag_io.typestore()
    header = ts.types["std_msgs/msg/Header"]
    block = ts.types[bag_io.SIGNAL_BLOCK]
    est = ts.types["sysid_msgs/msg/ModalEstimate"]
    mode = ts.types["sysid_msgs/msg/Mode"]
    blocks = [
        (
            int(round((T0 + 0.1 * k) * 1e9)),
            block(
                header=header(stamp=bag_io.stamp_msg(T0 + 0.1 * k), frame_id="b"),
                sample_period=0.01,
                channel_count=3,
                data=rng.standard_normal(30),
                channel_names=["x", "y", "z"],
            ),
        )
        for k in range(20)
    ]
    estimate = est(
        header=header(stamp=bag_io.stamp_msg(T0 + 1.0), frame_id=""),
        modes=[
            mode(
                id=3,
                status=1,
                frequency=2.0,
                frequency_std=0.01,
                damping_ratio=0.02,
                damping_ratio_std=0.001,
                amplitude=0.5,
                age=1.0,
                shape_magnitude=np.array([1.0, 0.5]),
                shape_phase=np.array([0.0, 3.1]),
            )
        ],
        model_order=4,
        block_rows=10,
        forgetting_factor=0.99,
        sample_rate=100.0,
        prediction_error_rms=float("nan"),
        prediction_error_rms_per_channel=np.array([0.1, float("nan")]),
        converged=True,
        samples_used=100,
        health=1,
        health_reason="outliers rejected",
        band_min=0.0,
        band_max=40.0,
        scheduling_value=float("nan"),
        predicted_modes=[],
    )
    return bag_io.write_bag(
        path,
        {
            "/vibration": (
                bag_io.SIGNAL_SAMPLE,
                bag_io.signal_samples(t, rng.standard_normal((200, 2)), ["a", "b"]),
            ),
            "/excitation": (
                bag_io.SIGNAL_SAMPLE,
                bag_io.signal_samples(t, rng.standard_normal((200, 1)), ["u"]),
            ),
            "/block": (bag_io.SIGNAL_BLOCK, blocks),
            "/modal_estimate": (
                "sysid_msgs/msg/ModalEstimate",
                [(int((T0 + 1.0) * 1e9), estimate)],
            ),
        },
        qos={"/modal_estimate": [bag_io.make_qos(transient_local=True, depth=1)]},
    )


def _raw(bag: Path, topic: str) -> list[bytes]:
    """Serialized messages of ``topic``, padded to 4 bytes as DDS delivers them."""
    return [raw + b"\0" * (-len(raw) % 4) for _, _, raw in bag_io.iter_messages(bag, [topic])]


@pytest.mark.dds
@pytest.mark.parametrize("storage", ["mcap", "sqlite3"])
def test_replay_into_record_is_byte_exact(tmp_path: Path, storage: str) -> None:
    src = _source_bag(tmp_path / "src")
    out = tmp_path / "rec"
    topics = ["/vibration", "/excitation", "/block", "/modal_estimate"]
    rec = _start(
        [
            "sysid_node.tools.record",
            *topics,
            "/clock",
            "--type",
            "/clock=rosgraph_msgs/msg/Clock",
            "-o",
            str(out),
            "--storage",
            storage,
        ],
        tmp_path / "record.log",
    )
    try:
        t0 = time.monotonic()
        rep = _run(["sysid_node.tools.replay", str(src), "--rate", "2", "--clock"])
        took = time.monotonic() - t0
        assert rep.returncode == 0, rep.stderr
        assert "published 421 messages" in rep.stdout
        time.sleep(0.5)
    finally:
        assert stop_group(rec) == 0, (tmp_path / "record.log").read_text()
    log = (tmp_path / "record.log").read_text()
    assert "/vibration 200" in log and "/modal_estimate 1" in log
    assert took > 0.9  # 2 s of data at 2x, paced, not dumped
    for topic in topics:
        assert _raw(out, topic) == _raw(src, topic), topic
    got = bag_io.read_signals(out, ["/vibration", "/block"])
    ref = bag_io.read_signals(src, ["/vibration", "/block"])
    for topic in got:
        np.testing.assert_array_equal(got[topic].values, ref[topic].values)
        np.testing.assert_array_equal(got[topic].t, ref[topic].t)
    # /clock followed the bag's log time
    clock = [
        bag_io.typestore().deserialize_cdr(r, "rosgraph_msgs/msg/Clock")
        for r in _raw(out, "/clock")
    ]
    assert len(clock) >= 200
    assert clock[-1].clock.sec == int(T0 + 1.99)
    # the latched estimate was recorded with a transient-local QoS
    meta = (out / "metadata.yaml").read_text().lower()
    assert "transient_local" in meta or "durability: 1" in meta


@pytest.mark.dds
def test_topic_selection_and_record_duration(tmp_path: Path) -> None:
    src = _source_bag(tmp_path / "src")
    out = tmp_path / "rec"
    rec = _start(
        [
            "sysid_node.tools.record",
            "/excitation",
            "/vibration",
            "--type",
            "/excitation=sysid_msgs/SignalSample",
            "--type",
            "/vibration=sysid_msgs/msg/SignalSample",
            "-o",
            str(out),
            "--duration",
            "7",
        ],
        tmp_path / "record.log",
    )
    try:
        rep = _run(
            ["sysid_node.tools.replay", "--bag", str(src), "--rate", "4", "--topics", "/excitation"]
        )
        assert rep.returncode == 0, rep.stderr
        rec.wait(timeout=20)  # ends by itself after --duration
    finally:
        stop_group(rec)
    assert rec.returncode == 0
    assert _raw(out, "/excitation") == _raw(src, "/excitation")
    assert bag_io.list_topics(out)["/vibration"][1] == 0


@pytest.mark.dds
def test_namespaced_record_and_remapped_replay(tmp_path: Path) -> None:
    """record resolves relative names in its namespace (--ros-args -r __ns:=/left_wing) and
    stores the full names; replay --remap publishes a bag topic under another name."""
    src = _source_bag(tmp_path / "src")
    out = tmp_path / "rec"
    rec = _start(
        ["sysid_node.tools.record", "vibration", "--type", "vibration=sysid_msgs/SignalSample",
         "-o", str(out), "--duration", "7", "--ros-args", "-r", "__ns:=/left_wing"],
        tmp_path / "record.log",
    )
    try:
        rep = _run(["sysid_node.tools.replay", "--bag", str(src), "--rate", "4", "--topics",
                    "/vibration", "--remap", "/vibration:=/left_wing/vibration"])
        assert rep.returncode == 0, rep.stderr
        assert "/left_wing/vibration 200" in rep.stdout
        rec.wait(timeout=20)
    finally:
        stop_group(rec)
    assert rec.returncode == 0, (tmp_path / "record.log").read_text()
    assert list(bag_io.list_topics(out)) == ["/left_wing/vibration"]
    assert _raw(out, "/left_wing/vibration") == _raw(src, "/vibration")
    bad = _run(["sysid_node.tools.replay", "--bag", str(src), "--remap", "/vibration:=a//b"])
    assert bad.returncode != 0 and "empty name token" in bad.stderr


@pytest.mark.parametrize(
    ("args", "needle"),
    [
        (["sysid_node.tools.replay", "/no/such/bag"], "bag not found"),
        (["sysid_node.tools.replay", "{tmp}"], "metadata.yaml"),
        (["sysid_node.tools.replay", "{src}", "--topics", "/airspeed"], "available: /block"),
        (["sysid_node.tools.record", "/x", "-o", "{src}"], "already exists"),
        # -o under a regular file (#13 item 10): says which path is a file
        (["sysid_node.tools.record", "/x", "-o", "{src}/metadata.yaml/out"],
         "metadata.yaml is a file, not a directory"),
        (
            ["sysid_node.tools.record", "/x", "--type", "/x=foo_msgs/msg/Bar", "-o", "{tmp}/n"],
            "foo_msgs",
        ),
    ],
)
def test_bad_input_gives_one_line(tmp_path: Path, args: list[str], needle: str) -> None:
    src = _source_bag(tmp_path / "src")
    args = [a.format(tmp=tmp_path, src=src) for a in args]
    res = _run(args, timeout=30)
    assert res.returncode != 0
    lines = res.stderr.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in res.stderr, res.stderr
    assert needle in lines[0]


def test_truncated_bag_one_line(tmp_path: Path) -> None:
    src = _source_bag(tmp_path / "src")
    (data,) = src.glob("*.mcap")
    raw = data.read_bytes()
    data.write_bytes(raw[: len(raw) // 3])
    res = _run(["sysid_node.tools.replay", str(src), "--wait-subscribers", "0"], timeout=30)
    assert res.returncode != 0
    assert len(res.stderr.strip().splitlines()) == 1, res.stderr


@pytest.mark.dds
def test_loop_with_sensor_qos_until_sigint(tmp_path: Path) -> None:
    src = _source_bag(tmp_path / "src")
    out = tmp_path / "rec"
    rec = _start(["sysid_node.tools.record", "/vibration", "-o", str(out)], tmp_path / "rec.log")
    rep = _start(
        [
            "sysid_node.tools.replay",
            str(src),
            "--rate",
            "4",
            "--loop",
            "--qos",
            "sensor",
            "--topics",
            "/vibration",
        ],
        tmp_path / "replay.log",
    )
    try:
        deadline = time.monotonic() + 20.0
        while "recording /vibration" not in (tmp_path / "rec.log").read_text():
            assert time.monotonic() < deadline, "record never subscribed"
            time.sleep(0.1)
        time.sleep(3.0)  # 0.5 s per pass
        assert rep.poll() is None, (tmp_path / "replay.log").read_text()
    finally:
        assert stop_group(rep) == 0
        assert stop_group(rec) == 0
    line = (tmp_path / "replay.log").read_text().strip().splitlines()[-1]
    assert int(line.split("published ")[1].split()[0]) > 400  # more than two passes
    assert "best effort" in (tmp_path / "rec.log").read_text()
    assert bag_io.list_topics(out)["/vibration"][1] > 200
