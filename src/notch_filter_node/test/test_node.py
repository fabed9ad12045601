"""notch_filter_node over real DDS (loopback): the installed executable runs in its own process
group; this test publishes estimates and a sine, receives the filtered signal, the notch bank and
diagnostics, and sets parameters through the parameter services (what `ros2 param set` calls)."""

import os
import random
import signal
import subprocess
import time
from pathlib import Path

import numpy as np
import pytest

pytestmark = [pytest.mark.dds, pytest.mark.slow]

FS, F_MODE = 200.0, 6.0
T0_NS = 1_700_000_000 * 10**9


@pytest.fixture(scope="module")
def dds():
    os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    os.environ.setdefault("ROS_DOMAIN_ID", str(random.randint(10, 89)))
    import rclpy
    from ament_index_python.packages import get_package_prefix

    exe = Path(get_package_prefix("notch_filter_node")) / "lib/notch_filter_node/notch_filter_node"
    args = ["--ros-args", "-p", "freq_min:=2.0", "-p", "stale_timeout:=1.0",
            "-p", "fallback_timeout:=3.0", "-p", "fallback_center:=5.0",
            "-p", "fallback_bandwidth:=3.0"]
    proc = subprocess.Popen([str(exe), *args], stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                            start_new_session=True, text=True)
    rclpy.init()
    client = Client(rclpy)
    try:
        yield client
    finally:
        client.node.destroy_node()
        rclpy.try_shutdown()
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGINT)
            try:
                proc.wait(timeout=10)
            except subprocess.TimeoutExpired:
                os.killpg(proc.pid, signal.SIGKILL)
                proc.wait(timeout=5)
        out = proc.stdout.read() if proc.stdout else ""
        print(out[-3000:])


class Client:
    """The test's side of the DDS graph."""

    def __init__(self, rclpy):
        from diagnostic_msgs.msg import DiagnosticArray
        from rcl_interfaces.srv import SetParameters
        from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy

        from sysid_msgs.msg import ModalEstimate, NotchBank, SignalSample

        self.rclpy = rclpy
        self.node = rclpy.create_node("notch_test_client")
        est_qos = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                             durability=DurabilityPolicy.TRANSIENT_LOCAL)
        self.est_pub = self.node.create_publisher(ModalEstimate, "/modal_estimate", est_qos)
        self.sig_pub = self.node.create_publisher(SignalSample, "/vibration", 1000)
        self.out, self.banks, self.diags = [], [], []
        self.node.create_subscription(SignalSample, "/vibration_filtered", self.out.append, 5000)
        self.node.create_subscription(NotchBank, "/notch_bank", self.banks.append, 1000)
        self.node.create_subscription(DiagnosticArray, "/diagnostics", self.diags.append, 100)
        self.set_cli = self.node.create_client(SetParameters, "/notch_filter_node/set_parameters")
        assert self.set_cli.wait_for_service(timeout_sec=20.0), "node did not come up"
        self.k = 0  # next sample index
        self.spin(1.0)  # let the node's subscriptions match ours

    def spin(self, seconds):
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            self.rclpy.spin_once(self.node, timeout_sec=0.01)

    def estimate(self, f, converged=True):
        from sysid_msgs.msg import ModalEstimate, Mode

        m = Mode(id=4, status=Mode.STATUS_TRACKED, frequency=f, frequency_std=0.01,
                 damping_ratio=0.02, damping_ratio_std=0.003)
        msg = ModalEstimate(modes=[m], converged=converged, sample_rate=FS)
        ns = T0_NS + int(round(self.k / FS * 1e9))
        msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(ns, 10**9)
        self.est_pub.publish(msg)

    def samples(self, seconds, estimate_f=None):
        """Publish ``seconds`` of a 6 Hz sine (+ estimates every 0.2 s); returns the stamps."""
        from sysid_msgs.msg import SignalSample

        stamps = []
        for _ in range(int(seconds * FS)):
            if estimate_f is not None and self.k % int(0.2 * FS) == 0:
                self.estimate(estimate_f)
            ns = T0_NS + int(round(self.k / FS * 1e9))
            msg = SignalSample(values=[np.sin(2 * np.pi * F_MODE * self.k / FS), 1.0],
                               channel_names=["acc_z[m/s^2]", "const"])
            msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(ns, 10**9)
            self.sig_pub.publish(msg)
            stamps.append(ns)
            self.k += 1
            if self.k % 10 == 0:
                self.spin(0.025)  # 400 samples/s of wall time
        self.spin(0.5)
        return stamps

    def set_params(self, **values):
        from rcl_interfaces.msg import Parameter, ParameterType, ParameterValue
        from rcl_interfaces.srv import SetParameters

        req = SetParameters.Request()
        for name, v in values.items():
            if isinstance(v, str):
                pv = ParameterValue(type=ParameterType.PARAMETER_STRING, string_value=v)
            elif isinstance(v, bool):
                pv = ParameterValue(type=ParameterType.PARAMETER_BOOL, bool_value=v)
            else:
                pv = ParameterValue(type=ParameterType.PARAMETER_DOUBLE, double_value=float(v))
            req.parameters.append(Parameter(name=name, value=pv))
        fut = self.set_cli.call_async(req)
        end = time.monotonic() + 10
        while not fut.done() and time.monotonic() < end:
            self.rclpy.spin_once(self.node, timeout_sec=0.05)
        assert fut.done(), "set_parameters timed out"
        return fut.result().results


def stamp(msg):
    return msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec


def test_filters_with_same_stamps_and_publishes_bank(dds):
    sent = dds.samples(4.0, estimate_f=F_MODE)
    got = {stamp(m): np.array(m.values) for m in dds.out}
    cost = [(kv.key, kv.value) for d in dds.diags for s in d.status for kv in s.values
            if kv.key in ("per_sample_cost_us", "samples_filtered")]
    print("received", len(got), "of", len(sent), "cost us", cost)
    assert len(got) >= 0.9 * len(sent)
    assert set(got) <= set(sent)
    assert all(list(dds.out[0].channel_names) == ["acc_z[m/s^2]", "const"] for _ in (0,))
    late = [got[s] for s in sent[-int(FS) :] if s in got]
    y = np.array(late)
    assert np.max(np.abs(y[:, 0])) < 0.2  # the 6 Hz sine is notched (input amplitude 1)
    np.testing.assert_allclose(y[:, 1], 1.0, atol=1e-6)  # DC passes
    bank = dds.banks[-1]
    ns = [n for n in bank.notches if n.state == n.STATE_TRACKING]  # one section or a pair
    centre = np.mean([n.center_frequency for n in ns])
    assert {n.mode_id for n in ns} == {4} and len(ns) <= 2 and abs(centre - F_MODE) < 0.01
    assert all(n.depth == n.shape_depth >= 15.0 for n in ns)  # faded in
    assert not bank.fallback_active and bank.estimate_age < 0.5
    assert bank.bank_state == bank.BANK_TRACKING and bank.reason == ""
    assert min(n.peak_reduction for n in ns) >= 15.0 - 0.1 and bank.crossover_frequency == 0.5
    assert 0.0 < bank.phase_lag < 10.0
    dds.spin(1.2)
    keys = {kv.key for d in dds.diags for s in d.status for kv in s.values}
    assert {"estimate_age_s", "fallback_active", "per_sample_cost_us"} <= keys


def test_parameters_applied_or_rejected_with_reason(dds):
    ok = dds.set_params(depth=40.0, notch_pairs=False)  # single notches: 40 dB deep
    assert all(r.successful for r in ok)
    dds.banks.clear()
    dds.samples(1.5, estimate_f=F_MODE)
    assert max(n.depth for n in dds.banks[-1].notches) > 35.0
    (ok,) = dds.set_params(notch_pairs=True)
    assert ok.successful
    (bad,) = dds.set_params(depth=100.0)  # out of the descriptor's range
    assert not bad.successful and "depth" in bad.reason
    (bad,) = dds.set_params(peak_reduction=45.0)  # cross check: must stay below depth
    assert not bad.successful and "peak_reduction" in bad.reason
    (bad,) = dds.set_params(depht=30.0)
    assert not bad.successful and "did you mean 'depth'" in bad.reason
    (bad,) = dds.set_params(signal_topic="/other")
    assert not bad.successful and bad.reason
    (ok,) = dds.set_params(depth=30.0)
    assert ok.successful


def test_late_estimate_holds_then_falls_back(dds):
    dds.samples(0.5, estimate_f=F_MODE)
    dds.banks.clear()
    dds.samples(1.5)  # no estimate for 1.5 s of data > stale_timeout 1 s: holding
    bank = dds.banks[-1]
    assert not bank.fallback_active and bank.bank_state == bank.BANK_HOLDING
    assert bank.estimate_age > 1.0 and "late" in bank.reason
    ns = [n for n in bank.notches if n.state == n.STATE_HOLDING]  # one section or a pair
    centre = np.mean([n.center_frequency for n in ns])
    assert {n.mode_id for n in ns} == {4} and len(ns) <= 2 and abs(centre - F_MODE) < 0.01
    assert all(n.depth == n.shape_depth for n in ns)  # held at full depth
    dds.samples(2.0)  # now 3.5 s > fallback_timeout 3 s
    bank = dds.banks[-1]
    assert bank.fallback_active and bank.bank_state == bank.BANK_FALLBACK
    parked = [n for n in bank.notches if n.state == n.STATE_PARKED]
    assert len(parked) == 1 and parked[0].center_frequency == 5.0 and parked[0].depth == 30.0
    dds.spin(1.2)
    diag = {kv.key: kv.value for kv in dds.diags[-1].status[0].values}
    assert "tracking_to_holding=1" in diag["transitions"]
    assert "holding_to_fallback=1" in diag["transitions"]
