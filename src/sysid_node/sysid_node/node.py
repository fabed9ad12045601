"""``sysid_node``: the recursive DSRA on live topics (thin ROS 2 adapter over pipeline.py).

Subscribes to the responses (``output_topic``, default ``/vibration``) and optionally the
excitation (``input_topic``, default ``/excitation``); publishes ``sysid_msgs/ModalEstimate`` on
``/modal_estimate`` (reliable, transient local, depth 1) stamped with the last sample used, and
``diagnostic_msgs/DiagnosticArray`` on ``/diagnostics``. All numerics are in
:class:`sysid_node.pipeline.Pipeline`, which the offline tool drives identically.

Processes: subscription callbacks only convert a message to arrays and queue it; a sender
thread hands the queued blocks to a worker *process* that runs the pipeline (so the estimator
never holds the GIL the subscriptions need, and uses the second core); a receiver thread
publishes what comes back. When the worker falls more than ``MAX_BACKLOG_S`` seconds of data
behind (or ``MAX_BACKLOG_SAMPLES``), whole batches are dropped and counted
(``overload_dropped_messages``) rather than lost silently in the DDS queues.
"""

from __future__ import annotations

import math
import multiprocessing as mp
import queue
import sys
import threading
import time
from collections import Counter, deque
from typing import Any

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
)

from sysid_msgs.msg import ResidualSpectrum
from sysid_node import msg_convert as mc
from sysid_node import node_params as NP
from sysid_node import params as P
from sysid_node.pipeline import worker_main
from sysid_node.records import EstimateRecord, stack_blocks

ESTIMATE_QOS = QoSProfile(
    history=HistoryPolicy.KEEP_LAST,
    depth=1,
    reliability=ReliabilityPolicy.RELIABLE,
    durability=DurabilityPolicy.TRANSIENT_LOCAL,
)
#: Data the worker may be behind before batches are dropped: this many seconds of data or
#: samples (over both streams), whichever is more.
MAX_BACKLOG_S = 60.0
MAX_BACKLOG_SAMPLES = 200_000
BAD_INPUT_KEYS = (
    "malformed", "wrong_channels", "nonfinite", "duplicate", "late", "rate_rejected",
    "unreadable", "overload_dropped_messages",
)


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
    """The ROS 2 node; see the module docstring."""

    def __init__(self) -> None:
        super().__init__("sysid_node")
        try:
            values = NP.declare(self, P.PARAMS, KIND_NOTES)
        except NP.ParameterError as err:
            raise StartupError(str(err)) from None
        reason = P.validate_set(values)
        if reason:
            raise StartupError(f"invalid parameters: {reason}")
        self.values = values
        self._queue: deque = deque()
        self._wake = threading.Event()
        self._stop = threading.Event()
        self._arrivals: Counter[str] = Counter()
        self._last_arrival = math.nan
        self._last_record: EstimateRecord | None = None
        self._latency = math.nan
        self._status: dict[str, Any] = {"counters": {}, "rates": {}, "fs": math.nan,
                                        "mode": "pending", "cost": math.nan,
                                        "lambda": values["forgetting_factor"], "values": values}
        self._in_flight = 0  # samples sent to the worker and not yet processed
        self._channel_names: dict[str, list[str]] = {}
        self._start_worker(values)
        self.estimate_pub = self.create_publisher(
            mc_estimate_type(), "modal_estimate", ESTIMATE_QOS
        )
        self.diag_pub = self.create_publisher(DiagnosticArray, "/diagnostics", 10)
        self.spectrum_pub = self.create_publisher(
            ResidualSpectrum, "residual_spectrum", 10)
        self._subs: list = []
        self._subscribe(values)
        self.add_on_set_parameters_callback(self._on_set_parameters)
        self._diag_timer = self.create_timer(1.0 / values["diagnostics_rate"], self._diagnostics)
        self._diag_prev: dict[str, int] = {}
        self._diag_prev_t = time.monotonic()
        self._sender = threading.Thread(target=self._send_loop, name="sysid_send", daemon=True)
        self._receiver = threading.Thread(target=self._receive_loop, name="sysid_recv",
                                          daemon=True)
        self._sender.start()
        self._receiver.start()
        # the names after remapping and namespace, as `ros2 topic list` shows them
        names = [s.topic_name for s in self._subs]
        mode = "output-only" if len(names) < 2 else (
            f"inputs from {names[1]} ({values['input_type']})")
        self.get_logger().info(
            f"identifying modes from {names[0]} ({values['output_type']}), {mode}; "
            f"publishing {self.estimate_pub.topic_name} at {values['publish_rate']:g} Hz of "
            f"data time, {self.spectrum_pub.topic_name}, /diagnostics"
        )

    def _start_worker(self, values: dict[str, Any]) -> None:
        ctx = mp.get_context("spawn")  # never fork a process that runs DDS threads
        self._inbox, self._outbox = ctx.Queue(), ctx.Queue()
        self._proc = ctx.Process(target=worker_main, args=(values, self._inbox, self._outbox),
                                 name="sysid_worker", daemon=True)
        self._proc.start()
        try:
            tag, error = self._outbox.get(timeout=60.0)
        except queue.Empty:
            error = "the worker process did not start within 60 s"
        if error:
            self._proc.terminate()
            raise StartupError(f"the estimator cannot start: {error}")

    # ---- parameters ----
    def _on_set_parameters(self, parameters: list[Parameter]) -> SetParametersResult:
        # parameters rclpy owns (use_sim_time, ...) are not ours to check
        changes = {p.name: p.value for p in parameters if p.name in P.SPECS}
        if not changes:
            return SetParametersResult(successful=True)
        old = dict(self.values)
        new = {**old, **changes}
        fs = self._status["fs"] if new["sample_rate"] == old["sample_rate"] else math.nan
        reason = P.validate_set(new, sample_rate=fs)
        if reason:
            self.get_logger().warning(f"parameter change rejected: {reason}")
            return SetParametersResult(successful=False, reason=reason)
        self.values = new
        self._inbox.put(("params", changes))
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
        for s in self._subs:
            self.destroy_subscription(s)
        self._subs = []
        qos = _qos(values)
        axes = P.parse_axes(values["imu_axes"])
        streams = [("output", values["output_topic"], values["output_type"])]
        if values["input_topic"] and not values["output_only"]:
            streams.append(("input", values["input_topic"], values["input_type"]))
        for stream, topic, kind in streams:
            def callback(msg, stream=stream, kind=kind):
                self._on_message(stream, kind, axes, msg)

            self._subs.append(self.create_subscription(_msg_class(kind), topic, callback, qos))

    def _on_message(self, stream: str, kind: str, axes: list[str], msg: Any) -> None:
        try:
            t, v = mc.to_arrays(msg, kind, axes)
        except (ValueError, TypeError, AttributeError) as err:
            self._arrivals[f"{stream}_unreadable"] += 1
            self.get_logger().warning(f"{stream}: unreadable message: {err}",
                                      throttle_duration_sec=5.0)
            return
        self._arrivals[f"{stream}_messages"] += 1
        self._last_arrival = time.monotonic()
        names = mc.channel_names(msg, kind, axes)
        if names != self._channel_names.get(stream):  # first message, or renamed channels
            self._channel_names[stream] = names
            self._inbox.put(("names", stream, names))
        self._queue.append((stream, t, v))
        self._wake.set()

    # ---- processing ----
    def _send_loop(self) -> None:
        """Hand queued message blocks to the worker process every few milliseconds."""
        while not self._stop.is_set():
            self._wake.wait(0.05)
            time.sleep(0.002)  # let a burst of messages gather
            self._wake.clear()
            items = []
            while self._queue:
                items.append(self._queue.popleft())
            if not items:
                continue
            fs = self._status["fs"]
            limit = max(MAX_BACKLOG_S * (fs if math.isfinite(fs) else 0.0), MAX_BACKLOG_SAMPLES)
            if self._in_flight > limit:
                self._arrivals["overload_dropped_messages"] += len(items)
                self.get_logger().warning(
                    f"estimator {self._in_flight} samples behind: {len(items)} message(s) "
                    "dropped", throttle_duration_sec=5.0)
                continue
            # one array per stream and channel count: far less to pickle than many small ones
            stacked = [
                (stream, t, v)
                for stream in ("output", "input")
                for t, v in stack_blocks([(t, v) for s_, t, v in items if s_ == stream])
            ]
            n = sum(len(t) for _, t, _ in stacked)
            self._in_flight += n
            self._inbox.put(("data", stacked, n))

    def _receive_loop(self) -> None:
        """Publish the worker's estimates, log its lines, keep its status."""
        while not self._stop.is_set():
            try:
                records, lines, status, n_msgs, spectra = self._outbox.get(timeout=0.2)
            except queue.Empty:
                continue
            except (EOFError, OSError, ValueError):
                break
            self._in_flight -= n_msgs
            self._status = status
            for line in lines:
                if line.startswith("ERROR "):
                    self.get_logger().error(line[6:], throttle_duration_sec=5.0)
                else:
                    self.get_logger().info(line)
            for r in records:
                self._publish(r)
            for sp in spectra:
                self.spectrum_pub.publish(mc.residual_spectrum_msg(sp))

    def _publish(self, r: EstimateRecord) -> None:
        self.estimate_pub.publish(mc.estimate_msg(r))
        self._last_record = r
        now = self.get_clock().now().nanoseconds
        self._latency = (now - r.stamp_ns) * 1e-9

    # ---- diagnostics ----
    def _diagnostics(self) -> None:
        now = time.monotonic()
        dt = max(now - self._diag_prev_t, 1e-6)
        st = self._status
        counters, rates, values = st["counters"], st["rates"], self.values
        fs, mode, cost = st["fs"], st["mode"], st["cost"]
        arrivals = dict(self._arrivals)
        r = self._last_record
        kv: dict[str, Any] = {
            "output_topic": self._subs[0].topic_name if self._subs else "",
            "input_topic": self._subs[1].topic_name if mode == "io" and len(self._subs) > 1
            else "",
            "mode": mode,
            "sample_rate_hz": fs,
            "identification_rate_hz": st.get("id_fs", math.nan),
            "output_rate_hz": rates.get("output", math.nan),
            "input_rate_hz": rates.get("input", math.nan),
            "forgetting_factor": st["lambda"],
            "converged": bool(r.converged) if r else False,
            "samples_used": r.samples_used if r else 0,
            "modes_tracked": sum(m.status == "tracked" for m in r.modes) if r else 0,
            "prediction_error_rms": r.prediction_error_rms if r else math.nan,
            "update_cost_us_per_sample": cost * 1e6,
            "realtime_factor": 1.0 / (cost * fs) if cost > 0 and fs > 0 else math.nan,
            "estimate_latency_s": self._latency,
            "queued_messages": len(self._queue) + self._in_flight,
        }
        for k, v in sorted(arrivals.items()):
            kv[k] = v
            kv[k.replace("_messages", "_message_rate_hz")] = (
                (v - self._diag_prev.get(k, 0)) / dt if k.endswith("_messages") else None)
        for k, v in sorted(counters.items()):
            kv[k] = v
        bad_now = sum(v for k, v in {**counters, **arrivals}.items()
                      if k.endswith(BAD_INPUT_KEYS) or k in ("gaps", "time_resets"))
        bad_before = sum(v for k, v in self._diag_prev.items() if k.endswith(BAD_INPUT_KEYS) or
                         k in ("gaps", "time_resets"))
        stale = not math.isfinite(self._last_arrival) or now - self._last_arrival > 2.0
        if stale:
            level, message = DiagnosticStatus.STALE, "no data received"
        elif bad_now > bad_before:
            level, message = DiagnosticStatus.WARN, f"{bad_now - bad_before} bad input event(s)"
        elif not (r and r.converged):
            level, message = DiagnosticStatus.WARN, "not converged yet"
        else:
            level, message = DiagnosticStatus.OK, "tracking"
        status = DiagnosticStatus(
            level=level,
            name=f"{self.get_fully_qualified_name().lstrip('/')}: identification",
            message=message,
            hardware_id=self._subs[0].topic_name if self._subs else values["output_topic"],
            values=[KeyValue(key=k, value=_fmt(v)) for k, v in kv.items() if v is not None],
        )
        arr = DiagnosticArray(status=[status])
        arr.header.stamp = self.get_clock().now().to_msg()
        self.diag_pub.publish(arr)
        self._diag_prev = {**counters, **arrivals}
        self._diag_prev_t = now

    def _log(self, text: str) -> None:
        self.get_logger().info(text)

    def stop(self) -> None:
        """Stop the threads and the worker process (within a few seconds)."""
        self._stop.set()
        self._wake.set()
        self._sender.join(timeout=2.0)
        try:
            self._inbox.put(None)
        except (OSError, ValueError):
            pass
        self._proc.join(timeout=3.0)
        if self._proc.is_alive():
            self._proc.terminate()
            self._proc.join(timeout=2.0)
        self._receiver.join(timeout=2.0)
        self._inbox.cancel_join_thread()
        self._outbox.cancel_join_thread()


def mc_estimate_type():
    from sysid_msgs.msg import ModalEstimate

    return ModalEstimate


def _fmt(v: Any) -> str:
    if isinstance(v, bool):
        return str(v).lower()
    if isinstance(v, float):
        return "nan" if math.isnan(v) else f"{v:.6g}"
    return str(v)


def main(args: list[str] | None = None) -> int:
    """Entry point of ``ros2 run sysid_node sysid_node``."""
    # hand the GIL over often, so subscriptions are served while the worker computes
    sys.setswitchinterval(0.001)
    rclpy.init(args=args)
    node = None
    code = 0
    try:
        node = SysidNode()
        rclpy.spin(node)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except StartupError as err:
        print(f"sysid_node: error: {err}", file=sys.stderr)
        code = 1
    finally:
        if node is not None:
            node.stop()
            node.destroy_node()
        rclpy.try_shutdown()
    return code


if __name__ == "__main__":
    sys.exit(main())
