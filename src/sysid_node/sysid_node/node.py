"""``sysid_node``: the recursive DSRA on live topics (thin ROS 2 adapter over pipeline.py).

Subscribes to the responses (``output_topic``, default ``/vibration``) and optionally the
excitation (``input_topic``, default ``/excitation``); publishes ``sysid_msgs/ModalEstimate`` on
``/modal_estimate`` (reliable, transient local, depth 1) stamped with the last sample used, and
``diagnostic_msgs/DiagnosticArray`` on ``/diagnostics``. All numerics are in
:class:`sysid_node.pipeline.Pipeline`, which the offline tool drives identically.

Where the time goes, and how it is bounded (measured with py-spy, benchmarks/bench_node.py):
rclpy's executor costs far more per callback than converting a message, so a subscription
callback takes the whole burst waiting in the DDS queue (one wake-up, one conversion without a
Python loop over the values); the burst is handed to the estimator's worker process through
:class:`sysid_node.worker.WorkerLink` (credit-based batching, newest data first when behind);
a receiver thread publishes what comes back. Start-up and shutdown honour any number of
SIGINT/SIGTERM without a traceback (:func:`main`).
"""

from __future__ import annotations

import math
import threading
import time
from collections import Counter
from typing import Any

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rcl_interfaces.msg import SetParametersResult
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

from sysid_msgs.msg import ModalEstimate, ResidualSpectrum
from sysid_node import diagnostics as D
from sysid_node import msg_convert as mc
from sysid_node import node_params as NP
from sysid_node import params as P
from sysid_node.log_throttle import LogThrottle
from sysid_node.records import EstimateRecord
from sysid_node.worker import STALL_S, WorkerLink

ESTIMATE_QOS = QoSProfile(
    history=HistoryPolicy.KEEP_LAST,
    depth=1,
    reliability=ReliabilityPolicy.RELIABLE,
    durability=DurabilityPolicy.TRANSIENT_LOCAL,
)
#: Messages taken from a subscription's queue per callback at most.
MAX_BURST = 5000
#: Kept for callers of the old names: the node never drops data below these (see max_backlog).
BAD_INPUT_KEYS = D.BAD_INPUT_KEYS


class StartupError(RuntimeError):
    """The node cannot start; ``str(err)`` is a one-line reason."""


#: What each kind of parameter does, appended to its description.
KIND_NOTES = {"structural": " (structural: a change resets the estimator)",
              "read_only": " (read-only)", "live": " (live-tunable)"}


def _qos(values: dict[str, Any]) -> QoSProfile:
    reliable = values["qos"] == "reliable"
    return QoSProfile(
        history=HistoryPolicy.KEEP_LAST,
        depth=int(values["qos_depth"]),
        reliability=ReliabilityPolicy.RELIABLE if reliable else ReliabilityPolicy.BEST_EFFORT,
        durability=DurabilityPolicy.VOLATILE,
    )


def _msg_class(kind: str):
    if kind == "Imu":
        from sensor_msgs.msg import Imu

        return Imu
    from sysid_msgs import msg

    return getattr(msg, kind)


class SysidNode(Node):
    """The ROS 2 node; see the module docstring. ``cancelled()`` is polled while the worker
    starts (a stop request during start-up)."""

    def __init__(self, cancelled=lambda: False) -> None:
        super().__init__("sysid_node")
        self.values = self._declare_parameters()
        self._arrivals: Counter[str] = Counter()
        self._last_arrival = math.nan
        self._last_record: EstimateRecord | None = None
        self._last_record_wall = math.nan
        self._latency = math.nan
        self._stop = threading.Event()
        self._diag_lock = threading.Lock()
        self._health_said = 0
        self._say = LogThrottle(self._info)
        self._warn = LogThrottle(self._warning)
        self.worker = WorkerLink(self.values, self._link_log)
        error = self.worker.start(cancelled)
        if error:
            self.worker.stop(timeout=0.5)
            raise StartupError(f"the estimator cannot start: {error}")
        self.estimate_pub = self.create_publisher(ModalEstimate, "modal_estimate", ESTIMATE_QOS)
        self.diag_pub = self.create_publisher(DiagnosticArray, "/diagnostics", 10)
        self.spectrum_pub = self.create_publisher(ResidualSpectrum, "residual_spectrum", 10)
        self._subs: dict[str, Any] = {}
        self._subscribe(self.values)
        self.add_on_set_parameters_callback(self._on_set_parameters)
        self._diag_timer = self.create_timer(1.0 / self.values["diagnostics_rate"],
                                             self._diagnostics)
        self._diag_prev: dict[str, int] = {}
        self._diag_prev_t = time.monotonic()
        self._receiver = threading.Thread(target=self._receive_loop, name="sysid_recv",
                                          daemon=True)
        self._receiver.start()
        v = self.values
        # the names after remapping and namespace, as `ros2 topic list` shows them
        names = [self._subs[s].topic_name for s in ("output", "input") if s in self._subs]
        mode = "output-only" if len(names) < 2 else (
            f"inputs from {names[1]} ({v['input_type']})")
        self.get_logger().info(
            f"identifying modes from {names[0]} ({v['output_type']}), {mode}; "
            f"publishing {self.estimate_pub.topic_name} at {v['publish_rate']:g} Hz of "
            f"data time, {self.spectrum_pub.topic_name}, /diagnostics")

    # ---- parameters ----
    def _declare_parameters(self) -> dict[str, Any]:
        try:
            values = NP.declare(self, P.PARAMS, KIND_NOTES)
        except NP.ParameterError as err:
            raise StartupError(str(err)) from None
        reason = P.validate_set(values)
        if reason:
            raise StartupError(f"invalid parameters: {reason}")
        return values

    def _on_set_parameters(self, parameters: list[Parameter]) -> SetParametersResult:
        # parameters rclpy owns (use_sim_time, ...) are not ours to check
        changes = {p.name: p.value for p in parameters if p.name in P.SPECS}
        if not changes:
            return SetParametersResult(successful=True)
        old = dict(self.values)
        new = {**old, **changes}
        fs = self.worker.status.get("fs", math.nan)
        if new["sample_rate"] != old["sample_rate"]:
            fs = math.nan
        reason = P.validate_set(new, sample_rate=fs)
        if reason:
            self.get_logger().warning(f"parameter change rejected: {reason}")
            return SetParametersResult(successful=False, reason=reason)
        self.values = new
        self.worker.set_parameters(changes)
        topic_keys = ("output_topic", "output_type", "input_topic", "input_type", "output_only",
                      "qos", "qos_depth", "imu_axes")
        if any(old[k] != new[k] for k in topic_keys):
            self._subscribe(new)
        if old["diagnostics_rate"] != new["diagnostics_rate"]:
            self._diag_timer.cancel()
            self.destroy_timer(self._diag_timer)
            self._diag_timer = self.create_timer(1.0 / new["diagnostics_rate"],
                                                 self._diagnostics)
        return SetParametersResult(successful=True)

    # ---- subscriptions ----
    def _subscribe(self, values: dict[str, Any]) -> None:
        for s in self._subs.values():
            self.destroy_subscription(s)
        self._subs = {}
        qos = _qos(values)
        axes = P.parse_axes(values["imu_axes"])
        streams = [("output", values["output_topic"], values["output_type"])]
        if values["input_topic"] and not values["output_only"]:
            streams.append(("input", values["input_topic"], values["input_type"]))
        if values["scheduling_topic"]:  # online LPV: to the worker like the data
            streams.append(("scheduling", values["scheduling_topic"], "SignalSample"))
        for stream, topic, kind in streams:
            def callback(msg, stream=stream, kind=kind):
                self._on_burst(stream, kind, axes, msg)

            self._subs[stream] = self.create_subscription(_msg_class(kind), topic, callback, qos)

    def _take_burst(self, stream: str, first: Any) -> list[Any]:
        """``first`` and every message already waiting in the subscription's queue: one
        executor wake-up per burst instead of one per message."""
        msgs = [first]
        sub = self._subs.get(stream)
        if sub is None:
            return msgs
        try:
            with sub.handle:
                while len(msgs) < MAX_BURST:
                    got = sub.handle.take_message(sub.msg_type, sub.raw)
                    if got is None:
                        break
                    msgs.append(got[0])
        except Exception:  # destroyed meanwhile (re-subscription): keep what we have
            pass
        return msgs

    def _on_burst(self, stream: str, kind: str, axes: list[str], first: Any) -> None:
        """One wake-up takes what waits on every data topic, this one first: the streams go
        to the worker together (an output burst covering seconds while the input waits in
        its queue would look like a stopped input)."""
        self._convert(stream, kind, axes, self._take_burst(stream, first))
        v = self.values
        for other in ("output", "input"):
            sub = self._subs.get(other)
            if other == stream or sub is None:
                continue
            try:
                with sub.handle:
                    got = sub.handle.take_message(sub.msg_type, sub.raw)
            except Exception:
                continue
            if got is not None:
                self._convert(other, v[f"{other}_type"], axes,
                              self._take_burst(other, got[0]))

    def _convert(self, stream: str, kind: str, axes: list[str], msgs: list[Any]) -> None:
        blocks, errors = mc.burst_to_blocks(msgs, kind, axes)
        if errors:
            self._arrivals[f"{stream}_unreadable"] += len(errors)
            self._warn.emit(f"{stream}: unreadable message(s), {len(errors)} dropped: "
                            f"{errors[-1]}")
        good = len(msgs) - len(errors)
        if blocks and len(blocks[-1][0]):
            self.worker.stages.add("arrival", (time.time_ns() - int(blocks[-1][0][-1])) * 1e-9)
        self._arrivals[f"{stream}_messages"] += good
        self._last_arrival = time.monotonic()
        self.worker.submit(stream, blocks, good)

    # ---- estimates ----
    def _receive_loop(self) -> None:
        """Publish the worker's estimates, log its lines, restart it if it died."""
        while not self._stop.is_set():
            rep = self.worker.receive(timeout=0.2)
            if rep is None:
                if not self.worker.alive and not self._stop.is_set():
                    self.get_logger().error("the estimator process died: restarting it "
                                            "(the estimate starts again)")
                    error = self.worker.restart()
                    if error:
                        self.get_logger().error(f"estimator restart failed: {error}",
                                                throttle_duration_sec=10.0)
                        time.sleep(1.0)
                continue
            for line in rep.lines:
                if line.startswith("ERROR "):
                    self.get_logger().error(line[6:], throttle_duration_sec=5.0)
                elif line.startswith("WARN "):
                    self._warn.emit(line[5:])
                else:
                    self._say.emit(line)
            for r in rep.records:
                self._publish(r)
            if rep.records and rep.records[-1].health != self._health_said:
                self._health_said = rep.records[-1].health
                self._diagnostics()  # a change of health is said at once, not at the next tick
            for sp in rep.spectra:
                self.spectrum_pub.publish(mc.residual_spectrum_msg(sp))
            self.worker.check_backlog()

    def _node_faults(self) -> list[tuple[int, str]]:
        return D.node_health(self.worker.alive, self.worker.stalled_s(), self.worker.backlog_s(),
                             self.values["backlog_warning"], STALL_S)

    def _publish(self, r: EstimateRecord) -> None:
        r.health, r.health_reason = D.merge_health(r.health, r.health_reason,
                                                   self._node_faults())
        self.estimate_pub.publish(mc.estimate_msg(r))
        self._last_record = r
        self._last_record_wall = time.monotonic()
        self._latency = (self.get_clock().now().nanoseconds - r.stamp_ns) * 1e-9
        self.worker.stages.add("estimate", (time.time_ns() - r.stamp_ns) * 1e-9)

    # one call site per severity: rclpy refuses two severities from one line
    def _info(self, text: str) -> None:
        self.get_logger().info(text)

    def _warning(self, text: str) -> None:
        self.get_logger().warning(text)

    def _error(self, text: str) -> None:
        self.get_logger().error(text)

    def _link_log(self, level: str, text: str) -> None:
        {"info": self._info, "warn": self._warning, "error": self._error}[level](text)

    # ---- diagnostics ----
    def _diagnostics(self) -> None:
        with self._diag_lock:
            self._diagnostics_now()

    def _diagnostics_now(self) -> None:
        now = time.monotonic()
        dt = max(now - self._diag_prev_t, 1e-6)
        st = self.worker.status
        counters, rates, values = st.get("counters", {}), st.get("rates", {}), self.values
        fs, mode, cost = st.get("fs", math.nan), st.get("mode", "pending"), st.get("cost", math.nan)
        arrivals = {**self._arrivals, **self.worker.counters}
        r = self._last_record
        faults = self._node_faults()
        if r is not None and r.health > D.HEALTH_OK:
            faults.append((r.health, r.health_reason))
        if st.get("band_warning"):  # the band does not fit the data's rate: said, not a fault
            faults.append((D.HEALTH_DEGRADED, st["band_warning"]))
        backlog = self.worker.backlog_s()
        kv: dict[str, Any] = {
            "output_topic": self._topic("output"),
            "input_topic": self._topic("input") if mode == "io" else "",
            "mode": mode,
            "health": D.HEALTH_NAMES[max((lv for lv, _ in faults), default=0)],
            "health_reason": "; ".join(why for lv, why in faults if lv > 0),
            "sample_rate_hz": fs,
            "identification_rate_hz": st.get("id_fs", math.nan),
            "output_rate_hz": rates.get("output", math.nan),
            "input_rate_hz": rates.get("input", math.nan),
            "forgetting_factor": st.get("lambda", values["forgetting_factor"]),
            "converged": bool(r.converged) if r else False,
            "samples_used": r.samples_used if r else 0,
            "modes_tracked": sum(m.status == "tracked" for m in r.modes) if r else 0,
            "prediction_error_rms": r.prediction_error_rms if r else math.nan,
            "update_cost_us_per_sample": cost * 1e6,
            "realtime_factor": 1.0 / (cost * fs) if cost > 0 and fs > 0 else math.nan,
            "estimate_latency_s": self._latency,
            "last_estimate_age_s": now - self._last_record_wall,
            "backlog_s": backlog,
            "data_backlog_s": self.worker.data_backlog_s(),
            "queued_messages": self.worker.queued_messages(),
            "worker_alive": self.worker.alive,
            **st.get("scheduling", {}),  # online LPV: scheduling_value, _age_s, lpv_in_range
            **self.worker.stages.percentiles(),
        }
        for k, v in sorted(arrivals.items()):
            kv[k] = v
            if k.endswith("_messages"):
                kv[k.replace("_messages", "_message_rate_hz")] = (
                    (v - self._diag_prev.get(k, 0)) / dt)
        for k, v in sorted(counters.items()):
            kv[k] = v
        merged = {**counters, **arrivals}
        bad_now = sum(v for k, v in merged.items() if D.is_bad_input(k))
        bad_before = sum(v for k, v in self._diag_prev.items() if D.is_bad_input(k))
        stale = not math.isfinite(self._last_arrival) or now - self._last_arrival > 2.0
        level, message = D.summary(kv, bad_now - bad_before, stale,
                                   bool(r and r.converged), faults)
        status = DiagnosticStatus(
            level=bytes([level]), message=message,
            name=f"{self.get_fully_qualified_name().lstrip('/')}: identification",
            hardware_id=self._topic("output") or values["output_topic"],
            values=[KeyValue(key=k, value=D.fmt(v)) for k, v in kv.items() if v is not None],
        )
        arr = DiagnosticArray(status=[status])
        arr.header.stamp = self.get_clock().now().to_msg()
        self.diag_pub.publish(arr)
        self._diag_prev = merged
        self._diag_prev_t = now
        self._say.flush()
        self._warn.flush()

    def _topic(self, stream: str) -> str:
        """The resolved name (namespace, remapping) of a stream's topic, '' if none."""
        sub = self._subs.get(stream)
        return sub.topic_name if sub is not None else ""

    def stop(self) -> None:
        """Stop the receiver thread and the worker process (within about 3 s)."""
        self._stop.set()
        self.worker.stop(timeout=1.5)
        self._receiver.join(timeout=1.0)
        self._say.flush(force=True)
        self._warn.flush(force=True)
