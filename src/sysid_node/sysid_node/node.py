"""``sysid_node``: the recursive DSRA on live topics (thin ROS 2 adapter over pipeline.py).

Subscribes to the responses (``output_topic``, default ``/vibration``) and optionally the
excitation (``input_topic``, default ``/excitation``); publishes ``sysid_msgs/ModalEstimate`` on
``/modal_estimate`` (reliable, transient local, depth 1) stamped with the last sample used, and
``diagnostic_msgs/DiagnosticArray`` on ``/diagnostics``. All numerics are in
:class:`sysid_node.pipeline.Pipeline`, which the offline tool drives identically.

Threads: subscription callbacks only convert a message to arrays and queue it; a worker thread
drains the queue in blocks, runs the pipeline (numpy releases the GIL in the heavy parts) and
publishes, so a realization never holds up the subscriptions.
"""

from __future__ import annotations

import math
import sys
import threading
import time
from collections import Counter, deque
from typing import Any

import rclpy
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rcl_interfaces.msg import (
    FloatingPointRange,
    IntegerRange,
    ParameterDescriptor,
    SetParametersResult,
)
from rclpy.exceptions import (
    InvalidParameterTypeException,
    InvalidParameterValueException,
    ParameterException,
)
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import (
    DurabilityPolicy,
    HistoryPolicy,
    QoSProfile,
    ReliabilityPolicy,
)

from sysid_node import msg_convert as mc
from sysid_node import params as P
from sysid_node.pipeline import EstimateRecord, Pipeline

ESTIMATE_QOS = QoSProfile(
    history=HistoryPolicy.KEEP_LAST,
    depth=1,
    reliability=ReliabilityPolicy.RELIABLE,
    durability=DurabilityPolicy.TRANSIENT_LOCAL,
)
BAD_INPUT_KEYS = (
    "malformed", "wrong_channels", "nonfinite", "duplicate", "late", "rate_rejected",
)


class StartupError(RuntimeError):
    """The node cannot start; ``str(err)`` is a one-line reason."""


def descriptor(spec: P.ParamSpec) -> ParameterDescriptor:
    """ROS parameter descriptor (description, range, read-only) of a parameter spec."""
    text = spec.description
    if spec.choices:
        text += f" [{'|'.join(spec.choices)}]"
    text += {"structural": " (structural: a change resets the estimator)",
             "read_only": " (read-only)", "live": " (live-tunable)"}[spec.kind]
    d = ParameterDescriptor(description=text, read_only=spec.kind == "read_only")
    if spec.type is float:
        d.floating_point_range = [FloatingPointRange(from_value=float(spec.lo),
                                                     to_value=float(spec.hi))]
    elif spec.type is int:
        d.integer_range = [IntegerRange(from_value=int(spec.lo), to_value=int(spec.hi))]
    if spec.choices:
        d.additional_constraints = "one of: " + ", ".join(spec.choices)
    return d


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
        self._coerce_int_overrides()
        try:
            for spec in P.PARAMS:
                self.declare_parameter(spec.name, spec.default, descriptor(spec))
        except (InvalidParameterValueException, InvalidParameterTypeException,
                ParameterException) as err:
            raise StartupError(str(err).splitlines()[0]) from None
        values = {s.name: self.get_parameter(s.name).value for s in P.PARAMS}
        reason = P.validate_set(values)
        if reason:
            raise StartupError(f"invalid parameters: {reason}")
        self._lock = threading.Lock()
        self._queue: deque = deque()
        self._wake = threading.Event()
        self._stop = threading.Event()
        self._arrivals: Counter[str] = Counter()
        self._last_arrival = math.nan
        self._last_record: EstimateRecord | None = None
        self._last_publish_wall = math.nan
        self._latency = math.nan
        try:
            self.pipeline = Pipeline(values, log=self._log)
        except ImportError as err:
            raise StartupError(f"the DSRA core cannot be imported: {err}") from None
        self.estimate_pub = self.create_publisher(
            mc_estimate_type(), "/modal_estimate", ESTIMATE_QOS
        )
        self.diag_pub = self.create_publisher(DiagnosticArray, "/diagnostics", 10)
        self._subs: list = []
        self._subscribe(values)
        self.add_on_set_parameters_callback(self._on_set_parameters)
        self._diag_timer = self.create_timer(1.0 / values["diagnostics_rate"], self._diagnostics)
        self._diag_prev: dict[str, int] = {}
        self._diag_prev_t = time.monotonic()
        self._worker = threading.Thread(target=self._work, name="sysid_worker", daemon=True)
        self._worker.start()
        mode = "output-only" if values["output_only"] or not values["input_topic"] else (
            f"inputs from {values['input_topic']} ({values['input_type']})")
        self.get_logger().info(
            f"identifying modes from {values['output_topic']} ({values['output_type']}), {mode}; "
            f"publishing /modal_estimate at {values['publish_rate']:g} Hz of data time"
        )

    # ---- parameters ----
    def _coerce_int_overrides(self) -> None:
        """Accept ``sample_rate: 100`` (an integer) for a float parameter, as users write it."""
        overrides = getattr(self, "_parameter_overrides", None)
        if not isinstance(overrides, dict):
            return
        for name, p in list(overrides.items()):
            spec = P.SPECS.get(name)
            if spec and spec.type is float and p.type_ == Parameter.Type.INTEGER:
                overrides[name] = Parameter(name, Parameter.Type.DOUBLE, float(p.value))

    def _on_set_parameters(self, parameters: list[Parameter]) -> SetParametersResult:
        changes = {p.name: p.value for p in parameters}
        old = dict(self.pipeline.values)
        with self._lock:
            reason = self.pipeline.set_parameters(changes)
        if reason:
            self.get_logger().warning(f"parameter change rejected: {reason}")
            return SetParametersResult(successful=False, reason=reason)
        new = self.pipeline.values
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
        self._queue.append((stream, t, v))
        self._wake.set()

    # ---- processing ----
    def _work(self) -> None:
        while not self._stop.is_set():
            self._wake.wait(0.05)
            self._wake.clear()
            if not self._queue:
                continue
            items = []
            while self._queue:
                items.append(self._queue.popleft())
            try:
                with self._lock:
                    records = self._process(items)
            except Exception as err:  # keep running on anything the data throws at us
                self.get_logger().error(f"processing failed, estimator reset: {err!r}",
                                        throttle_duration_sec=5.0)
                with self._lock:
                    self.pipeline.reset()
                continue
            for r in records:
                self._publish(r)

    def _process(self, items: list) -> list[EstimateRecord]:
        for stream in ("output", "input"):
            blocks = [(t, v) for s, t, v in items if s == stream]
            push = self.pipeline.push_output if stream == "output" else self.pipeline.push_input
            for t, v in mc.stack_blocks(blocks):
                push(t, v)
        return self.pipeline.step()

    def _publish(self, r: EstimateRecord) -> None:
        self.estimate_pub.publish(mc.estimate_msg(r))
        self._last_record = r
        now = self.get_clock().now().nanoseconds
        self._latency = (now - r.stamp_ns) * 1e-9
        self._last_publish_wall = time.monotonic()

    # ---- diagnostics ----
    def _diagnostics(self) -> None:
        now = time.monotonic()
        dt = max(now - self._diag_prev_t, 1e-6)
        with self._lock:
            pl = self.pipeline
            counters = pl.counters
            rates = pl.ingest.rates()
            values = dict(pl.values)
            fs, mode = pl.sample_rate, pl.ingest.mode
            cost = pl.update_seconds / pl.update_samples if pl.update_samples else math.nan
            est_ok = pl.estimator is not None
        arrivals = dict(self._arrivals)
        r = self._last_record
        kv: dict[str, Any] = {
            "output_topic": values["output_topic"],
            "input_topic": values["input_topic"] if mode == "io" else "",
            "mode": mode,
            "sample_rate_hz": fs,
            "output_rate_hz": rates["output"],
            "input_rate_hz": rates["input"],
            "forgetting_factor": pl.forgetting_factor,
            "converged": bool(r.converged) if r else False,
            "samples_used": r.samples_used if r else 0,
            "modes_tracked": sum(m.status == "tracked" for m in r.modes) if r else 0,
            "prediction_error_rms": r.prediction_error_rms if r else math.nan,
            "update_cost_us_per_sample": cost * 1e6,
            "realtime_factor": 1.0 / (cost * fs) if cost > 0 and fs > 0 else math.nan,
            "estimate_latency_s": self._latency,
            "queued_messages": len(self._queue),
        }
        for k, v in sorted(arrivals.items()):
            kv[k] = v
            kv[k.replace("_messages", "_message_rate_hz")] = (
                (v - self._diag_prev.get(k, 0)) / dt if k.endswith("_messages") else None)
        for k, v in sorted(counters.items()):
            kv[k] = v
        bad_now = sum(v for k, v in counters.items() if k.endswith(BAD_INPUT_KEYS) or
                      k in ("gaps", "time_resets"))
        bad_before = sum(v for k, v in self._diag_prev.items() if k.endswith(BAD_INPUT_KEYS) or
                         k in ("gaps", "time_resets"))
        stale = not math.isfinite(self._last_arrival) or now - self._last_arrival > 2.0
        if stale:
            level, message = DiagnosticStatus.STALE, "no data received"
        elif bad_now > bad_before:
            level, message = DiagnosticStatus.WARN, f"{bad_now - bad_before} bad input event(s)"
        elif not (r and r.converged) or not est_ok:
            level, message = DiagnosticStatus.WARN, "not converged yet"
        else:
            level, message = DiagnosticStatus.OK, "tracking"
        status = DiagnosticStatus(
            level=level,
            name="sysid_node: identification",
            message=message,
            hardware_id=values["output_topic"],
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
        self._stop.set()
        self._wake.set()
        self._worker.join(timeout=5.0)


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
