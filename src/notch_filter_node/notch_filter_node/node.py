"""notch_filter_node: the adaptive notch bank as a ROS 2 node (thin; numerics in the pure modules).

Subscribes to ``estimate_topic`` (sysid_msgs/ModalEstimate, reliable + transient-local, depth 1,
as sysid_node publishes it) and to ``signal_topic`` (SignalSample, SignalBlock or sensor_msgs/Imu,
sensor-data QoS); publishes every filtered message on ``output_topic`` with the same type and
header, ``bank_topic`` (sysid_msgs/NotchBank: sections, bank state and reason, peak reduction per
notch, phase lag at the crossover) when a notch changes and periodically, and /diagnostics.
Input checks (:mod:`notch_filter_node.stream`): a message sent twice or from the past is
dropped, the rate the stamps measure is compared with the bank's continuously (the bank is
re-designed at the measured rate), channels are mapped by name, a new layout is adopted once
confirmed. Every event is counted, logged once and then summarised, and sets the diagnostics
level while it is recent. Parameters: see :mod:`notch_filter_node.params`; live ones retune
the bank through the parameter services; a parameter file is checked at start-up.
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
from notch_filter_node import smoothing as SM
from notch_filter_node import stream as ST
from notch_filter_node.adaptive import AdaptiveNotchFilter
from notch_filter_node.policy import (
    BANK_FALLBACK,
    BANK_NAMES,
    BANK_TRACKING,
    STATE_NAMES,
    EstimateInput,
    ModeInput,
)
from sysid_msgs.msg import ModalEstimate, Notch, NotchBank
from sysid_node import msg_convert as mc
from sysid_node import node_params as NP

STATUS_NAMES = {0: "tentative", 1: "tracked", 2: "lost"}
#: Samples whose stamps measure the sample rate when neither a parameter nor the message gives it.
RATE_SAMPLES = 20
#: Bad-input events within this many seconds (wall clock) set the diagnostics level to WARN.
RECENT_S = 10.0
#: Lost samples up to this long [s] are bridged in the filter memory (longer gaps restart it).
BRIDGE_S = 0.5


class StartupError(RuntimeError):
    """The node cannot start; ``str(err)`` is a one-line reason."""


#: What each kind of parameter does, appended to its description.
KIND_NOTES = {"structural": " (structural: rebuilds the bank)", "read_only": " (read-only)",
              "live": " (live-tunable)"}


def estimate_input(msg: Any, received: float = math.nan) -> EstimateInput:
    """sysid_msgs/ModalEstimate -> the policy's plain input; ``received``: data time [s] of the
    signal when it arrived."""
    def convert(ms) -> list[ModeInput]:
        return [ModeInput(int(m.id), STATUS_NAMES.get(int(m.status), "tentative"),
                          float(m.frequency), float(m.frequency_std), float(m.damping_ratio),
                          float(m.damping_ratio_std), float(m.amplitude)) for m in ms]

    memory, lag = SM.estimator_memory(msg.forgetting_factor, msg.sample_rate, msg.block_rows)
    return EstimateInput(mc.stamp_ns(msg.header) * 1e-9, bool(msg.converged),
                         convert(msg.modes), int(msg.health), str(msg.health_reason), received,
                         convert(msg.predicted_modes), memory, lag)


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
        # undeclared names reach _on_set_parameters, which refuses them with the closest name
        super().__init__("notch_filter_node", allow_undeclared_parameters=True)
        try:
            NP.check_overrides(self, P.SPECS)  # unknown names, wrong types: one line
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
        self.events = ST.EventLog(period=5.0, recent=RECENT_S)
        self.stream = ST.StampCheck()
        self.layout = ST.LayoutTracker(int(v["layout_confirm"]))
        self._declared_fs = math.nan  # rate the parameter or SignalBlock states
        self._prev_ns: int | None = None  # last sample's stamp and values (bank order)
        self._prev_row: np.ndarray | None = None
        self._missing = 0
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
        # the names after remapping and namespace, as `ros2 topic list` shows them
        self.get_logger().info(
            f"filtering {sig_sub.topic_name} ({self.kind}) -> {self.out_pub.topic_name}, "
            f"estimates from {est_sub.topic_name}, bank on {self.bank_pub.topic_name}"
        )

    # ---- parameters ----
    def _on_set_parameters(self, parameters: list[Parameter]) -> SetParametersResult:
        reason = NP.unknown_names(P.SPECS, [p.name for p in parameters])
        if reason:
            self.get_logger().warning(f"parameter change rejected: {reason}")
            return SetParametersResult(successful=False, reason=reason)
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
        if new["layout_confirm"] != old["layout_confirm"]:
            self.layout.confirm = int(new["layout_confirm"])
        structural = [k for k in changes if P.SPECS[k].kind == "structural"
                      and changes[k] != old[k]]
        if structural and self.filter is not None:
            self.get_logger().info(f"{', '.join(structural)} changed: rebuilding the bank")
            rate = new["sample_rate"] or self.filter.fs
            self._build(rate, self.filter.channels)
            self.stream.restart()
        elif self.filter is not None:
            self.filter.reconfigure(P.policy_config(new))
            self._apply_enable()
        self.get_logger().info(
            "parameters set: " + ", ".join(f"{k}={v}" for k, v in changes.items())
        )
        return SetParametersResult(successful=True)

    # ---- the bank ----
    def _build(self, fs: float, channels: int) -> None:
        """(Re)create the bank at ``fs`` for ``channels`` channels."""
        old = self.filter
        self.filter = AdaptiveNotchFilter(
            P.policy_config(self.values), fs, channels, int(self.values["substep"])
        )
        est = old.policy.estimate if old is not None else self._estimate
        if est is not None:
            self.filter.set_estimate(est)
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

    def _event(self, key: str, text: str, level: str = "warning", n: int = 1) -> None:
        """Count an event; log it (first at once, then summarised every 5 s)."""
        line = self.events.add(key, text, time.monotonic(), n)
        if line is None:
            return
        # rclpy ties one severity to each call site: one call per level
        if level == "info":
            self.get_logger().info(line)
        else:
            self.get_logger().warning(line)

    def _declared_rate(self, msg: Any) -> float:
        """Rate the parameter or the message states, NaN when neither does."""
        if self.values["sample_rate"] > 0:
            return float(self.values["sample_rate"])
        if self.kind == "SignalBlock" and msg.sample_period > 0 and math.isfinite(
                msg.sample_period):
            return 1.0 / float(msg.sample_period)
        return math.nan

    def _first_rate(self, stamps: np.ndarray) -> float:
        """Rate from the stamps of the first samples, NaN while they are being collected."""
        self._stamps.extend(int(s) for s in stamps)
        if len(self._stamps) < RATE_SAMPLES:
            return math.nan
        d = np.diff(np.array(self._stamps[-RATE_SAMPLES:], dtype=np.int64))
        d = d[d > 0]
        return 1e9 / float(np.median(d)) if d.size >= RATE_SAMPLES // 2 else math.nan

    def _check_rate(self) -> None:
        """The measured rate against the bank's: re-design at the measured rate, and say so."""
        measured = self.stream.rate()
        fs = self.filter.fs
        if not math.isfinite(measured) or abs(measured / fs - 1.0) <= self.values[
                "rate_tolerance"]:
            return
        src = ("the sample_rate parameter" if self.values["sample_rate"] > 0 else
               "SignalBlock.sample_period" if self.kind == "SignalBlock" else "the bank")
        key = "rate_mismatch" if self.values["sample_rate"] > 0 else "rate_changed"
        self._event(key, f"stamps measure {measured:.4g} Hz, {src} says {fs:.4g} Hz: bank "
                    f"re-designed at {measured:.4g} Hz")
        self.filter.set_rate(measured)
        self.stream.restart()

    # ---- callbacks ----
    def _on_estimate(self, msg: ModalEstimate) -> None:
        est = estimate_input(msg, self._last_stamp_s)
        self._estimate = est
        if self.filter is not None:
            why = self.filter.set_estimate(est)
            if why:
                key = "estimate_future" if "ahead" in why else "estimate_rejected"
                self._event(key, why)
            self._drain_transitions()
            self._maybe_publish_bank()

    def _drain_transitions(self) -> None:
        """Log every bank state change once at WARN (with age and reason), throttled when it
        flaps; the counts go to /diagnostics."""
        pol = self.filter.policy
        for tr in pol.transitions:
            key = f"bank_{BANK_NAMES[tr.old]}_to_{BANK_NAMES[tr.new]}"
            level = "info" if tr.old == BANK_FALLBACK and tr.new == BANK_TRACKING and \
                self.events.counts.get(key, 0) == 0 else "warning"
            self._event(key, tr.text(), level)
        pol.transitions.clear()

    def _on_signal(self, msg: Any) -> None:
        t0 = time.perf_counter()
        if self.kind == "SignalBlock":
            c = int(msg.channel_count)
            if c <= 0 or len(msg.data) % c:
                self._event("malformed", f"SignalBlock with {len(msg.data)} values is not a "
                            f"whole number of samples of {c} channels: dropped")
                return
            if not (msg.sample_period > 0 and math.isfinite(msg.sample_period)) and \
                    len(msg.data) > c:
                self._event("malformed", f"SignalBlock with sample_period "
                            f"{msg.sample_period}: dropped")
                return
        try:
            stamps, x = mc.to_arrays(msg, self.kind, self.axes)
        except (ValueError, TypeError) as err:
            self._event("malformed", f"unreadable {self.kind}: {err}")
            return
        if x.shape[0] == 0:
            return
        channels = x.shape[1]
        if channels == 0 or channels > P.MAX_CHANNELS:
            self._event("wrong_channels", f"{channels} channels: dropped")
            return
        order = self.stream.check(int(stamps[0]))
        if order in (ST.DUPLICATE, ST.OUT_OF_ORDER):
            what = "sent twice" if order == ST.DUPLICATE else "older than the previous one"
            self._event(order, f"message stamped {stamps[0] * 1e-9:.6f} s {what}: dropped "
                        "(not filtered)")
            return
        if order == ST.RESTART:
            self._event("stamps_restarted", "stamps jumped back by more than 1 s: the stream "
                        "restarted, rate measurement restarts", "info")
            self.stream.restart()
        if self.filter is None:
            fs = self._declared_rate(msg)
            if not math.isfinite(fs):
                fs = self._first_rate(stamps)
            if not math.isfinite(fs):  # still measuring: pass the samples through
                self.stream.accept(int(stamps[0]), x.shape[0])
                self.out_pub.publish(msg)
                return
            self.layout = ST.LayoutTracker(int(self.values["layout_confirm"]))
            self.layout.observe(list(getattr(msg, "channel_names", [])), channels)
            self._declared_fs = self._declared_rate(msg)
            self._build(fs, channels)
            t0 = time.perf_counter()
            mapping = ST.Mapping(np.arange(channels))
        else:
            mapping = self._map_channels(msg, channels)
            declared = self._declared_rate(msg)
            if math.isfinite(declared) and math.isfinite(self._declared_fs) and abs(
                    declared / self._declared_fs - 1.0) > 1e-6:
                self._event("rate_changed", f"declared sample rate changed from "
                            f"{self._declared_fs:g} to {declared:g} Hz: bank re-designed")
                self.filter.set_rate(declared)
                self.stream.restart()
            self._declared_fs = declared
        self.stream.accept(int(stamps[0]), x.shape[0])
        self._check_rate()
        if self._estimate is not None and self.filter.policy.estimate is None:
            self.filter.set_estimate(self._estimate)
        if not np.isfinite(x).all():
            self._event("nonfinite", "non-finite sample values: output NaN there, filter "
                        "memory kept clean")
        t_last = float(stamps[-1]) * 1e-9
        self._last_stamp_s = t_last
        known = mapping.index >= 0
        fill = self._bridge(int(stamps[0]), x, mapping)
        if known.all():
            same = np.array_equal(mapping.index, np.arange(self.filter.channels))
            if fill is not None:  # lost samples and this message in one pass; theirs dropped
                y = self.filter.process(np.vstack([fill, x]), t_last, None if same else
                                        mapping.index)[fill.shape[0]:]
            else:
                y = self.filter.process(x, t_last, None if same else mapping.index)
        else:
            y = x.copy()
            if known.any():
                y[:, known] = self.filter.process(x[:, known], t_last, mapping.index[known])
            else:
                self.filter.policy.advance(t_last, x.shape[0] / self.filter.fs)
        self.out_pub.publish(filled_message(msg, self.kind, y, self.axes))
        self._prev_ns = int(stamps[-1])
        if self._prev_row is None or self._prev_row.size != self.filter.channels:
            self._prev_row = np.full(self.filter.channels, np.nan)
        self._prev_row[mapping.index[known]] = x[-1, known]
        n = x.shape[0]
        self._samples += n
        per_sample = (time.perf_counter() - t0) / n
        self._cost_s = per_sample if self._cost_s == 0 else 0.99 * self._cost_s + 0.01 * per_sample
        self._drain_transitions()
        self._maybe_publish_bank()

    def _bridge(self, first_ns: int, x: np.ndarray, mapping: ST.Mapping) -> np.ndarray | None:
        """Samples lost before this message (counted): the rows of a straight line in their
        place, in the message's channel order, for the filter to run through before the message
        (not published), so its memory keeps the stream's time base; None when there is
        nothing to bridge."""
        fs = self.filter.fs
        missing = ST.missing_samples(self._prev_ns, first_ns, fs)
        if not missing:
            return None
        self._missing += missing
        self._event("gap", f"{missing} sample(s) missing before {first_ns * 1e-9:.6f} s: "
                    "filter memory bridged" if missing <= BRIDGE_S * fs else
                    f"{missing} sample(s) missing before {first_ns * 1e-9:.6f} s: filter goes on",
                    n=missing)
        full = mapping.index.size == self.filter.channels and (mapping.index >= 0).all()
        if missing > BRIDGE_S * fs or not full or self._prev_row is None or \
                self._prev_row.size != self.filter.channels:
            return None
        return ST.bridge(self._prev_row[mapping.index], x[0], missing)

    def _map_channels(self, msg: Any, channels: int) -> ST.Mapping:
        names = list(getattr(msg, "channel_names", []))
        m = self.layout.observe(names, channels)
        if m.event == "reordered":
            self._event("channels_reordered", f"channels reordered ({', '.join(names)}): "
                        "filtered by name")
        elif m.event == "pending":
            self._event("layout_pending", f"new channel layout ({channels} channel(s): "
                        f"{', '.join(names) or 'unnamed'}): known channels filtered, "
                        f"{', '.join(m.unknown) or 'none'} passed through unfiltered until it "
                        f"has come {self.layout.confirm} times in a row")
        elif m.event == "adopted":
            self._event("layout_changed", f"channel layout adopted ({channels} channel(s): "
                        f"{', '.join(names) or 'unnamed'}): known channels keep their filter "
                        "memory, new ones start from their first sample; notches unchanged")
            self.filter.relayout(m.kept)
            self._apply_enable()
        return m

    # ---- outputs ----
    def _bank_msg(self) -> NotchBank:
        st = self.filter.status()
        guaranteed, _ = self.filter.peak_reductions()
        msg = NotchBank()
        ns = int(round(self._last_stamp_s * 1e9)) if math.isfinite(self._last_stamp_s) else (
            self.get_clock().now().nanoseconds)
        msg.header.stamp.sec, msg.header.stamp.nanosec = mc.split_ns(ns)
        notches = []
        for n, pr in zip(st.notches, guaranteed, strict=True):
            m = Notch()
            m.mode_id, m.state = int(n.mode_id), int(n.state)
            m.center_frequency, m.bandwidth, m.depth = (float(n.center), float(n.bandwidth),
                                                        float(n.depth))
            m.shape_depth = float(n.shape_depth)
            m.peak_reduction = float(pr)
            notches.append(m)
        msg.notches = notches
        msg.fallback_active = bool(st.fallback_active)
        msg.estimate_age = float(st.estimate_age)
        msg.bank_state = int(st.bank_state)
        msg.reason = st.reason if st.bank_state != BANK_TRACKING else ""
        msg.crossover_frequency = float(self.filter.policy.config.crossover_frequency)
        msg.phase_lag = float(self.filter.phase_lag())
        return msg

    def _maybe_publish_bank(self) -> None:
        """Publish /notch_bank on a discrete change at once, while notches move at most at
        bank_max_rate."""
        if self.filter is None:
            return
        st = self.filter.status()
        key = tuple((n.mode_id, n.state, round(n.center, 4), round(n.bandwidth, 4),
                     round(n.depth, 2)) for n in st.notches) + (st.bank_state,)
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
        now = time.monotonic()
        for line in self.events.due(now):
            self.get_logger().warning(line)
        flt = self.filter
        st = flt.status() if flt is not None else None
        s = DiagnosticStatus(
            name=f"{self.get_fully_qualified_name().lstrip('/')}: notch bank",
            hardware_id=self.get_fully_qualified_name())
        recent = {k: n for k, n in self.events.recent(now).items() if not k.startswith("bank_")}
        short = [n for n in st.notches if n.limit] if st else []
        if st is None:
            s.level, s.message = DiagnosticStatus.WARN, "waiting for the signal"
        elif st.bank_state != BANK_TRACKING:
            s.level = DiagnosticStatus.WARN
            s.message = f"{BANK_NAMES[st.bank_state]}: {st.reason}"
        elif recent:
            s.level = DiagnosticStatus.WARN
            s.message = "bad input in the last {:g} s: {}".format(
                RECENT_S, ", ".join(f"{k}={v}" for k, v in sorted(recent.items())))
        elif short:
            s.level = DiagnosticStatus.WARN
            s.message = f"peak reduction short of {flt.policy.config.peak_reduction:g} dB: " \
                + "; ".join(f"mode {n.mode_id}: {n.limit}" for n in short)
        else:
            s.level, s.message = DiagnosticStatus.OK, f"{len(st.notches)} notch(es) tracking"
        vals = {
            "bank_state": BANK_NAMES[st.bank_state] if st else "none",
            "reason": st.reason if st else "",
            "estimate_age_s": f"{st.estimate_age:.3f}" if st else "nan",
            "fallback_active": str(st.fallback_active if st else True).lower(),
            "per_sample_cost_us": f"{self._cost_s * 1e6:.2f}",
            "sample_rate_hz": f"{flt.fs:g}" if flt else "nan",
            "measured_rate_hz": f"{self.stream.rate():.4g}",
            "channels": str(flt.channels if flt else 0),
            "samples_filtered": str(self._samples),
            "samples_missing": str(self._missing),
        }
        if st is not None:
            guaranteed, nominal = flt.peak_reductions()
            vals["notches"] = "; ".join(
                f"{STATE_NAMES[n.state]} {n.center:.3f} Hz bw {n.bandwidth:.3f} Hz "
                f"{n.depth:.1f} dB" for n in st.notches)
            vals["peak_reduction_db"] = "; ".join(
                f"mode {n.mode_id}: {g:.1f} guaranteed, {m:.1f} nominal"
                for n, g, m in zip(st.notches, guaranteed, nominal, strict=True) if n.mode_id)
            vals["peak_reduction_required_db"] = f"{flt.policy.config.peak_reduction:g}"
            vals["phase_lag_deg_at_crossover"] = f"{flt.phase_lag():.2f}"
            vals["phase_lag_budget_limited"] = str(st.budget_limited).lower()
            vals["shortfall"] = "; ".join(f"mode {n.mode_id}: {n.limit}" for n in short)
        counts = self.events.counts
        vals["transitions"] = ", ".join(
            f"{k[5:]}={v}" for k, v in sorted(counts.items()) if k.startswith("bank_")) or "none"
        vals["bad_input"] = ", ".join(
            f"{k}={v}" for k, v in sorted(counts.items()) if not k.startswith("bank_")) or "none"
        s.values = [KeyValue(key=k, value=v) for k, v in vals.items()]
        msg = DiagnosticArray(status=[s])
        msg.header.stamp = self.get_clock().now().to_msg()
        self.diag_pub.publish(msg)


def _node_name(args: list[str]) -> str:
    for a in args:
        if a.startswith("__node:=") or a.startswith("__name:="):
            return a.split(":=", 1)[1]
    return "notch_filter_node"


def check_args(args: list[str]) -> str:
    """Parameter files named on the command line, checked before rclpy reads them (which
    would end an unparseable one with a traceback): '' or a one-line reason."""
    name = _node_name(args)
    for i, a in enumerate(args):
        if a == "--params-file" and i + 1 < len(args):
            reason = P.check_params_file(args[i + 1], name)
            if reason:
                return reason
    return ""


def main(args: list[str] | None = None) -> int:
    """Entry point of ``ros2 run notch_filter_node notch_filter_node``."""
    argv = sys.argv if args is None else args
    reason = check_args(list(argv))
    if reason:
        print(f"notch_filter_node: error: {reason}", file=sys.stderr)
        return 1
    try:
        rclpy.init(args=args)
    except Exception as err:  # RCLError on arguments rcl cannot parse: one line, no traceback
        print(f"notch_filter_node: error: {str(err).splitlines()[0]}", file=sys.stderr)
        return 1
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
    except Exception:
        if rclpy.ok():
            raise
        # stopped (SIGINT/SIGTERM) while a message was being taken: rclpy's shutdown raced the
        # take (RuntimeError from take_message with a backlog queued); a requested stop
    finally:
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
    return code


if __name__ == "__main__":
    sys.exit(main())
