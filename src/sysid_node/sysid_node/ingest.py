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
from collections import Counter, deque
from dataclasses import dataclass, field

import numpy as np

#: Relative difference between a stream's measured rate and the sample rate tolerated as jitter.
RATE_TOLERANCE = 0.01
#: A stamp within this fraction of the period of a grid instant is taken as taken at that instant.
STAMP_TOLERANCE = 0.25
#: Samples needed to measure a rate.
RATE_SAMPLES = 20
#: Output data waited for an input stream before running output-only [s].
INPUT_WAIT = 1.0
#: Samples older than the hand-out point by more than this [s] are a jump back in time ...
TIME_JUMP = 1.0
#: ... and a new time line once such samples span this much data [s].
TIME_RESET_SPAN = 0.5
_RECENT = 4096
#: A sample stamped this far [s] ahead of what its stream has delivered is held as suspect: a
#: forward clock jump once the held samples span TIME_RESET_SPAN of data, a bad stamp (dropped,
#: counted) once the stream's own data has moved on by that much without them.
FUTURE_JUMP = 1.0
#: A new channel count (or new channel names) held for this much data [s], with nothing in the
#: old layout meanwhile, is adopted: the estimator restarts on the new layout.
LAYOUT_CONFIRM_S = 1.0
#: Held samples per stream at most (suspect stamps, unconfirmed layouts): memory is bounded by
#: the data received, never by the stamps' span.
MAX_HELD = 100_000
#: A measured rate this close to a round value [ppm] is taken as that value.
SNAP_PPM = 20.0


@dataclass
class Chunk:
    """Uniformly sampled data for the estimator.

    ``stamps_ns[k]`` is the time of row ``k`` of ``y`` (outputs) and ``u`` (inputs, None when
    output-only). ``new_segment``: not contiguous with the previous chunk (restart the Hankel
    window). ``reset``: the channel layout or the time line changed (rebuild the estimator).
    """

    stamps_ns: np.ndarray
    y: np.ndarray
    u: np.ndarray | None
    new_segment: bool
    reset: bool = False

    def __len__(self) -> int:
        return len(self.stamps_ns)


@dataclass
class _Stream:
    name: str
    channels: int | None
    t: np.ndarray = field(default_factory=lambda: np.empty(0))
    v: np.ndarray | None = None
    recent: np.ndarray = field(default_factory=lambda: np.empty(0))
    max_t: float = -math.inf
    seen: bool = False
    rate: float = math.nan
    mismatch: bool = False
    rejected: bool = False
    names: tuple[str, ...] | None = None
    future: list = field(default_factory=list)  # held (t, values) stamped far ahead
    future_since: float = math.nan  # max_t when the first of them arrived
    layout: list = field(default_factory=list)  # held (t, values, names) of a new layout

    def clear(self) -> None:
        self.t = np.empty(0)
        self.v = None if self.channels is None else np.empty((0, self.channels))
        self.recent = np.empty(0)
        self.max_t = -math.inf
        self.future, self.future_since = [], math.nan


class Ingest:
    """Aligns the output (and input) streams by stamp onto a uniform sample grid.

    Parameters: ``sample_rate`` [Hz] (0 = measure from the output stamps), ``use_input`` (expect
    an input stream; output-only while none arrives within ``INPUT_WAIT`` s of data),
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
    ) -> None:
        self.configured_rate = float(sample_rate)
        self.use_input = use_input
        self.max_fill = int(gap_fill_max_samples)
        self.reorder_window = float(reorder_window)
        self.rate_mismatch = rate_mismatch
        self.counters: Counter[str] = Counter()
        self.events: deque[str] = deque(maxlen=200)
        self.out = _Stream("output", output_channels or None)
        self.inp = _Stream("input", input_channels or None)
        self.origin_ns: int | None = None
        self._jump: list[tuple[_Stream, np.ndarray, np.ndarray]] = []
        self._reset_timeline(first=True)

    # ---- state ----
    def _reset_timeline(self, first: bool = False) -> None:
        self.fs = self.configured_rate if self.configured_rate > 0 else math.nan
        self.t0 = math.nan  # grid origin [s relative to origin_ns]
        self.next_k = 0
        self.mode = "pending" if self.use_input else "output_only"
        self._segment_open = False
        self._pending_reset = not first
        self._emitted_any = False
        self._gap_run = 0
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
        self.events.append(text)

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

    def _push(self, s: _Stream, stamps_ns: np.ndarray, values: np.ndarray,
              names: tuple[str, ...] | None = None) -> None:
        stamps_ns = np.asarray(stamps_ns, dtype=np.int64).reshape(-1)
        values = np.asarray(values, dtype=float)
        if values.ndim == 1:
            values = values.reshape(len(stamps_ns), -1) if len(stamps_ns) else values[None]
        n = len(stamps_ns)
        self.counters[f"{s.name}_received"] += n
        if n == 0:
            return
        if values.ndim != 2 or values.shape[0] != n:
            self.counters[f"{s.name}_malformed"] += n
            self._event(f"{s.name}: malformed block (values {values.shape} for {n} stamps)")
            return
        c = values.shape[1]
        names = tuple(names) if names and len(names) == c else None
        if s.channels is None and c > 0:
            s.channels = c
            s.v = np.empty((0, c))
        if s.names is None and names is not None and c == s.channels:
            s.names = names
        if c == s.channels and names is not None and names != s.names:
            if sorted(names) == sorted(s.names):  # the same channels in another order
                values = values[:, [names.index(x) for x in s.names]]
                if not self.counters[f"{s.name}_reordered"]:
                    self._event(f"{s.name}: channels arrive in another order ({', '.join(names)}"
                                f"): mapped back by name to {', '.join(s.names)}")
                self.counters[f"{s.name}_reordered"] += n
                names = s.names
        if c != s.channels or (names is not None and names != s.names):
            if not self._new_layout(s, stamps_ns, values, names):
                return
            c = s.channels
        elif s.layout:
            self._event(f"{s.name}: back to the {s.channels}-channel layout")
            s.layout = []
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

    def _new_layout(self, s: _Stream, stamps_ns: np.ndarray, values: np.ndarray,
                    names: tuple[str, ...] | None) -> bool:
        """Samples in another channel layout (count or names): dropped and counted while
        unconfirmed; adopted (True, timeline and estimator reset) once only they have arrived
        for LAYOUT_CONFIRM_S of data."""
        n, c = values.shape
        key = "wrong_channels" if c != s.channels else "channel_names_changed"
        was = (f"{s.channels} channels" if c != s.channels
               else f"names {', '.join(s.names or ())}")
        now = f"{c} channels" if c != s.channels else f"names {', '.join(names or ())}"
        self.counters[f"{s.name}_{key}"] += n
        if not s.layout:
            self._event(f"{s.name}: {n} sample(s) with {now}, expected {was}: dropped")
        s.layout.append((stamps_ns, values, names))
        held = sum(len(x[0]) for x in s.layout)
        span = (max(int(x[0].max()) for x in s.layout)
                - min(int(x[0].min()) for x in s.layout)) * 1e-9
        same = all(x[1].shape[1] == c and x[2] == names for x in s.layout)
        if not same or held > MAX_HELD:
            s.layout = [(stamps_ns, values, names)]
            return False
        if span < LAYOUT_CONFIRM_S:
            return False
        self._event(f"{s.name}: {now} instead of {was} for {span:.2f} s of data: new layout "
                    "adopted, estimator reset")
        self.counters["layout_changes"] += 1
        s.channels, s.names, s.layout = c, names, []
        self._reset_timeline()
        s.v = np.empty((0, c))
        return True

    def _accept(self, s: _Stream, t: np.ndarray, values: np.ndarray) -> None:
        """Accept finite samples, or hold them while the output stamps have jumped back or
        they are stamped far ahead of their stream."""
        if math.isfinite(s.max_t):
            ahead = _beyond_jump(t, s.max_t)
            if ahead.any() or s.future:
                t, values = self._hold_future(s, t, values, ahead)
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
                        self._accept_now(hs, ht, hv)
                return
            if self._jump:  # back on the current time line: the held samples were late
                held, self._jump = self._jump, []
                for hs, ht, hv in held:
                    self._accept_now(hs, ht, hv)
        elif self._jump:
            self._jump.append((s, t, values))
            return
        self._accept_now(s, t, values)

    def _hold_future(self, s: _Stream, t: np.ndarray, values: np.ndarray, ahead: np.ndarray):
        """Hold samples stamped far ahead; return the others. The held ones are accepted as a
        forward clock jump once they span TIME_RESET_SPAN of data, dropped as bad stamps once
        the stream's own data moved on by that much without them."""
        if ahead.any():
            if not s.future:
                s.future_since = s.max_t
            s.future.append((t[ahead], values[ahead]))
            t, values = t[~ahead], values[~ahead]
        ft = np.concatenate([x[0] for x in s.future])
        if float(ft.max() - ft.min()) >= TIME_RESET_SPAN and len(t) == 0:
            held, s.future = s.future, []
            self._event(f"{s.name}: stamps jumped ahead by {float(ft.min()) - s.max_t:.3f} s: "
                        "new data after a gap")
            return (np.concatenate([x[0] for x in held]),
                    np.concatenate([x[1] for x in held]))
        newest = max(s.max_t, float(t.max()) if len(t) else -math.inf)
        if newest - s.future_since >= TIME_RESET_SPAN or len(ft) > MAX_HELD:
            self.counters[f"{s.name}_bad_stamp"] += len(ft)
            self._event(f"{s.name}: {len(ft)} sample(s) stamped {float(ft.min()) - newest:.6g} s "
                        "or more ahead of the stream: dropped (bad stamp)")
            s.future = []
        return t, values

    def _accept_now(self, s: _Stream, t: np.ndarray, values: np.ndarray) -> None:
        n = len(t)
        # out of order with respect to arrival
        prev_max = np.maximum.accumulate(np.concatenate(([s.max_t], t)))[:-1]
        ooo = int((t < prev_max).sum())
        if ooo:
            self.counters[f"{s.name}_out_of_order"] += ooo
        s.max_t = max(s.max_t, float(t.max()))
        tol = STAMP_TOLERANCE * self.period if math.isfinite(self.fs) else 1e-6
        order = np.argsort(t, kind="stable")
        t, values = t[order], values[order]
        # duplicates within the block and against recent samples
        dup = np.zeros(n, bool)
        if n > 1:
            dup[1:] = np.diff(t) <= tol
        if len(s.recent):
            dup |= _distance_to_nearest(s.recent, t) <= tol
        if dup.any():
            self.counters[f"{s.name}_duplicate"] += int(dup.sum())
            self._event(f"{s.name}: {int(dup.sum())} duplicate stamp(s) dropped")
        late = ~dup & (t <= self.watermark + tol)
        if late.any():
            self.counters[f"{s.name}_late"] += int(late.sum())
            self._event(f"{s.name}: {int(late.sum())} sample(s) older than the data already "
                        "processed (stamps went backwards): dropped")
        keep = ~dup & ~late
        if not keep.any():
            return
        t, values = t[keep], values[keep]
        self.counters[f"{s.name}_accepted"] += len(t)
        s.seen = True
        if len(s.recent) and t[0] < s.recent[-1]:
            s.recent = np.sort(np.concatenate((s.recent, t)))
        else:
            s.recent = np.concatenate((s.recent, t))
        if len(s.recent) > 2 * _RECENT:
            s.recent = s.recent[-_RECENT:]
        if len(s.t) and t[0] < s.t[-1]:
            tt = np.concatenate((s.t, t))
            o = np.argsort(tt, kind="stable")
            s.t, s.v = tt[o], np.concatenate((s.v, values))[o]
        else:
            s.t = np.concatenate((s.t, t))
            s.v = values if s.v is None or len(s.v) == 0 else np.concatenate((s.v, values))

    # ---- rates ----
    def _measure(self, s: _Stream) -> float:
        r = s.recent
        if len(r) < RATE_SAMPLES:
            return math.nan
        d = np.diff(r[-512:])
        d = d[d > 0]
        if len(d) < RATE_SAMPLES // 2:
            return math.nan
        med = float(np.median(d))
        # refine over the window: whole number of periods between first and last stamp
        span = float(r[-1] - r[max(0, len(r) - 513)])
        steps = round(span / med)
        if steps >= 1 and abs(span / steps - med) < 0.1 * med:
            med = span / steps
        return _snap_rate(1.0 / med)

    def rates(self) -> dict[str, float]:
        """Measured rate of each stream [Hz], NaN while unknown."""
        return {"output": self.out.rate, "input": self.inp.rate}

    def _check_rate(self, s: _Stream) -> None:
        s.rate = self._measure(s)
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
        if self.out.channels is None or not self.out.seen:
            return []
        if not math.isfinite(self.fs):
            fs = self._measure(self.out)
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
        T = self.period
        self._choose_mode(flush)
        if self.mode == "pending":
            return []
        streams = [self.out] + ([self.inp] if self.mode == "io" else [])
        if any(len(s.t) == 0 for s in streams):
            return []
        hold = 0.0 if flush else self.reorder_window
        ready = min(float(s.t[-1]) for s in streams) - hold
        kmax = math.floor((ready - self.t0) / T + STAMP_TOLERANCE)
        # grid instants before the next sample of a stream that cannot be filled: skip them
        g_next = self.t0 + self.next_k * T
        k_skip = self.next_k
        for s in streams:
            i = int(np.searchsorted(s.t, g_next - STAMP_TOLERANCE * T))
            if i < len(s.t) and s.t[i] - g_next > (self.max_fill + 1) * T:
                k_skip = max(k_skip, math.ceil((s.t[i] - self.t0) / T - STAMP_TOLERANCE))
        k_skip = min(k_skip, kmax + 1)
        if k_skip > self.next_k:
            self._missing(k_skip - self.next_k)
            self.next_k = k_skip
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
            v, ok, interp, st = self._sample_at(s, g, T)
            if s is self.out:
                stamps_t = st
            valid &= ok
            vals.append(v)
            n_interp = int((interp & ok).sum())
            if n_interp:
                self.counters[f"{s.name}_{'resampled' if s.mismatch else 'repaired'}"] += n_interp
        chunks = self._split(k, stamps_t, valid, vals)
        self.next_k = kmax + 1
        keep_from = self.watermark - (self.max_fill + 2) * T
        for s in (self.out, self.inp):
            i = int(np.searchsorted(s.t, keep_from))
            if i:
                s.t, s.v = s.t[i:], s.v[i:]
        return chunks

    def _choose_mode(self, flush: bool) -> None:
        """Input-output while input samples arrive, output-only otherwise (with a log line)."""
        out_end = float(self.out.t[-1]) if len(self.out.t) else -math.inf
        if self.mode == "pending":
            if self.inp.seen and not self.inp.rejected:
                self.mode = "io"
            elif out_end - self.t0 >= INPUT_WAIT or flush:
                self.mode = "output_only"
                self._event(f"no input samples within {INPUT_WAIT:g} s of data: output-only")
            return
        stopped = self.out.max_t - self.inp.max_t > INPUT_WAIT
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
        self._pending_reset = True
        self._segment_open = False

    def _missing(self, n: int) -> None:
        """``n`` grid instants without usable data (counted as a gap when data resumes)."""
        self._gap_run += max(0, int(n))

    def _close_gap(self) -> None:
        n, self._gap_run = self._gap_run, 0
        if n <= 0:
            return
        if self._emitted_any:
            self.counters["gaps"] += 1
            self.counters["gap_samples"] += n
            self._event(f"gap of {n * self.period:.3f} s ({n} samples): Hankel window restarted")
            self._segment_open = False
        else:
            self.counters["unaligned_start_samples"] += n

    def _sample_at(self, s: _Stream, g: np.ndarray, T: float):
        """Values of stream ``s`` at grid times ``g``: taken (stamp within tolerance) or
        interpolated between neighbours at most ``max_fill + 1`` periods apart; also the stamp
        of each value (the sample's own when taken, the grid time when interpolated)."""
        t = s.t
        j = np.searchsorted(t, g)
        jl = np.clip(j - 1, 0, len(t) - 1)
        jr = np.clip(j, 0, len(t) - 1)
        dl, dr = np.abs(g - t[jl]), np.abs(t[jr] - g)
        tol = STAMP_TOLERANCE * T
        exact_l, exact_r = dl <= tol, dr <= tol
        exact = exact_l | exact_r
        ji = np.where(exact_l & (~exact_r | (dl <= dr)), jl, jr)
        out = s.v[ji].copy()
        span = t[jr] - t[jl]
        inner = (j > 0) & (j < len(t)) & (span > 0)
        interp = ~exact & inner & (span <= (self.max_fill + 1 + STAMP_TOLERANCE) * T)
        if interp.any():
            w = ((g[interp] - t[jl[interp]]) / span[interp])[:, None]
            out[interp] = s.v[jl[interp]] * (1 - w) + s.v[jr[interp]] * w
        ok = exact | interp
        stamps = np.where(exact, t[ji], g)  # a sample taken as it is keeps its own stamp
        return out, ok, interp, stamps

    def _split(self, k, g, valid, vals) -> list[Chunk]:
        chunks: list[Chunk] = []
        if not len(k):
            return chunks
        edges = np.flatnonzero(np.diff(np.concatenate(([0], valid.astype(np.int8), [0]))))
        starts, ends = edges[::2], edges[1::2]
        pos = 0
        for a, b in zip(starts, ends, strict=True):
            self._missing(a - pos)
            self._close_gap()
            pos = b
            stamps = self.origin_ns + np.round(g[a:b] * 1e9).astype(np.int64)
            chunks.append(
                Chunk(
                    stamps_ns=stamps,
                    y=vals[0][a:b],
                    u=vals[1][a:b] if len(vals) > 1 else None,
                    new_segment=not self._segment_open,
                    reset=self._pending_reset,
                )
            )
            self._pending_reset = False
            self._segment_open = True
            self._emitted_any = True
        self._missing(len(k) - pos)
        return chunks


def _beyond_jump(t: np.ndarray, last: float) -> np.ndarray:
    """Samples after the first forward jump of more than FUTURE_JUMP in the stamp-sorted
    sequence that continues from ``last`` (a block spanning many seconds is no jump)."""
    tt = np.sort(t)
    step = np.diff(np.concatenate(([last], tt)))
    jumps = np.flatnonzero(step > FUTURE_JUMP)
    if not len(jumps):
        return np.zeros(len(t), bool)
    return t >= tt[jumps[0]]


def _snap_rate(fs: float) -> float:
    """The roundest rate (whole, tenths or hundredths of Hz) within ``SNAP_PPM`` of ``fs``:
    stamps stored as float seconds or quantized by a driver make 100 Hz measure as 99.99993."""
    for digits in (0, 1, 2):
        r = round(fs, digits)
        if r > 0 and abs(r - fs) <= SNAP_PPM * 1e-6 * fs:
            return float(r)
    return fs


def _distance_to_nearest(sorted_t: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Distance from each ``t`` to the nearest element of the non-empty sorted ``sorted_t``."""
    j = np.searchsorted(sorted_t, t)
    jl = np.clip(j - 1, 0, len(sorted_t) - 1)
    jr = np.clip(j, 0, len(sorted_t) - 1)
    return np.minimum(np.abs(sorted_t[jl] - t), np.abs(sorted_t[jr] - t))
