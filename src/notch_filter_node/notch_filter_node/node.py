"""notch_filter_node: the adaptive notch bank as a ROS 2 node (thin; numerics in the pure modules).

Subscribes to ``estimate_topic`` (sysid_msgs/ModalEstimate, reliable + transient-local, depth 1,
as sysid_node publishes it) and to ``signal_topic`` (SignalSample, SignalBlock or sensor_msgs/Imu,
sensor-data QoS); publishes every filtered message on ``output_topic`` with the same type and
header, ``bank_topic`` (sysid_msgs/NotchBank) when a notch changes and periodically, and
/diagnostics (estimate age, fallback, per-sample cost, bad input). Parameters: see
:mod:`notch_filter_node.params`; live ones retune the bank through the parameter services.
"""

from __future__ import annotations

import array
import copy
import math
import sys
import time
from typing import Any

import numpy as np
import rclpy
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rcl_interfaces.msg import SetParametersResult
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import (
    DurabilityPolicy,
    HistoryPolicy,
    QoSProfile,
    ReliabilityPolicy,
    qos_profile_sensor_data,
)
from sysid_node.node import ESTIMATE_QOS  # the publisher's QoS of /modal_estimate

from notch_filter_node import params as P
from notch_filter_node.adaptive import AdaptiveNotchFilter
from notch_filter_node.policy import STATE_NAMES, EstimateInput, ModeInput
from sysid_msgs.msg import ModalEstimate, Notch, NotchBank
from sysid_node import msg_convert as mc
from sysid_node import node_params as NP

STATUS_NAMES = {0: "tentative", 1: "tracked", 2: "lost"}
#: Samples whose stamps measure the sample rate when neither a parameter nor the message gives it.
RATE_SAMPLES = 20


class StartupError(RuntimeError):
    """The node cannot start; ``str(err)`` is a one-line reason."""


#: What each kind of parameter does, appended to its description.
KIND_NOTES = {"structural": " (structural: rebuilds the bank)", "read_only": " (read-only)",
              "live": " (live-tunable)"}


def estimate_input(msg: Any) -> EstimateInput:
    """sysid_msgs/ModalEstimate -> the policy's plain input."""
    modes = [
        ModeInput(int(m.id), STATUS_NAMES.get(int(m.status), "tentative"), float(m.frequency),
                  float(m.frequency_std), float(m.damping_ratio), float(m.damping_ratio_std),
                  float(m.amplitude))
        for m in msg.modes
    ]
    return EstimateInput(mc.stamp_ns(msg.header) * 1e-9, bool(msg.converged), modes)


def _msg_class(kind: str):
    if kind == "Imu":
        from sensor_msgs.msg import Imu

        return Imu
    from sysid_msgs import msg

    return getattr(msg, kind)


def filled_message(msg: Any, kind: str, y: np.ndarray, axes: list[str]) -> Any:
    """A copy of the input message (same header, names, other fields) carrying ``y``."""
    out = copy.copy(msg)
    if kind == "SignalSample":
        out.values = array.array("d", np.ascontiguousarray(y.reshape(-1)).tobytes())
    elif kind == "SignalBlock":
        out.data = array.array("d", np.ascontiguousarray(y.reshape(-1)).tobytes())
    else:
        for axis, value in zip(axes, y.reshape(-1), strict=True):
            group, field = mc.IMU_FIELDS[axis]
            vec = copy.copy(getattr(out, group))
            setattr(vec, field, float(value))
            setattr(out, group, vec)
    return out


class NotchFilterNode(Node):
    """The ROS 2 node; see the module docstring."""

    def __init__(self) -> None:
        super().__init__("notch_filter_node")
        try:
            self.values = NP.declare(self, P.PARAMS, KIND_NOTES)
        except NP.ParameterError as err:
            raise StartupError(str(err)) from None
        reason = P.validate_set(self.values)
        if reason:
            raise StartupError(f"invalid parameters: {reason}")
        v = self.values
        self.kind = v["signal_type"]
        self.axes = P.parse_list(v["imu_axes"])
        self.filter: AdaptiveNotchFilter | None = None
        self._stamps: list[int] = []
        self._last_stamp_s = math.nan
        self._cost_s = 0.0  # processing time, exponentially averaged per sample
        self._samples = 0
        self._bad: dict[str, int] = {}
        self._last_bad_log = -math.inf
        self._published: tuple = ()
        self._last_bank_wall = -math.inf
        self._revision = -1
        self._estimate: EstimateInput | None = None
        sig_qos = QoSProfile(
            history=HistoryPolicy.KEEP_LAST, depth=int(v["qos_depth"]),
            reliability=qos_profile_sensor_data.reliability,
            durability=qos_profile_sensor_data.durability,
        )
        reliable = v["output_qos"] == "reliable"
        out_qos = QoSProfile(
            history=HistoryPolicy.KEEP_LAST, depth=int(v["qos_depth"]),
            reliability=ReliabilityPolicy.RELIABLE if reliable else ReliabilityPolicy.BEST_EFFORT,
            durability=DurabilityPolicy.VOLATILE,
        )
        cls = _msg_class(self.kind)
        self.out_pub = self.create_publisher(cls, v["output_topic"], out_qos)
        self.bank_pub = self.create_publisher(NotchBank, v["bank_topic"], 10)
        self.diag_pub = self.create_publisher(DiagnosticArray, "/diagnostics", 10)
        est_sub = self.create_subscription(ModalEstimate, v["estimate_topic"],
                                           self._on_estimate, ESTIMATE_QOS)
        sig_sub = self.create_subscription(cls, v["signal_topic"], self._on_signal, sig_qos)
        self.add_on_set_parameters_callback(self._on_set_parameters)
        self._bank_timer = self.create_timer(1.0 / v["bank_rate"], self._publish_bank_periodic)
        self._diag_timer = self.create_timer(1.0 / v["diagnostics_rate"], self._publish_diag)
        if v["sample_rate"] > 0:
            self._build(v["sample_rate"], None)
        # the names after remapping and namespace, as `ros2 topic list` shows them
        self.get_logger().info(
            f"filtering {sig_sub.topic_name} ({self.kind}) -> {self.out_pub.topic_name}, "
            f"estimates from {est_sub.topic_name}, bank on {self.bank_pub.topic_name}"
        )

    # ---- parameters ----
    def _on_set_parameters(self, parameters: list[Parameter]) -> SetParametersResult:
        changes = {p.name: p.value for p in parameters if p.name in P.SPECS}
        if not changes:
            return SetParametersResult(successful=True)
        new = {**self.values, **changes}
        fs = self.filter.fs if self.filter is not None else math.nan
        reason = P.validate_set(new, fs if new["sample_rate"] == 0 else math.nan)
        reason = reason or NP.read_only_changes(P.SPECS, self.values, changes)
        if reason:
            self.get_logger().warning(f"parameter change rejected: {reason}")
            return SetParametersResult(successful=False, reason=reason)
        old, self.values = self.values, new
        for k in ("bank_rate", "diagnostics_rate"):
            if new[k] != old[k]:
                timer = self._bank_timer if k == "bank_rate" else self._diag_timer
                timer.timer_period_ns = int(1e9 / new[k])
                timer.reset()
        structural = [k for k in changes if P.SPECS[k].kind == "structural"
                      and changes[k] != old[k]]
        if structural and self.filter is not None:
            self.get_logger().info(f"{', '.join(structural)} changed: rebuilding the bank")
            rate = new["sample_rate"] or self.filter.fs
            self._build(rate, self.filter.channels)
        elif self.filter is not None:
            self.filter.reconfigure(P.policy_config(new))
            self._apply_enable()
        self.get_logger().info(
            "parameters set: " + ", ".join(f"{k}={v}" for k, v in changes.items())
        )
        return SetParametersResult(successful=True)

    # ---- the bank ----
    def _build(self, fs: float, channels: int | None) -> None:
        """(Re)create the bank at ``fs``; ``channels`` None = wait for the first message."""
        if channels is None:
            self.filter = None
            return
        old = self.filter
        self.filter = AdaptiveNotchFilter(
            P.policy_config(self.values), fs, channels, int(self.values["substep"])
        )
        if old is not None and old.policy.estimate is not None:
            self.filter.set_estimate(old.policy.estimate)
        self._apply_enable()
        self.get_logger().info(f"notch bank ready: {channels} channel(s) at {fs:g} Hz")

    def _apply_enable(self) -> None:
        if self.filter is None:
            return
        enabled = np.ones(self.filter.channels, dtype=bool)
        off = [c for c in P.disabled_channels(self.values["disabled_channels"])
               if c < self.filter.channels]
        enabled[off] = False
        self.filter.enabled = enabled

    def _bad_input(self, key: str, text: str) -> None:
        self._bad[key] = self._bad.get(key, 0) + 1
        now = time.monotonic()
        if now - self._last_bad_log > 5.0:
            self._last_bad_log = now
            self.get_logger().warning(f"{text} (bad input so far: {self._bad})")

    def _sample_rate(self, msg: Any, stamps: np.ndarray) -> float:
        """Sample rate to build the bank with, or NaN while it is being measured."""
        if self.values["sample_rate"] > 0:
            return float(self.values["sample_rate"])
        if self.kind == "SignalBlock" and msg.sample_period > 0:
            return 1.0 / float(msg.sample_period)
        self._stamps.extend(int(s) for s in stamps)
        if len(self._stamps) < RATE_SAMPLES:
            return math.nan
        d = np.diff(np.array(self._stamps[-RATE_SAMPLES:], dtype=np.int64))
        d = d[d > 0]
        return 1e9 / float(np.median(d)) if d.size >= RATE_SAMPLES // 2 else math.nan

    # ---- callbacks ----
    def _on_estimate(self, msg: ModalEstimate) -> None:
        self._estimate = estimate_input(msg)
        if self.filter is not None:
            self.filter.set_estimate(self._estimate)
            self._maybe_publish_bank()

    def _on_signal(self, msg: Any) -> None:
        t0 = time.perf_counter()
        if self.kind == "SignalBlock":
            c = int(msg.channel_count)
            if c <= 0 or len(msg.data) % c:
                self._bad_input("malformed", f"SignalBlock with {len(msg.data)} values is not "
                                f"a whole number of samples of {c} channels: dropped")
                return
        try:
            stamps, x = mc.to_arrays(msg, self.kind, self.axes)
        except (ValueError, TypeError) as err:
            self._bad_input("malformed", f"unreadable {self.kind}: {err}")
            return
        if x.shape[0] == 0:
            return
        channels = x.shape[1]
        if channels == 0 or channels > P.MAX_CHANNELS:
            self._bad_input("wrong_channels", f"{channels} channels: dropped")
            return
        if self.filter is None or self.filter.channels != channels:
            fs = self._sample_rate(msg, stamps)
            if not math.isfinite(fs):  # still measuring: pass the samples through
                self.out_pub.publish(msg)
                return
            if self.filter is not None:
                self._bad_input("wrong_channels", f"channel count changed from "
                                f"{self.filter.channels} to {channels}: bank rebuilt")
            self._build(fs, channels)
            t0 = time.perf_counter()
        elif self.kind == "SignalBlock" and self.values["sample_rate"] == 0:
            fs = 1.0 / msg.sample_period if msg.sample_period > 0 else self.filter.fs
            if abs(fs - self.filter.fs) > 1e-3 * self.filter.fs:
                self._bad_input("rate_changed", f"sample rate changed from "
                                f"{self.filter.fs:g} to {fs:g} Hz: bank rebuilt")
                self._build(fs, channels)
        if self._estimate is not None and self.filter.policy.estimate is None:
            self.filter.set_estimate(self._estimate)
        if not np.isfinite(x).all():
            self._bad_input("nonfinite", "non-finite sample values: output NaN there, filter "
                            "memory kept clean")
        t_last = float(stamps[-1]) * 1e-9
        self._last_stamp_s = t_last
        y = self.filter.process(x, t_last)
        self.out_pub.publish(filled_message(msg, self.kind, y, self.axes))
        n = x.shape[0]
        self._samples += n
        per_sample = (time.perf_counter() - t0) / n
        self._cost_s = per_sample if self._cost_s == 0 else 0.99 * self._cost_s + 0.01 * per_sample
        self._maybe_publish_bank()

    # ---- outputs ----
    def _bank_msg(self) -> NotchBank:
        st = self.filter.status()
        msg = NotchBank()
        ns = int(round(self._last_stamp_s * 1e9)) if math.isfinite(self._last_stamp_s) else (
            self.get_clock().now().nanoseconds)
        msg.header.stamp.sec, msg.header.stamp.nanosec = mc.split_ns(ns)
        notches = []
        for n in st.notches:
            m = Notch()
            m.mode_id, m.state = int(n.mode_id), int(n.state)
            m.center_frequency, m.bandwidth, m.depth = (float(n.center), float(n.bandwidth),
                                                        float(n.depth))
            m.peak_reduction = math.nan  # not computed yet
            notches.append(m)
        msg.notches = notches
        msg.fallback_active = bool(st.fallback_active)
        msg.estimate_age = float(st.estimate_age)
        msg.bank_state = NotchBank.BANK_FALLBACK if st.fallback_active else NotchBank.BANK_TRACKING
        msg.reason = "no usable estimate" if st.fallback_active else ""
        msg.crossover_frequency = float(self.filter.policy.config.crossover_frequency)
        msg.phase_lag = math.nan  # not computed yet
        return msg

    def _maybe_publish_bank(self) -> None:
        """Publish /notch_bank on a discrete change at once, while notches move at most at
        bank_max_rate."""
        if self.filter is None:
            return
        st = self.filter.status()
        key = tuple((n.mode_id, n.state, round(n.center, 4), round(n.bandwidth, 4),
                     round(n.depth, 2)) for n in st.notches) + (st.fallback_active,)
        if key == self._published:
            return
        now = time.monotonic()
        discrete = self.filter.policy.revision != self._revision or len(key) != len(
            self._published)
        if discrete or now - self._last_bank_wall >= 1.0 / self.values["bank_max_rate"]:
            self._publish_bank(key)

    def _publish_bank(self, key: tuple | None = None) -> None:
        self.bank_pub.publish(self._bank_msg())
        self._last_bank_wall = time.monotonic()
        self._revision = self.filter.policy.revision
        if key is not None:
            self._published = key

    def _publish_bank_periodic(self) -> None:
        if self.filter is not None:
            self._publish_bank()

    def _publish_diag(self) -> None:
        st = self.filter.status() if self.filter is not None else None
        s = DiagnosticStatus(
            name=f"{self.get_fully_qualified_name().lstrip('/')}: notch bank",
            hardware_id=self.get_fully_qualified_name())
        if st is None:
            s.level, s.message = DiagnosticStatus.WARN, "waiting for the signal"
        elif st.fallback_active:
            s.level, s.message = DiagnosticStatus.WARN, "fallback notch active (estimate stale, " \
                "missing or not converged)"
        else:
            s.level, s.message = DiagnosticStatus.OK, f"{len(st.notches)} notch(es) tracking"
        if self._bad and s.level == DiagnosticStatus.OK:
            s.level, s.message = DiagnosticStatus.WARN, f"bad input: {self._bad}"
        vals = {
            "estimate_age_s": f"{st.estimate_age:.3f}" if st else "nan",
            "fallback_active": str(st.fallback_active if st else True).lower(),
            "per_sample_cost_us": f"{self._cost_s * 1e6:.2f}",
            "sample_rate_hz": f"{self.filter.fs:g}" if self.filter else "nan",
            "channels": str(self.filter.channels if self.filter else 0),
            "samples_filtered": str(self._samples),
            "notches": "; ".join(f"{STATE_NAMES[n.state]} {n.center:.3f} Hz bw {n.bandwidth:.3f} "
                                 f"Hz {n.depth:.1f} dB" for n in st.notches) if st else "",
            "phase_lag_deg_at_crossover": f"{st.phase_lag_deg:.2f}" if st else "nan",
            "phase_lag_budget_limited": str(st.budget_limited if st else False).lower(),
            "bad_input": ", ".join(f"{k}={v}" for k, v in sorted(self._bad.items())) or "none",
        }
        s.values = [KeyValue(key=k, value=v) for k, v in vals.items()]
        msg = DiagnosticArray(status=[s])
        msg.header.stamp = self.get_clock().now().to_msg()
        self.diag_pub.publish(msg)


def main(args: list[str] | None = None) -> int:
    """Entry point of ``ros2 run notch_filter_node notch_filter_node``."""
    rclpy.init(args=args)
    node = None
    code = 0
    try:
        node = NotchFilterNode()
        rclpy.spin(node)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except StartupError as err:
        print(f"notch_filter_node: error: {err}", file=sys.stderr)
        code = 1
    finally:
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
    return code


if __name__ == "__main__":
    sys.exit(main())
