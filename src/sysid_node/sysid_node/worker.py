"""The node's worker process and the hand-off to it (pure: no rclpy).

The estimator runs in a worker *process* so that its numerics never hold the GIL the
subscriptions need, and so that it can use the second core. :class:`WorkerLink` is the node's
side of the hand-off; :func:`worker_main` the worker's body. The design bounds the latency
from a sample to the estimate that used it, whatever the load:

- **Credit-based batching.** At most ``IN_FLIGHT`` batches are in the pipe to the worker. What
  arrives meanwhile waits in the node and goes over as ONE batch (one array per stream and
  channel count) when the worker reports back, so the worker always takes everything that is
  waiting: the busier the machine, the larger and cheaper the batches, and the pipe never holds
  more than a couple of batches (nothing to drain before a parameter change applies).
- **Realization off the catch-up path.** A batch gathered while the worker was busy, whose
  oldest data have waited more than ``CATCH_UP_AFTER_S``, is absorbed by the RLS without
  realizations except over its newest publication period
  (the realization, not the RLS update, is the expensive part): only current estimates are
  made, the skipped ones are counted (``estimates_skipped``).
- **Newest data first when behind.** The backlog is how long the oldest data not yet
  processed has waited in the node (the lag behind real time, whatever the replay speed; the
  same in seconds of data is reported too). When it exceeds ``max_backlog``, the oldest
  waiting messages are dropped (counted per stream as
  ``*_shed``, said in a throttled warning): a current estimate is worth more than a complete one
  that arrives seconds late.
- **Health.** A worker that died is restarted with the current parameters (the estimate starts
  again; ``worker_restarts`` counts it); one that has not reported for ``STALL_S`` seconds while
  it has work is reported stalled.
"""

from __future__ import annotations

import multiprocessing as mp
import signal

if mp.parent_process() is not None:  # imported by a spawned worker: the node stops it
    signal.signal(signal.SIGINT, signal.SIG_IGN)

import math
import queue
import threading
import time
from collections import Counter, deque
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from sysid_node.msg_convert import stack_named

#: Batches in the pipe to the worker at most (one being processed, one waiting).
IN_FLIGHT = 2
#: A worker with work that has not reported for this long is reported stalled [s].
STALL_S = 5.0
#: A batch gathered while the worker was busy is realized only over its newest publication
#: period (and at least this many seconds); the older part is absorbed without realizations
#: (Pipeline.step(realize_from_ns)): the estimator catches up at a fraction of the cost.
CATCH_UP_KEEP_S = 0.05
#: ... once the oldest data of such a batch have waited this long [s]: a batch held only for
#: the duration of one realization is processed whole (each of its estimates is made, at most
#: this late), one held through a stall of the machine is caught up.
CATCH_UP_AFTER_S = 0.25
#: Time the worker may take to import and build its pipeline [s].
START_TIMEOUT_S = 120.0


@dataclass
class Report:
    """What the worker sends back after each batch."""

    records: list
    lines: list[str]
    status: dict[str, Any]
    batch_id: int
    spectra: list = field(default_factory=list)
    received_ns: int = 0  # wall clock when the worker took the batch
    done_ns: int = 0  # wall clock when it had processed it


def worker_status(pl: Any) -> dict[str, Any]:
    """The pipeline's state the node reports in /diagnostics."""
    cost = pl.update_seconds / pl.update_samples if pl.update_samples else math.nan
    ing = pl.ingest
    wm = ing.watermark
    processed_ns = (int(ing.origin_ns + round(wm * 1e9))
                    if ing.origin_ns is not None and math.isfinite(wm) else None)
    return {
        "counters": pl.counters,
        "rates": ing.rates(),
        "fs": pl.sample_rate,
        "id_fs": pl.identification_rate,
        "split_hz": pl.split_hz if pl.low_band is not None else math.nan,
        "low_fs": pl.low_band.rate if pl.low_band is not None else math.nan,
        "mode": ing.mode,
        "cost": cost,
        "lambda": pl.forgetting_factor,
        "processed_ns": processed_ns,
        "values": dict(pl.values),
        "band_warning": pl.band_warning(),
        "scheduling": pl.scheduling_status(),
    }


def worker_main(values: dict[str, Any], inbox: Any, outbox: Any) -> None:
    """Body of the worker process (multiprocessing, spawn): a Pipeline fed with the batches
    the node sends.

    Inbox items: ``("data", batch_id, [(stream, stamps, values, names), ...],
    realize_from_ns)``,
    ``("params", changes)``, ``("reset", None)``, ``None`` (stop). Outbox items: ``("ready",
    error)`` first, then one :class:`Report` per data batch (``batch_id`` -1 after parameters).
    """
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # the node stops us, not the terminal
    from sysid_node.pipeline import Pipeline

    lines: list[str] = []
    try:
        pl = Pipeline(values, log=lines.append)
        pl.go_live()  # the wall-clock rules: live only
    except Exception as err:  # reported to the node, which refuses to start
        outbox.put(("ready", f"{type(err).__name__}: {err}"))
        return
    outbox.put(("ready", ""))
    while True:
        try:
            item = inbox.get()
        except (EOFError, OSError):  # the node is gone
            return
        if item is None:
            return
        received_ns = time.time_ns()
        kind, *payload = item
        records: list = []
        batch_id = -1
        try:
            if kind == "data":
                batch_id, blocks, realize_from_ns = payload
                push = {"output": pl.push_output, "input": pl.push_input,
                        "scheduling": pl.push_scheduling}
                for stream, t, v, names in blocks:
                    push[stream](t, v, names)
                records = pl.step(realize_from_ns=realize_from_ns)
            elif kind == "params":
                reason = pl.set_parameters(payload[0])
                if reason:
                    lines.append(f"parameter change not applied: {reason}")
            elif kind == "reset":
                pl.reset()
        except Exception as err:  # keep running on anything the data throws at us
            lines.append(f"ERROR processing failed, estimator reset: {err!r}")
            pl.reset()
        outbox.put(Report(records, lines[:], worker_status(pl), batch_id, pl.pop_spectra(),
                          received_ns, time.time_ns()))
        lines.clear()


@dataclass
class _Pending:
    stream: str
    stamps: np.ndarray
    values: np.ndarray
    messages: int
    arrived: float = 0.0  # time.monotonic()
    names: tuple[str, ...] | None = None


class WorkerLink:
    """The node's side of the worker: start, send, receive, backlog, shedding, restart.

    ``log(level, text)`` receives the link's own lines (level 'info', 'warn' or 'error').
    Thread-safe: :meth:`submit` is called by the subscription callbacks, :meth:`receive` by
    the node's receiver thread.
    """

    def __init__(self, values: dict[str, Any], log: Callable[[str, str], None]) -> None:
        self.values = dict(values)
        self.log = log
        self.counters: Counter[str] = Counter()
        self._lock = threading.Lock()
        # held from taking a batch to queueing it: two threads sending (a subscription callback
        # and the receiver) would otherwise queue their batches out of order
        self._send_lock = threading.Lock()
        self._pending: deque[_Pending] = deque()
        self._in_flight: dict[int, float] = {}  # batch id -> arrival of its oldest data
        self._sent_ns: dict[int, int] = {}  # batch id -> wall clock sent [ns]
        self.stages = StageTimes()
        self._next_id = 0
        self.newest_ns: int | None = None  # newest stamp received
        self.status: dict[str, Any] = {}
        self.last_report = math.nan  # wall time (monotonic) of the last report
        self._warned_backlog = False
        self._held_back = False
        self._last_shed_log = -math.inf
        self._proc: Any = None
        self.inbox: Any = None
        self.outbox: Any = None

    # ---- process ----
    def start(self, cancelled: Callable[[], bool] = lambda: False) -> str:
        """Start the worker and wait until its pipeline is built; '' or the reason it failed.
        ``cancelled()`` is polled while waiting (a stop request during start-up)."""
        ctx = mp.get_context("spawn")  # never fork a process that runs DDS threads
        self.inbox, self.outbox = ctx.Queue(), ctx.Queue()
        self._proc = ctx.Process(target=worker_main, args=(self.values, self.inbox, self.outbox),
                                 name="sysid_worker", daemon=True)
        _start_ignoring_sigint(self._proc)
        deadline = time.monotonic() + START_TIMEOUT_S
        while time.monotonic() < deadline and not cancelled():
            try:
                _tag, error = self.outbox.get(timeout=0.1)
            except queue.Empty:
                if not self._proc.is_alive():
                    return f"the worker process exited with code {self._proc.exitcode}"
                continue
            self.last_report = time.monotonic()
            return error
        return "cancelled" if cancelled() else (
            f"the worker process did not start within {START_TIMEOUT_S:g} s")

    @property
    def alive(self) -> bool:
        return self._proc is not None and self._proc.is_alive()

    def restart(self) -> str:
        """Replace a dead worker (the estimate starts again); '' or the reason it failed."""
        self._close_process(timeout=0.5)
        with self._lock:
            self._in_flight.clear()
        self.counters["worker_restarts"] += 1
        error = self.start()
        if not error:
            self._send_waiting()
        return error

    def stop(self, timeout: float = 2.0) -> None:
        """Stop the worker (within ``timeout`` + 1 s at most)."""
        self._close_process(timeout)

    def _close_process(self, timeout: float) -> None:
        if self._proc is None:
            return
        try:
            self.inbox.put(None)
        except (OSError, ValueError):
            pass
        self._proc.join(timeout=timeout)
        if self._proc.is_alive():
            self._proc.terminate()
            self._proc.join(timeout=1.0)
        for q in (self.inbox, self.outbox):
            q.cancel_join_thread()
            q.close()

    # ---- data in ----
    def submit(self, stream: str, blocks: list[tuple], messages: int) -> None:
        """Queue the converted messages of one burst of ``stream``; send if the worker has
        credit."""
        if not blocks:
            return
        blocks = [b for b in blocks if len(b[0])]
        if not blocks:
            return
        newest = max(int(b[0].max()) for b in blocks)
        with self._lock:
            if self.newest_ns is None or newest > self.newest_ns or \
                    newest < self.newest_ns - 10**9:  # a clock reset starts a new time line
                self.newest_ns = newest
            for t, v, *names in blocks:
                self._pending.append(_Pending(stream, t, v, messages, time.monotonic(),
                                              names[0] if names else None))
                messages = 0  # counted once per burst
            if len(self._in_flight) >= IN_FLIGHT:
                self._held_back = True
        self._send_waiting()

    def set_parameters(self, changes: dict[str, Any]) -> None:
        self.values.update(changes)
        self.inbox.put(("params", changes))

    def _send_waiting(self) -> None:
        """Send what is waiting as one batch, if the worker has credit (batches are queued in
        the order their data were taken)."""
        with self._send_lock:
            self._send_batch()

    def _send_batch(self) -> None:
        with self._lock:
            if not self._pending or len(self._in_flight) >= IN_FLIGHT or not self.alive:
                return
            self._shed()
            items, self._pending = list(self._pending), deque()
            held, self._held_back = self._held_back, False
            batch_id = self._next_id
            self._next_id += 1
            self._in_flight[batch_id] = items[0].arrived
            self._sent_ns[batch_id] = time.time_ns()
            self.stages.add("waiting", time.monotonic() - items[0].arrived)
        blocks = [(s, *b) for s in ("output", "input", "scheduling") for b in
                  stack_named([(p.stamps, p.values, p.names) for p in items if p.stream == s])]
        realize_from = None
        waited = time.monotonic() - items[0].arrived
        if (held and waited > CATCH_UP_AFTER_S and self.newest_ns is not None
                and self.values.get("catch_up", True)):
            # gathered while the worker was busy, and for long enough to be behind
            keep = max(CATCH_UP_KEEP_S, 1.0 / float(self.values.get("publish_rate", 10.0)))
            realize_from = self.newest_ns - int(keep * 1e9)
        try:
            self.inbox.put(("data", batch_id, blocks, realize_from))
        except (OSError, ValueError):  # closed while stopping
            pass

    def _shed(self) -> None:
        """Drop the oldest waiting messages while the backlog exceeds ``max_backlog`` (lock
        held)."""
        limit = float(self.values.get("max_backlog", 0.0))
        if limit <= 0 or not self._pending:
            return
        now = time.monotonic()
        oldest = min([self._pending[0].arrived, *self._in_flight.values()])
        if now - oldest <= limit:
            return
        dropped: Counter[str] = Counter()
        # keep the newest half of max_backlog of data (by stamps): after a long stall (a
        # worker restart) the newest data are still identified
        keep_from = (self.newest_ns or 0) - int(0.5 * limit * 1e9)
        while self._pending and self._pending[0].stamps.max() < keep_from:
            p = self._pending.popleft()
            dropped[p.stream] += p.messages
            dropped[p.stream + "_samples"] += len(p.stamps)
        if not dropped:
            return
        for s in ("output", "input"):
            if dropped[s] or dropped[s + "_samples"]:
                self.counters[f"{s}_shed"] += dropped[s]
                self.counters[f"{s}_shed_samples"] += dropped[s + "_samples"]
        now = time.monotonic()
        if now - self._last_shed_log >= 5.0:
            self._last_shed_log = now
            self.log("warn", f"estimator {now - oldest:.2f} s behind (max_backlog "
                     f"{limit:g} s): older data dropped to stay current (total shed: "
                     f"{self.counters['output_shed']} output, {self.counters['input_shed']} "
                     "input messages)")

    # ---- data out ----
    def receive(self, timeout: float) -> Report | None:
        """The worker's next report (None on timeout); frees its batch's credit and sends
        what has been waiting."""
        try:
            rep = self.outbox.get(timeout=timeout)
        except queue.Empty:
            return None
        except (EOFError, OSError, ValueError):
            time.sleep(timeout)
            return None
        if not isinstance(rep, Report):
            return None
        self.last_report = time.monotonic()
        if rep.status:
            self.status = rep.status
        with self._lock:
            self._in_flight.pop(rep.batch_id, None)
            sent = self._sent_ns.pop(rep.batch_id, None)
        if sent is not None:
            self.stages.add("to_worker", (rep.received_ns - sent) * 1e-9)
            self.stages.add("worker", (rep.done_ns - rep.received_ns) * 1e-9)
            if rep.records:
                self.stages.add("worker_estimating", (rep.done_ns - rep.received_ns) * 1e-9)
            self.stages.add("from_worker", (time.time_ns() - rep.done_ns) * 1e-9)
        self._send_waiting()
        return rep

    # ---- health ----
    def backlog_s(self) -> float:
        """How long the oldest data not yet processed has waited in the node [s] (0 when
        idle): the node's lag behind real time, whatever the replay speed."""
        with self._lock:
            first = [p.arrived for p in list(self._pending)[:1]] + list(self._in_flight.values())
        return max(0.0, time.monotonic() - min(first)) if first else 0.0

    def data_backlog_s(self) -> float:
        """Seconds of data received but not yet handed to the estimator (stamps)."""
        done = self.status.get("processed_ns")
        if self.newest_ns is None or done is None:
            return 0.0
        return max(0.0, (self.newest_ns - done) * 1e-9)

    def queued_messages(self) -> int:
        with self._lock:
            return sum(p.messages for p in self._pending)

    def stalled_s(self) -> float:
        """Seconds since the worker last reported while it has work in flight (0 if none)."""
        with self._lock:
            busy = bool(self._in_flight)
        return max(0.0, time.monotonic() - self.last_report) if busy else 0.0

    def check_backlog(self) -> None:
        """Warn once (then again only after it recovered) when the backlog exceeds
        ``backlog_warning`` seconds."""
        limit = float(self.values.get("backlog_warning", 0.0))
        b = self.backlog_s()
        if limit > 0 and math.isfinite(b) and b > limit and not self._warned_backlog:
            self._warned_backlog = True
            self.log("warn", f"estimator {b:.2f} s behind (backlog_warning {limit:g} s); "
                     "the machine or the parameters do not let it keep up")
        elif self._warned_backlog and (not math.isfinite(b) or b < 0.5 * limit):
            self._warned_backlog = False
            self.log("info", f"estimator caught up ({b:.2f} s behind)")


class StageTimes:
    """Recent durations of each hand-off stage [s], for /diagnostics: where the latency goes.
    arrival: sample stamp -> taken by the node's reader (DDS and polling; wall-clock stamps only);
    waiting: in the node for the worker's credit; to_worker: pipe -> taken by the worker;
    worker: ingest + estimator per batch (worker_estimating: batches that made an estimate);
    from_worker: report -> received by the node; estimate: sample stamp -> published."""

    def __init__(self, n: int = 500) -> None:
        self.n = n
        self._d: dict[str, deque[float]] = {}

    def add(self, stage: str, seconds: float) -> None:
        self._d.setdefault(stage, deque(maxlen=self.n)).append(seconds)

    def percentiles(self) -> dict[str, float]:
        """``{stage}_p50_ms`` and ``{stage}_p99_ms`` over the recent values."""
        out = {}
        for stage, d in list(self._d.items()):
            if d:
                p50, p99 = np.percentile(np.fromiter(d, float), [50, 99])
                out[f"latency_{stage}_p50_ms"] = 1e3 * float(p50)
                out[f"latency_{stage}_p99_ms"] = 1e3 * float(p99)
        return out


def _start_ignoring_sigint(proc: Any) -> None:
    """Start ``proc`` with SIGINT ignored from its first instant (a Ctrl-C to the process group
    during the worker's imports would otherwise print a traceback). Ignored signals survive
    exec; handlers do not. Only the main thread may change handlers: elsewhere the worker
    ignores SIGINT once its module is imported."""
    if threading.current_thread() is not threading.main_thread():
        proc.start()
        return
    previous = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        proc.start()
    finally:
        signal.signal(signal.SIGINT, previous)
