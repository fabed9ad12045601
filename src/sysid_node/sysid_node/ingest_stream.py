"""One stream of the ingest (pure, no rclpy): its samples held in stamp order, the screening of
each arriving block (channel layout, stamps far ahead, duplicates, late samples) and the rate
measured from its stamps. :class:`sysid_node.ingest.Ingest` owns one per stream (output and
input) and aligns them onto the sample grid.

Every dropped or altered sample is counted in :class:`IngestReport` (``<stream>_<reason>``)
with a reason line in its events.
"""

from __future__ import annotations

import math
from collections import Counter, deque
from dataclasses import dataclass, field

import numpy as np

from .sample_period import unit_period

#: A stamp within this fraction of the period of a grid instant is taken as taken at that instant.
STAMP_TOLERANCE = 0.25
#: Samples needed to measure a rate.
RATE_SAMPLES = 20
#: A new time line once held samples span this much data [s] (see ingest.TIME_JUMP).
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
class IngestReport:
    """Counters of dropped/altered samples and the latest reason lines."""

    counters: Counter[str] = field(default_factory=Counter)
    events: deque[str] = field(default_factory=lambda: deque(maxlen=200))

    def event(self, text: str) -> None:
        self.events.append(text)


@dataclass
class Stream:
    """Samples of one stream not yet handed out, in stamp order (``t`` [s relative to the
    ingest's origin], ``v`` ``(n, channels)``), and what its screening holds back."""

    name: str
    channels: int | None
    report: IngestReport
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

    def _count(self, key: str, n: int) -> None:
        self.report.counters[f"{self.name}_{key}"] += n

    # ---- channel layout ----
    def map_names(self, values: np.ndarray, names: tuple[str, ...] | None):
        """The first channel count and names seen are the stream's; the same channels in
        another order are mapped back by name. Returns ``(values, names)``."""
        n, c = values.shape
        if self.channels is None and c > 0:
            self.channels = c
            self.v = np.empty((0, c))
        if self.names is None and names is not None and c == self.channels:
            self.names = names
        if c == self.channels and names is not None and names != self.names:
            if sorted(names) == sorted(self.names):  # the same channels in another order
                values = values[:, [names.index(x) for x in self.names]]
                if not self.report.counters[f"{self.name}_reordered"]:
                    self.report.event(
                        f"{self.name}: channels arrive in another order ({', '.join(names)}): "
                        f"mapped back by name to {', '.join(self.names)}")
                self._count("reordered", n)
                names = self.names
        return values, names

    def other_layout(self, c: int, names: tuple[str, ...] | None) -> bool:
        """A block of ``c`` channels named ``names`` is not in the stream's layout (saying so
        when the stream returns to its layout after another one was seen)."""
        if c != self.channels or (names is not None and names != self.names):
            return True
        if self.layout:
            self.report.event(f"{self.name}: back to the {self.channels}-channel layout")
            self.layout = []
        return False

    def hold_layout(self, stamps_ns: np.ndarray, values: np.ndarray,
                    names: tuple[str, ...] | None) -> bool:
        """Samples in another channel layout (count or names): dropped and counted while
        unconfirmed; adopted (True: the caller restarts the time line) once only they have
        arrived for LAYOUT_CONFIRM_S of data."""
        n, c = values.shape
        key = "wrong_channels" if c != self.channels else "channel_names_changed"
        was = (f"{self.channels} channels" if c != self.channels
               else f"names {', '.join(self.names or ())}")
        now = f"{c} channels" if c != self.channels else f"names {', '.join(names or ())}"
        self._count(key, n)
        if not self.layout:
            self.report.event(f"{self.name}: {n} sample(s) with {now}, expected {was}: dropped")
        self.layout.append((stamps_ns, values, names))
        held = sum(len(x[0]) for x in self.layout)
        span = (max(int(x[0].max()) for x in self.layout)
                - min(int(x[0].min()) for x in self.layout)) * 1e-9
        same = all(x[1].shape[1] == c and x[2] == names for x in self.layout)
        if not same or held > MAX_HELD:
            self.layout = [(stamps_ns, values, names)]
            return False
        if span < LAYOUT_CONFIRM_S:
            return False
        self.report.event(f"{self.name}: {now} instead of {was} for {span:.2f} s of data: new "
                          "layout adopted, estimator reset")
        self.report.counters["layout_changes"] += 1
        self.channels, self.names, self.layout = c, names, []
        return True

    # ---- stamps ----
    def hold_future(self, t: np.ndarray, values: np.ndarray, ahead: np.ndarray):
        """Hold samples stamped far ahead; return the others. The held ones are accepted as a
        forward clock jump once they span TIME_RESET_SPAN of data, dropped as bad stamps once
        the stream's own data moved on by that much without them."""
        if ahead.any():
            if not self.future:  # the stream's newest data when they arrived (this block's too)
                rest = t[~ahead]
                self.future_since = max(self.max_t, float(rest.max()) if len(rest) else -math.inf)
            self.future.append((t[ahead], values[ahead]))
            t, values = t[~ahead], values[~ahead]
        ft = np.concatenate([x[0] for x in self.future])
        if float(ft.max() - ft.min()) >= TIME_RESET_SPAN and len(t) == 0:
            held, self.future = self.future, []
            self.report.event(f"{self.name}: stamps jumped ahead by "
                              f"{float(ft.min()) - self.max_t:.3f} s: new data after a gap")
            return (np.concatenate([x[0] for x in held]),
                    np.concatenate([x[1] for x in held]))
        newest = max(self.max_t, float(t.max()) if len(t) else -math.inf)
        if newest - self.future_since >= TIME_RESET_SPAN or len(ft) > MAX_HELD:
            self._count("bad_stamp", len(ft))
            self.report.event(f"{self.name}: {len(ft)} sample(s) stamped "
                              f"{float(ft.min()) - newest:.6g} s or more ahead of the stream: "
                              "dropped (bad stamp)")
            self.future = []
        return t, values

    def add(self, t: np.ndarray, values: np.ndarray, tol: float, watermark: float) -> None:
        """Add samples, dropping (and counting) duplicate stamps (within ``tol`` [s] of one
        another or of a recent sample) and late ones (at or before ``watermark``, the last
        grid instant handed out); out-of-order arrivals are counted and sorted in."""
        n = len(t)
        prev_max = np.maximum.accumulate(np.concatenate(([self.max_t], t)))[:-1]
        ooo = int((t < prev_max).sum())
        if ooo:
            self._count("out_of_order", ooo)
        self.max_t = max(self.max_t, float(t.max()))
        order = np.argsort(t, kind="stable")
        t, values = t[order], values[order]
        dup = np.zeros(n, bool)
        if n > 1:
            dup[1:] = np.diff(t) <= tol
        if len(self.recent):
            dup |= _distance_to_nearest(self.recent, t) <= tol
        if dup.any():
            self._count("duplicate", int(dup.sum()))
            self.report.event(f"{self.name}: {int(dup.sum())} duplicate stamp(s) dropped")
        late = ~dup & (t <= watermark + tol)
        if late.any():
            self._count("late", int(late.sum()))
            self.report.event(f"{self.name}: {int(late.sum())} sample(s) older than the data "
                              "already processed (stamps went backwards): dropped")
        keep = ~dup & ~late
        if not keep.any():
            return
        t, values = t[keep], values[keep]
        self._count("accepted", len(t))
        self.seen = True
        if len(self.recent) and t[0] < self.recent[-1]:
            self.recent = np.sort(np.concatenate((self.recent, t)))
        else:
            self.recent = np.concatenate((self.recent, t))
        if len(self.recent) > 2 * _RECENT:
            self.recent = self.recent[-_RECENT:]
        if len(self.t) and t[0] < self.t[-1]:
            tt = np.concatenate((self.t, t))
            o = np.argsort(tt, kind="stable")
            self.t, self.v = tt[o], np.concatenate((self.v, values))[o]
        else:
            self.t = np.concatenate((self.t, t))
            self.v = (values if self.v is None or len(self.v) == 0
                      else np.concatenate((self.v, values)))

    def drop_before(self, t: float) -> None:
        """Forget the samples stamped before ``t`` [s]."""
        i = int(np.searchsorted(self.t, t))
        if i:
            self.t, self.v = self.t[i:], self.v[i:]

    # ---- rate and values on the grid ----
    def measure_rate(self) -> float:
        """Rate of the recent stamps [Hz] (snapped to a round value), NaN while unknown."""
        r = self.recent
        if len(r) < RATE_SAMPLES:
            return math.nan
        d = np.diff(r[-512:])
        d = d[d > 0]
        if len(d) < RATE_SAMPLES // 2:
            return math.nan
        med = unit_period(d.astype(float))  # not the median: lost samples double intervals
        # refine over the window: whole number of periods between first and last stamp
        span = float(r[-1] - r[max(0, len(r) - 513)])
        steps = round(span / med)
        if steps >= 1 and abs(span / steps - med) < 0.1 * med:
            med = span / steps
        return _snap_rate(1.0 / med)

    def sample_at(self, g: np.ndarray, T: float, max_fill: int):
        """Values at grid times ``g`` (period ``T``): taken (stamp within tolerance) or
        interpolated between neighbours at most ``max_fill + 1`` periods apart. Returns
        ``(values, ok, interpolated, stamps)``: the stamp of each value is the sample's own
        when taken, the grid time when interpolated."""
        t = self.t
        j = np.searchsorted(t, g)
        jl = np.clip(j - 1, 0, len(t) - 1)
        jr = np.clip(j, 0, len(t) - 1)
        dl, dr = np.abs(g - t[jl]), np.abs(t[jr] - g)
        tol = STAMP_TOLERANCE * T
        exact_l, exact_r = dl <= tol, dr <= tol
        exact = exact_l | exact_r
        ji = np.where(exact_l & (~exact_r | (dl <= dr)), jl, jr)
        out = self.v[ji].copy()
        span = t[jr] - t[jl]
        inner = (j > 0) & (j < len(t)) & (span > 0)
        interp = ~exact & inner & (span <= (max_fill + 1 + STAMP_TOLERANCE) * T)
        if interp.any():
            w = ((g[interp] - t[jl[interp]]) / span[interp])[:, None]
            out[interp] = self.v[jl[interp]] * (1 - w) + self.v[jr[interp]] * w
        ok = exact | interp
        stamps = np.where(exact, t[ji], g)  # a sample taken as it is keeps its own stamp
        return out, ok, interp, stamps


def beyond_jump(t: np.ndarray, last: float) -> np.ndarray:
    """Samples after the first forward jump of more than FUTURE_JUMP in the stamp-sorted
    sequence that continues from ``last`` (a block spanning many seconds is no jump). Samples
    at or before ``last`` (late ones in the same burst) are not part of that sequence: a late
    block followed by the stream's next samples is no jump."""
    tt = np.sort(t[t > last])
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
