"""sysid_node over real DDS with the online LPV model: the scheduling topic is subscribed, each
estimate carries the scheduling value at its stamp and the LPV-predicted modes there - the same
numbers the pure ``SchedulePredictor`` gives for those samples - and /diagnostics reports
``scheduling_value``, ``scheduling_age_s`` and ``lpv_in_range``."""

from __future__ import annotations

import math
import os
import subprocess
import threading
import time
from pathlib import Path

import numpy as np
import pytest

rclpy = pytest.importorskip("rclpy")

from sysid_node.core.lpv import LpvModel  # noqa: E402
from sysid_node.process_group import stop_group  # noqa: E402
from sysid_node.scenarios.csm_rotor import csm_at  # noqa: E402
from sysid_node.scenarios.paper import paper_example_data  # noqa: E402
from sysid_node.scheduling import SchedulePredictor  # noqa: E402

from sysid_node import msg_convert as mc  # noqa: E402

pytestmark = [pytest.mark.dds, pytest.mark.slow]

RUN = Path(__file__).resolve().parents[3] / "ros2_ws" / "run"
T0 = 1_700_000_000 * 10**9
FS = 100.0


def test_estimates_carry_scheduling_value_and_predicted_modes(tmp_path):
    from diagnostic_msgs.msg import DiagnosticArray
    from rclpy.executors import SingleThreadedExecutor
    from sysid_node.node import ESTIMATE_QOS

    from sysid_msgs.msg import ModalEstimate, SignalBlock, SignalSample

    pts = np.arange(32.0, 38.01, 1.0)
    lpv = LpvModel.from_systems(pts, [csm_at(p) for p in pts], scheduling="rotor_speed",
                                unit="Hz")
    lpv.save(tmp_path / "csm.lpv.npz")
    t, u, y = paper_example_data(duration_s=8.0, fs=FS, seed=3)
    stamps = T0 + np.round(t * 1e9).astype(np.int64)
    ts = stamps[::10]  # rotor speed at 10 Hz, 33 -> 35 Hz
    speed = 33.0 + 2.0 * (ts - ts[0]) / (ts[-1] - ts[0])

    env = dict(os.environ, ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
    env.setdefault("ROS_DOMAIN_ID", str(10 + os.getpid() % 80))
    os.environ.update(ROS_DOMAIN_ID=env["ROS_DOMAIN_ID"],
                      ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
    log = (tmp_path / "node.log").open("w")
    proc = subprocess.Popen(
        [str(RUN), "sysid_node", "sysid_node", "--ros-args", "-p", "output_type:=SignalBlock",
         "-p", "input_type:=SignalBlock", "-p", "publish_rate:=5.0",
         "-p", "scheduling_topic:=rotor_speed", "-p", f"lpv_model:={tmp_path / 'csm.lpv.npz'}"],
        stdout=log, stderr=subprocess.STDOUT, env=env, start_new_session=True)
    ctx = rclpy.Context()
    rclpy.init(context=ctx)
    node = rclpy.create_node("sysid_lpv_test", context=ctx)
    pub_y = node.create_publisher(SignalBlock, "/vibration", 100)
    pub_u = node.create_publisher(SignalBlock, "/excitation", 100)
    pub_s = node.create_publisher(SignalSample, "/rotor_speed", 100)
    estimates: list = []
    diags: list = []
    node.create_subscription(ModalEstimate, "/modal_estimate", estimates.append, ESTIMATE_QOS)
    node.create_subscription(DiagnosticArray, "/diagnostics", diags.append, 10)
    ex = SingleThreadedExecutor(context=ctx)
    ex.add_node(node)
    spin = threading.Thread(target=lambda: _spin(ex), daemon=True)
    spin.start()
    try:
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline and not (
                pub_y.get_subscription_count() and pub_u.get_subscription_count()
                and pub_s.get_subscription_count()):
            time.sleep(0.05)
        assert pub_s.get_subscription_count(), "sysid_node did not subscribe to rotor_speed"
        # the publisher sees the match before the node's reader has matched it back: what is
        # sent (best effort) in between is lost, so give discovery a moment to finish
        time.sleep(1.0)
        # the scheduling samples first: none arrives after the data of its instant (a sample
        # that does is not used for that estimate, live or offline)
        for k in range(len(ts)):
            pub_s.publish(mc.signal_sample_msg(int(ts[k]), [speed[k]], ["rotor_speed[Hz]"]))
            time.sleep(0.002)
        time.sleep(0.5)
        for a in range(0, len(stamps), 10):
            pub_y.publish(mc.signal_block_msg(int(stamps[a]), 1 / FS, y[a:a + 10]))
            pub_u.publish(mc.signal_block_msg(int(stamps[a]), 1 / FS, u[a:a + 10]))
            time.sleep(0.01)
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline and not (
                estimates and mc.stamp_ns(estimates[-1].header) >= stamps[-30]):
            time.sleep(0.05)
        recs = [mc.estimate_from_msg(m) for m in estimates]
        assert recs and recs[-1].stamp_ns >= stamps[-30], "no late estimate"
        ref = SchedulePredictor(lpv)
        ref.push(ts, speed)
        with_value = [r for r in recs if math.isfinite(r.scheduling_value)]
        assert len(with_value) >= 0.8 * len(recs)
        for r in with_value:
            theta, modes = ref.predict(r.stamp_ns)
            assert r.scheduling_value == pytest.approx(theta, abs=1e-9)
            np.testing.assert_allclose([m.frequency_hz for m in r.predicted_modes],
                                       [m.frequency_hz for m in modes], rtol=1e-9)
            np.testing.assert_allclose([m.damping_ratio for m in r.predicted_modes],
                                       [m.damping_ratio for m in modes], rtol=1e-6)
        deadline = time.monotonic() + 10
        kv: dict[str, str] = {}
        while time.monotonic() < deadline:
            kv = {v.key: v.value for v in diags[-1].status[0].values} if diags else {}
            if kv.get("lpv_in_range") == "true":
                break
            time.sleep(0.1)
        assert kv.get("lpv_in_range") == "true", kv
        assert 33.0 <= float(kv["scheduling_value"]) <= 35.0
        assert 0.0 <= float(kv["scheduling_age_s"]) <= 0.1 + 1e-6
    finally:
        stop_group(proc, timeout=15)
        ex.shutdown()
        node.destroy_node()
        rclpy.try_shutdown(context=ctx)
        log.close()
    text = (tmp_path / "node.log").read_text()
    assert proc.returncode == 0 and "Traceback" not in text, text[-2000:]


def _spin(ex) -> None:
    try:
        ex.spin()
    except Exception:  # context shut down
        pass
