"""End to end over real DDS: ``replay`` of the paper-example bag into a running ``sysid_node``,
``record`` capturing ``/modal_estimate``; the recorded estimates meet the core's accuracy figures
(2 and 4 Hz within 2 % by 2 s, 6 Hz within 1.5 s of its appearance at 20 s) and equal those of
the ``offline`` tool on the same bag. Also the offline command line on good and bad bags.
"""

from __future__ import annotations

import json
import os
import subprocess
import time
from pathlib import Path

import numpy as np
import pytest
from sysid_node.process_group import stop_group
from sysid_node.tools import offline

from sysid_node import bag_io
from sysid_node import msg_convert as mc

REPO = Path(__file__).resolve().parents[1]
RUN = REPO / "ros2_ws" / "run"
SHIPPED_BAG = REPO / "bags" / "paper_example"


def _env() -> dict[str, str]:
    env = dict(os.environ)
    env["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    env.setdefault("ROS_DOMAIN_ID", str(10 + os.getpid() % 80))
    return env


def _start(args: list[str], log: Path) -> subprocess.Popen:
    return subprocess.Popen([str(RUN), "sysid_node", *args], stdout=log.open("w"),
                            stderr=subprocess.STDOUT, env=_env(), start_new_session=True)


@pytest.fixture(scope="module")
def paper_bag(tmp_path_factory) -> Path:
    """bags/paper_example when shipped, else the same scenario written here."""
    if (SHIPPED_BAG / "metadata.yaml").is_file():
        return SHIPPED_BAG
    from sysid_node.scenarios.paper import paper_example_data

    t, u, y = paper_example_data(duration_s=40.0, fs=100.0, seed=0)
    t = t + 1_700_000_000.0
    path = tmp_path_factory.mktemp("bags") / "paper_example"
    bag_io.write_signals(path, {"/vibration": (t, y, ["y"]), "/excitation": (t, u, ["u"])})
    return path


@pytest.fixture(scope="module")
def short_bag(tmp_path_factory) -> Path:
    """8 s of the paper example (for the command-line tests)."""
    from sysid_node.scenarios.paper import paper_example_data

    t, u, y = paper_example_data(duration_s=8.0, fs=100.0, seed=2)
    t = t + 1_700_000_000.0
    path = tmp_path_factory.mktemp("short") / "paper_short"
    bag_io.write_signals(path, {"/vibration": (t, y, ["y"]), "/excitation": (t, u, ["u"])})
    return path


def _start_time(bag: Path) -> int:
    for conn, _ts, raw in bag_io.iter_messages(bag, ["/vibration"]):
        return mc.stamp_ns(bag_io.typestore().deserialize_cdr(raw, conn.msgtype).header)
    raise AssertionError("empty bag")


def _end_time(bag: Path) -> int:
    sig = bag_io.read_signals(bag, ["/vibration"])["/vibration"]
    return int(round(sig.t[-1] * 1e9))


def _wait_for_estimate(stamp_ns: int, timeout: float) -> None:
    """Wait until /modal_estimate reaches ``stamp_ns`` (the node may lag behind the replay)."""
    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from sysid_node.node import ESTIMATE_QOS

    from sysid_msgs.msg import ModalEstimate

    os.environ.update(_env())
    ctx = rclpy.Context()
    rclpy.init(context=ctx)
    node = rclpy.create_node("e2e_watch", context=ctx)
    last = [0]
    node.create_subscription(
        ModalEstimate, "/modal_estimate", lambda m: last.__setitem__(0, mc.stamp_ns(m.header)),
        ESTIMATE_QOS,
    )
    ex = SingleThreadedExecutor(context=ctx)
    ex.add_node(node)
    deadline = time.monotonic() + timeout
    try:
        while last[0] < stamp_ns and time.monotonic() < deadline:
            ex.spin_once(timeout_sec=0.1)
    finally:
        ex.shutdown()
        node.destroy_node()
        rclpy.try_shutdown(context=ctx)


def _read_estimates(bag: Path) -> list:
    ts = bag_io.typestore()
    return [
        mc.estimate_from_msg(ts.deserialize_cdr(raw, conn.msgtype))
        for conn, _t, raw in bag_io.iter_messages(bag, ["/modal_estimate"])
    ]


def _near(rec, f: float, tol: float = 0.02) -> bool:
    return any(abs(m.frequency_hz - f) <= tol * f and m.status != "lost" for m in rec.modes)


def _at(records, t_ns: int):
    return next(r for r in records if r.stamp_ns >= t_ns)


@pytest.fixture(scope="module")
def offline_records(paper_bag):
    records, _pipeline, _info = offline.run(paper_bag)
    return records


@pytest.mark.dds
@pytest.mark.slow
def test_replay_into_node_recorded_estimates_accurate_and_equal_offline(
    paper_bag, offline_records, tmp_path
):
    rec_bag = tmp_path / "recorded"
    # reliable and a deep reader queue: on a loaded 2-core machine the subscriber process can be
    # descheduled for a while, and offline = live holds only if no sample is lost
    # catch_up off, max_backlog 0 and realization_budget 0: every estimate is made from every
    # sample however late, with every realization, as offline does (by default a node that
    # falls behind makes only current estimates, and a slow machine realizes less often).
    # At 2x: at 5x (1000 messages/s) this VM's DDS delivered one topic seconds after the other
    # (the reliable repair of a loaded loopback), and the node, as designed, went output-only
    # on an input silent for over a second of wall clock
    node = _start(["sysid_node", "--ros-args", "-p", "qos:=reliable", "-p", "qos_depth:=5000",
                   "-p", "catch_up:=false", "-p", "max_backlog:=0.0",
                   "-p", "realization_budget:=0.0"], tmp_path / "node.log")
    record = _start(["record", "-o", str(rec_bag), "/modal_estimate"], tmp_path / "record.log")
    try:
        time.sleep(2.0)
        assert node.poll() is None, (tmp_path / "node.log").read_text()[-2000:]
        replay = subprocess.run(
            [str(RUN), "sysid_node", "replay", "--bag", str(paper_bag), "--rate", "2",
             "--topics", "/vibration", "/excitation", "--quiet"],
            capture_output=True, text=True, env=_env(), timeout=180,
        )
        assert replay.returncode == 0, replay.stderr[-2000:]
        _wait_for_estimate(_end_time(paper_bag) - 200_000_000, timeout=60.0)
        time.sleep(1.0)
    finally:
        stop_group(record)
        code = stop_group(node)
    node_log = (tmp_path / "node.log").read_text()
    assert code == 0 and "Traceback" not in node_log, node_log[-2000:]
    live = _read_estimates(rec_bag)
    t0 = _start_time(paper_bag)
    assert len(live) > 300

    # offline gives the same estimates at the same instants
    by_stamp = {r.stamp_ns: r for r in offline_records}
    matched = [(r, by_stamp[r.stamp_ns]) for r in live if r.stamp_ns in by_stamp]
    assert len(matched) >= 0.95 * len(live)
    for a, b in matched:
        fa = [m.frequency_hz for m in a.modes]
        fb = [m.frequency_hz for m in b.modes]
        assert len(fa) == len(fb)
        np.testing.assert_allclose(fa, fb, rtol=1e-9)
        assert a.samples_used == b.samples_used

    at2 = _at(live, t0 + 2_000_000_000)
    assert _near(at2, 2.0) and _near(at2, 4.0), [m.frequency_hz for m in at2.modes]
    at21 = _at(live, t0 + 21_500_000_000)
    assert _near(at21, 6.0), [m.frequency_hz for m in at21.modes]
    assert _near(at21, 2.0) and _near(at21, 4.0)


def test_offline_accuracy(paper_bag, offline_records):
    t0 = _start_time(paper_bag)
    assert _near(_at(offline_records, t0 + 2_000_000_000), 2.0)
    assert _near(_at(offline_records, t0 + 2_000_000_000), 4.0)
    assert _near(_at(offline_records, t0 + 21_500_000_000), 6.0)


def test_offline_command_line_writes_bag_csv_json(short_bag, tmp_path):
    params = tmp_path / "p.yaml"
    params.write_text("sysid_node:\n  ros__parameters:\n    publish_rate: 2\n"
                      "    memory_time_constant: 1.0\n    memory_periods: 0.0\n")
    out = tmp_path / "estimates"
    proc = subprocess.run(
        [str(RUN), "sysid_node", "offline", "--bag", str(short_bag), "--output", str(out),
         "--params-file", str(params)],
        capture_output=True, text=True, env=_env(), timeout=180,
    )
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert "offline [" in proc.stderr and "100.0%" in proc.stderr  # progress bar
    est = _read_estimates(out)
    assert 15 <= len(est) <= 17  # 8 s at 2 Hz
    assert est[-1].forgetting_factor == pytest.approx(np.exp(-1 / 100.0))
    rows = (tmp_path / "estimates.csv").read_text().splitlines()
    assert rows[0].startswith("stamp,samples_used") and len(rows) > len(est)
    summary = json.loads((tmp_path / "estimates.json").read_text())
    assert summary["estimates"] == len(est) and summary["sample_rate_hz"] == 100.0


@pytest.mark.parametrize(
    ("case", "fragment"),
    [
        ("missing", "not found"),
        ("not_a_bag", "not a rosbag2 bag"),
        ("truncated", "cannot read bag"),
        ("no_topic", "no topic /vibration"),
        ("bad_params", "forgetting_factor"),
    ],
)
def test_offline_bad_input_one_line_reason(case, fragment, short_bag, tmp_path):
    bag = tmp_path / "bag"
    extra: list[str] = []
    if case == "missing":
        bag = tmp_path / "nothing_here"
    elif case == "not_a_bag":
        bag.mkdir()
        (bag / "data.txt").write_text("hello")
    elif case == "truncated":
        import shutil

        shutil.copytree(short_bag, bag)
        data = max((p for p in bag.iterdir() if p.name != "metadata.yaml"),
                   key=lambda p: p.stat().st_size)
        data.write_bytes(data.read_bytes()[: data.stat().st_size // 3])
    elif case == "no_topic":
        bag_io.write_signals(bag, {"/other": (np.arange(10) * 0.01, np.zeros((10, 1)), [])})
    elif case == "bad_params":
        bag = short_bag
        p = tmp_path / "p.yaml"
        p.write_text("sysid_node:\n  ros__parameters:\n    forgetting_factor: 2.0\n")
        extra = ["--params-file", str(p)]
    proc = subprocess.run(
        [str(RUN), "sysid_node", "offline", "--bag", str(bag), "--output",
         str(tmp_path / "out"), "--quiet", *extra],
        capture_output=True, text=True, env=_env(), timeout=120,
    )
    assert proc.returncode == 2
    lines = [line for line in proc.stderr.splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith("offline: error:"), proc.stderr
    assert fragment in lines[0]
