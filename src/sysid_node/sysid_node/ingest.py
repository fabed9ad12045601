"""Stamp alignment of input and output samples into uniformly sampled blocks (pure, no rclpy).

The recursive DSRA needs equally spaced samples, inputs and outputs taken at the same instants,
and no fake continuity across missing data (a Hankel row (A1) spanning a gap mixes unrelated
samples). :class:`Ingest` takes message blocks of each stream as they arrive (stamps in
nanoseconds and a ``(n, channels)`` array) and hands out :class:`Chunk` objects on a uniform grid:

- samples are ordered by header stamp, not by arrival; duplicates (same stamp), samples arriving
  after their instant was handed out (late), wrong channel counts and NaN/Inf rows are dropped and
  counted, each with a reason string in :attr:`Ingest.events`;
- the sample rate is configured or measured from the stamps; a stream whose rate differs from it
  is resampled (linear interpolation onto the grid) or rejected, as configured, and said so;
- holes of at most ``gap_fill_max_samples`` samples (e.g. one NaN sample dropped) are repaired by
  linear interpolation; longer gaps split the data: the next chunk has ``new_segment`` set so the
  estimator restarts its Hankel window, and the gap is counted;
- a stamp jump far back in time held for ``TIME_RESET_SPAN`` seconds of data (a clock reset, a
  looped bag) starts a new time line (``reset`` set: rebuild the estimator).

Everything is vectorised per message block; no good sample is lost.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

from sysid_node.ingest_segments import Chunk, Segments
from sysid_node.ingest_stream import (
    STAMP_TOLERANCE,
    TIME_RESET_SPAN,
    IngestReport,
    Stream,
    beyond_jump,
)

#: Relative difference between a stream's measured rate and the sample rate tolerated as jitter.
RATE_TOLERANCE = 0.01
#: Output data waited for an input stream before running output-only [s].
INPUT_WAIT = 1.0
#: Samples older than the hand-out point by more than this [s] are a jump back in time ...
TIME_JUMP = 1.0


class Ingest:
    """Aligns the output (and input) streams by stamp onto a uniform sample grid.

    Parameters: ``sample_rate`` [Hz] (0 = measure from the output stamps), ``use_input`` (expect
    an input stream; output-only while none arrives within ``INPUT_WAIT`` s of data, and on a
    live node, ``clock`` given, within ``INPUT_WAIT`` s of wall-clock time too: a stream that is
    only late in transport, as in a fast replay or a busy node, is waited for, not dropped),
    ``output_channels``/``input_channels`` (0 = from the first message), ``gap_fill_max_samples``,
    ``reorder_window`` [s] (data held back to reorder late arrivals), ``rate_mismatch``
    ('resample' or 'reject').
    """

    def __init__(
        self,
        sample_rate: float = 0.0,
        use_input: bool = True,
        output_channels: int = 0,
        input_channels: int = 0,
        gap_fill_max_samples: int = 2,
        reorder_window: float = 0.02,
        rate_mismatch: str = "resample",
        clock: Callable[[], float] | None = None,
    ) -> None:
        self.clock = clock
        self._input_arrived = -math.inf  # clock() at the last input push
        self._lead_since = math.nan  # clock() when the output data got INPUT_WAIT ahead
        self._first_output = math.nan  # clock() at the timeline's first output push
        self.configured_rate = float(sample_rate)
        self.use_input = use_input
        self.max_fill = int(gap_fill_max_samples)
        self.reorder_window = float(reorder_window)
        self.rate_mismatch = rate_mismatch
        self.report = IngestReport()
        self.counters, self.events = self.report.counters, self.report.events
        self.out = Stream("output", output_channels or None, self.report)
        self.inp = Stream("input", input_channels or None, self.report)
        self.origin_ns: int | None = None
        self._jump: list[tuple[Stream, np.ndarray, np.ndarray]] = []
        self._reset_timeline(first=True)

    # ---- state ----
    def _reset_timeline(self, first: bool = False) -> None:
        self.fs = self.configured_rate if self.configured_rate > 0 else math.nan
        self.t0 = math.nan  # grid origin [s relative to origin_ns]
        self.next_k = 0
        self.mode = "pending" if self.use_input else "output_only"
        self._first_output = math.nan
        self._lead_since = math.nan
        self.segments = Segments(self.report, pending_reset=not first)
        for s in (self.out, self.inp):
            s.clear()
            s.seen = False

    @property
    def period(self) -> float:
        return 1.0 / self.fs

    @property
    def watermark(self) -> float:
        """Time of the last grid instant handed out [s relative to origin_ns], -inf if none."""
        if math.isnan(self.t0) or self.next_k == 0:
            return -math.inf
        return self.t0 + (self.next_k - 1) * self.period

    def _event(self, text: str) -> None:
        self.report.event(text)

    # ---- input ----
    def push_output(self, stamps_ns: np.ndarray, values: np.ndarray,
                    names: tuple[str, ...] | None = None) -> None:
        """Add a message block of the output stream (``values`` of shape ``(n, channels)``;
        ``names``: the channel names the message carries, if any)."""
        self._push(self.out, stamps_ns, values, names)

    def push_input(self, stamps_ns: np.ndarray, values: np.ndarray,
                   names: tuple[str, ...] | None = None) -> None:
        """Add a message block of the input (excitation) stream."""
        if not self.use_input:
            return
        self._push(self.inp, stamps_ns, values, names)

    def reject(self, stream: str, n: int, key: str, text: str) -> None:
        """Count ``n`` messages of ``stream`` dropped before conversion (e.g. unreadable)."""
        self.counters[f"{stream}_{key}"] += n
        self._event(text)

    def _push(self, s: Stream, stamps_ns: np.ndarray, values: np.ndarray,
              names: tuple[str, ...] | None = None) -> None:
        stamps_ns = np.asarray(stamps_ns, dtype=np.int64).reshape(-1)
        values = np.asarray(values, dtype=float)
        if values.ndim == 1:
            values = values.reshape(len(stamps_ns), -1) if len(stamps_ns) else values[None]
        n = len(stamps_ns)
        self.counters[f"{s.name}_received"] += n
        if n == 0:
            return
        if self.clock is not None:
            now = self.clock()
            if s is self.inp:
                self._input_arrived = now
            elif math.isnan(self._first_output):
                self._first_output = now
        if values.ndim != 2 or values.shape[0] != n:
            self.counters[f"{s.name}_malformed"] += n
            self._event(f"{s.name}: malformed block (values {values.shape} for {n} stamps)")
            return
        c = values.shape[1]
        names = tuple(names) if names and len(names) == c else None
        values, names = s.map_names(values, names)
        if s.other_layout(c, names):
            if not s.hold_layout(stamps_ns, values, names):
                return
            self._reset_timeline()
        finite = np.isfinite(values).all(axis=1)
        if not finite.all():
            bad = int(n - finite.sum())
            self.counters[f"{s.name}_nonfinite"] += bad
            self._event(f"{s.name}: {bad} sample(s) with NaN/Inf dropped")
            stamps_ns, values = stamps_ns[finite], values[finite]
            if len(stamps_ns) == 0:
                return
        if self.origin_ns is None:
            self.origin_ns = int(stamps_ns.min()) // 1_000_000_000 * 1_000_000_000
        t = (stamps_ns - self.origin_ns) * 1e-9
        self._accept(s, t, values)

    def _accept(self, s: Stream, t: np.ndarray, values: np.ndarray) -> None:
        """Accept finite samples, or hold them while the output stamps have jumped back or
        they are stamped far ahead of their stream."""
        if math.isfinite(s.max_t):
            ahead = beyond_jump(t, s.max_t)
            if ahead.any() or s.future:
                t, values = s.hold_future(t, values, ahead)
                if not len(t):
                    return
        if s is self.out:
            far = t < self.watermark - TIME_JUMP
            if far.all():
                self._jump.append((s, t, values))
                ts = [x[1] for x in self._jump if x[0] is self.out]
                back = self.watermark - float(ts[0].min())
                if max(float(x.max()) for x in ts) - min(float(x.min()) for x in ts) \
                        >= TIME_RESET_SPAN:
                    held, self._jump = self._jump, []
                    self.counters["time_resets"] += 1
                    self._event(f"stamps jumped back by {back:.3f} s: new time line, "
                                "estimator reset")
                    self._reset_timeline()
                    for hs, ht, hv in held:
                        self._add(hs, ht, hv)
                return
            if self._jump:  # back on the current time line: the held samples were late
                held, self._jump = self._jump, []
                for hs, ht, hv in held:
                    self._add(hs, ht, hv)
        elif self._jump:
            self._jump.append((s, t, values))
            return
        self._add(s, t, values)

    def _add(self, s: Stream, t: np.ndarray, values: np.ndarray) -> None:
        tol = STAMP_TOLERANCE * self.period if math.isfinite(self.fs) else 1e-6
        s.add(t, values, tol, self.watermark)

    # ---- rates ----
    def rates(self) -> dict[str, float]:
        """Measured rate of each stream [Hz], NaN while unknown."""
        return {"output": self.out.rate, "input": self.inp.rate}

    def _check_rate(self, s: Stream) -> None:
        s.rate = s.measure_rate()
        if not (math.isfinite(s.rate) and math.isfinite(self.fs)):
            return
        mismatch = abs(s.rate - self.fs) > RATE_TOLERANCE * self.fs
        if mismatch and not s.mismatch:
            action = ("rejected (rate_mismatch=reject)" if self.rate_mismatch == "reject"
                      else f"resampled onto the {self.fs:g} Hz grid")
            self._event(f"{s.name} stream at {s.rate:.4g} Hz differs from the sample rate "
                        f"{self.fs:g} Hz: {action}")
        elif s.mismatch and not mismatch:
            self._event(f"{s.name} stream back at the sample rate {self.fs:g} Hz")
        s.mismatch = mismatch
        s.rejected = mismatch and self.rate_mismatch == "reject"
        if s.rejected and len(s.t):
            self.counters[f"{s.name}_rate_rejected"] += len(s.t)
            s.t, s.v = s.t[:0], s.v[:0]

    # ---- output ----
    def pop(self, flush: bool = False) -> list[Chunk]:
        """Hand out the grid samples that can no longer change.

        ``flush``: the streams have ended; hand out everything (no reorder hold-back).
        """
        streams = self._streams_ready(flush)
        if not streams:
            return []
        T = self.period
        hold = 0.0 if flush else self.reorder_window
        ready = min(float(s.t[-1]) for s in streams) - hold
        kmax = math.floor((ready - self.t0) / T + STAMP_TOLERANCE)
        self._skip_unfillable(streams, kmax)
        if kmax < self.next_k:
            return []
        # never more grid instants than the samples held could fill (a stamp far ahead
        # must not allocate a grid over the jump): the rest waits for the next call
        room = sum(len(s.t) for s in streams) * (self.max_fill + 1) + 1
        kmax = min(kmax, self.next_k + room)
        k = np.arange(self.next_k, kmax + 1)
        g = self.t0 + k * T
        valid = np.ones(len(g), bool)
        vals = []
        stamps_t = g
        for s in streams:
            v, ok, interp, st = s.sample_at(g, T, self.max_fill)
            if s is self.out:
                stamps_t = st
            valid &= ok
            vals.append(v)
            n_interp = int((interp & ok).sum())
            if n_interp:
                self.counters[f"{s.name}_{'resampled' if s.mismatch else 'repaired'}"] += n_interp
        chunks = self.segments.split(stamps_t, valid, vals, self.origin_ns, T)
        self.next_k = kmax + 1
        keep_from = self.watermark - (self.max_fill + 2) * T
        for s in (self.out, self.inp):
            s.drop_before(keep_from)
        return chunks

    def _streams_ready(self, flush: bool) -> list[Stream]:
        """The streams to align now (rate known, grid origin set, mode chosen, data held);
        empty while not ready."""
        if self.out.channels is None or not self.out.seen:
            return []
        if not math.isfinite(self.fs):
            fs = self.out.measure_rate()
            if not math.isfinite(fs):
                return []
            self.fs = fs
            self._event(f"sample rate measured from the stamps: {fs:.6g} Hz")
        for s in (self.out, self.inp):
            self._check_rate(s)
        if math.isnan(self.t0):
            if len(self.out.t) == 0:
                return []
            self.t0 = float(self.out.t[0])
        self._choose_mode(flush)
        if self.mode == "pending":
            return []
        streams = [self.out] + ([self.inp] if self.mode == "io" else [])
        return [] if any(len(s.t) == 0 for s in streams) else streams

    def _skip_unfillable(self, streams: list[Stream], kmax: int) -> None:
        """Skip the grid instants (up to ``kmax``) before the next sample of a stream that
        cannot be filled (counted as missing)."""
        T = self.period
        g_next = self.t0 + self.next_k * T
        k_skip = self.next_k
        for s in streams:
            i = int(np.searchsorted(s.t, g_next - STAMP_TOLERANCE * T))
            if i < len(s.t) and s.t[i] - g_next > (self.max_fill + 1) * T:
                k_skip = max(k_skip, math.ceil((s.t[i] - self.t0) / T - STAMP_TOLERANCE))
        k_skip = min(k_skip, kmax + 1)
        if k_skip > self.next_k:
            self.segments.missing(k_skip - self.next_k)
            self.next_k = k_skip

    def _waited(self, since: float) -> bool:
        """Live (a clock): ``INPUT_WAIT`` s of wall-clock time have passed since ``since``
        (NaN: not yet started). Offline: always, the data time alone decides."""
        if self.clock is None:
            return True
        return math.isfinite(since) and self.clock() - since >= INPUT_WAIT

    def _choose_mode(self, flush: bool) -> None:
        """Input-output while input samples arrive, output-only otherwise (with a log line)."""
        out_end = float(self.out.t[-1]) if len(self.out.t) else -math.inf
        if self.mode == "pending":
            if self.inp.seen and not self.inp.rejected:
                self.mode = "io"
            elif flush or (out_end - self.t0 >= INPUT_WAIT
                           and self._waited(self._first_output)):
                self.mode = "output_only"
                self._event(f"no input samples within {INPUT_WAIT:g} s of data: output-only")
            return
        # stopped: INPUT_WAIT s of output DATA beyond the input's last stamp (a gap in both
        # streams, whose output side resumes a message before the input side, is not a stop)
        ahead = int(np.count_nonzero(self.out.t > self.inp.max_t)) if len(self.out.t) else 0
        enough = not math.isfinite(self.fs) or ahead * self.period > INPUT_WAIT
        ahead_in_data = self.out.max_t - self.inp.max_t > INPUT_WAIT and enough
        # live, no input for INPUT_WAIT of wall clock (a stream late in transport, as in a fast
        # replay, keeps arriving), and the lead lasting as long: after a stall of the process
        # both streams arrive in a burst, the output's drained first (the input's last arrival
        # is then long ago, but its samples are queued right behind)
        if not ahead_in_data:
            self._lead_since = math.nan
        elif math.isnan(self._lead_since) and self.clock is not None:
            self._lead_since = self.clock()
        stopped = (ahead_in_data and self._waited(self._input_arrived)
                   and self._waited(self._lead_since))
        if self.mode == "io" and (self.inp.rejected or stopped):
            self.mode = "output_only"
            why = "rejected" if self.inp.rejected else "stopped"
            self._event(f"input stream {why}: output-only, estimator reset")
        elif (self.mode == "output_only" and self.use_input and not self.inp.rejected
              and self.out.max_t - self.inp.max_t < INPUT_WAIT / 2 and len(self.inp.t)):
            self.mode = "io"
            self._event("input samples arrived: input-output identification, estimator reset")
        else:
            return
        self.segments.restart()
