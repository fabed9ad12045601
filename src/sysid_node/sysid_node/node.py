"""``sysid_node``: the recursive DSRA on live topics (thin ROS 2 adapter over pipeline.py).

Subscribes to the responses (``output_topic``, default ``/vibration``) and optionally the
excitation (``input_topic``, default ``/excitation``); publishes ``sysid_msgs/ModalEstimate`` on
``/modal_estimate`` (reliable, transient local, depth 1) stamped with the last sample used, and
``diagnostic_msgs/DiagnosticArray`` on ``/diagnostics``. All numerics are in
:class:`sysid_node.pipeline.Pipeline`, which the offline tool drives identically.

Where the time goes, and how it is bounded (measured with py-spy, benchmarks/bench_node.py):
rclpy's executor costs far more per wake-up than converting a message, and building one rclpy
message object per sample costs more than decoding it. So the data subscriptions are never
served by the executor (their callback group refuses execution): a reader thread takes every
message waiting on every data topic each ``POLL_S`` seconds, serialized (``raw=True``), and
decodes each burst as one array (:mod:`sysid_node.cdr`; per message only when a burst mixes
layouts). The executor serves only the parameter services and the diagnostics timer, which
therefore never delay data. The burst is handed to the estimator's worker process through
:class:`sysid_node.worker.WorkerLink` (credit-based batching, newest data first when behind);
a receiver thread publishes what comes back. Start-up and shutdown honour any number of
SIGINT/SIGTERM without a traceback (:mod:`sysid_node.entry`).
"""

from __future__ import annotations

import math
import threading
import time
from collections import Counter
from typing import Any

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rcl_interfaces.msg import SetParametersResult
from rclpy.callback_groups import CallbackGroup
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
#: Messages taken from a subscription's queue per poll at most.
MAX_BURST = 5000
#: The reader thread takes what waits on the data topics this often [s] (its latency is at
#: most this; one wake-up per poll, whatever the message rate).
POLL_S = 0.005
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


class _Polled(CallbackGroup):
    """Callback group of the data subscriptions: the executor never waits on nor executes
    them (the node's reader thread takes their messages)."""

    def can_execute(self, entity: Any) -> bool:
        return False

    def beginning_execution(self, entity: Any) -> bool:
        return False

    def ending_execution(self, entity: Any) -> None:
        pass


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
        self._subs_lock = threading.Lock()
        self._polled = _Polled()
        self._subscribe(self.values)
        self.add_on_set_parameters_callback(self._on_set_parameters)
        self._diag_timer = self.create_timer(1.0 / self.values["diagnostics_rate"],
                                             self._diagnostics)
        self._diag_prev: dict[str, int] = {}
        self._diag_prev_t = time.monotonic()
        self._receiver = threading.Thread(target=self._receive_loop, name="sysid_recv",
                                          daemon=True)
        self._receiver.start()
        self._reader = threading.Thread(target=self._read_loop, name="sysid_read", daemon=True)
        self._reader.start()
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
        with self._subs_lock:
            for s in self._subs.values():
                self.destroy_subscription(s)
            self._subs, self._kinds = {}, {}
            qos = _qos(values)
            self._axes = P.parse_axes(values["imu_axes"])
            streams = [("output", values["output_topic"], values["output_type"])]
            if values["input_topic"] and not values["output_only"]:
                streams.append(("input", values["input_topic"], values["input_type"]))
            if values["scheduling_topic"]:  # online LPV: to the worker like the data
                streams.append(("scheduling", values["scheduling_topic"], "SignalSample"))
            for stream, topic, kind in streams:
                sub = self.create_subscription(mc.signal_msg_class(kind), topic, _never_called, qos,
                                               callback_group=self._polled, raw=True)
                self._subs[stream], self._kinds[stream] = sub, kind

    def _read_loop(self) -> None:
        """Every POLL_S: take what waits on each data topic (output first), convert each
        burst, hand it to the worker. Both streams go over together (an output burst covering
        seconds while the input waited in its queue would look like a stopped input)."""
        next_poll = time.monotonic()
        while not self._stop.is_set():
            try:
                with self._subs_lock:
                    bursts = [(stream, self._kinds[stream], self._take(sub))
                              for stream, sub in self._subs.items()]
                for stream, kind, raws in bursts:
                    if raws:
                        self._convert(stream, kind, raws)
            except Exception as err:  # never lose the reader: say it and go on
                self._warn.emit(f"reading the data topics failed: {err!r}")
            next_poll = max(next_poll + POLL_S, time.monotonic())
            self._stop.wait(next_poll - time.monotonic())

    @staticmethod
    def _take(sub: Any) -> list[bytes]:
        """Every serialized message waiting in ``sub``'s queue (at most MAX_BURST)."""
        raws: list[bytes] = []
        try:
            with sub.handle:
                while len(raws) < MAX_BURST:
                    got = sub.handle.take_message(sub.msg_type, True)
                    if got is None:
                        break
                    raws.append(got[0])
        except Exception:  # destroyed meanwhile (re-subscription): keep what we have
            pass
        return raws

    def _convert(self, stream: str, kind: str, raws: list[bytes]) -> None:
        blocks, errors = mc.serialized_burst_to_blocks(raws, kind, self._axes)
        if errors:
            self._arrivals[f"{stream}_unreadable"] += len(errors)
            self._warn.emit(f"{stream}: unreadable message(s), {len(errors)} dropped: "
                            f"{errors[-1]}")
        good = len(raws) - len(errors)
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
                                                   D.estimate_faults(self._node_faults()))
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
            "band_split_hz": st.get("split_hz", math.nan),
            "low_band_rate_hz": st.get("low_fs", math.nan),
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
        """Stop the reader and receiver threads and the worker process (within about 3 s)."""
        self._stop.set()
        self._reader.join(timeout=0.5)
        self.worker.stop(timeout=1.5)
        self._receiver.join(timeout=1.0)
        self._say.flush(force=True)
        self._warn.flush(force=True)


def _never_called(_msg: Any) -> None:
    """Callback of the data subscriptions (the reader thread takes their messages)."""

