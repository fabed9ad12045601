"""Sensor plausibility on the uniform sample grid (pure): stuck, dead and clipped channels.

A stuck sensor (an output frozen at a constant), a dead excitation (an input channel reading 0
while the structure moves) or a clipping amplifier passes every NaN and stamp check, yet the
estimator then identifies noise or nothing while claiming convergence. These checks look at
the samples the ingest hands out, vectorised per chunk, with the state carried across chunks:

- **stuck / dead**: a channel repeating exactly the same value for at least ``STUCK_S`` seconds
  and ``STUCK_MIN_SAMPLES`` samples, or for ``STUCK_MAX_S`` seconds whatever the count (so at
  any rate within about 1 s of data). A real analog signal with noise never does; a quantised
  one of a quiet structure can, so the run must be long. An output stuck is a FAULT (no mode can
  be identified from it); an input stuck while an output moves is a FAULT too (the input-output
  relation is garbage), an input stuck while the outputs are also still is only DEGRADED.
- **clipped**: within the last ``CLIP_WINDOW_S`` seconds, at least ``CLIP_MIN_FRACTION`` of a
  channel's samples sit exactly at the window's maximum or minimum in runs of at least
  ``CLIP_MIN_RUN`` samples: the signal is flat at a rail. DEGRADED, held ``CLIP_HOLD_S``
  after the last clipping seen (a signal clipping at its peaks does not flap).

Each check recovers by itself when the condition ends (the reason disappears).
"""

from __future__ import annotations

from collections import deque

import numpy as np

HEALTH_OK, HEALTH_DEGRADED, HEALTH_FAULT = 0, 1, 2
#: A channel repeating one value this long [s] ...
STUCK_S = 0.5
#: ... and for at least this many samples is stuck ...
STUCK_MIN_SAMPLES = 20
#: ... but a run this long [s] always is (at low rates: flagged within this much data).
STUCK_MAX_S = 1.0
#: Window of the clipping check [s].
CLIP_WINDOW_S = 1.0
#: Share of the window's samples at its extremes that marks clipping.
CLIP_MIN_FRACTION = 0.02
#: Samples in a row at an extreme to count as flat at a rail.
CLIP_MIN_RUN = 3
#: A clipped channel stays reported this long after the last clipping seen [s] (no flapping).
CLIP_HOLD_S = 2.0


class _Channels:
    """Run lengths of repeated values and the recent window of one stream's channels."""

    def __init__(self, name: str, fs: float) -> None:
        self.name = name
        self.fs = fs
        self.last: np.ndarray | None = None
        self.run: np.ndarray | None = None  # current run of equal values per channel [samples]
        self.window: deque[np.ndarray] = deque()
        self.window_n = 0
        self.seen = 0  # samples so far
        self.clip_seen: dict[int, tuple[int, float]] = {}  # channel -> (sample, share)

    def add(self, x: np.ndarray) -> None:
        n, c = x.shape
        if n == 0:
            return
        if self.last is None or self.last.shape[0] != c:
            self.last, self.run = x[0].copy(), np.zeros(c, np.int64)
        prev = np.vstack([self.last[None], x])
        same = prev[1:] == prev[:-1]  # (n, c)
        # run length at the end of the chunk: trailing equal samples, plus the carried run
        # when the whole chunk continued it
        not_same = ~same
        last_break = np.where(not_same.any(axis=0), n - 1 - np.argmax(not_same[::-1], axis=0), -1)
        trailing = n - 1 - last_break
        self.run = np.where(last_break < 0, self.run + n, trailing)
        self.last = x[-1].copy()
        self.window.append(x)
        self.window_n += n
        self.seen += n
        keep = max(int(CLIP_WINDOW_S * self.fs), 1)
        while self.window_n - self.window[0].shape[0] >= keep:
            self.window_n -= self.window.popleft().shape[0]

    def stuck(self) -> list[tuple[int, float]]:
        """(channel, value) of every channel stuck now."""
        if self.run is None:
            return []
        need = stuck_samples(self.fs)
        return [(int(k), float(self.last[k])) for k in np.flatnonzero(self.run >= need)]

    def moving(self) -> bool:
        """Some channel varied within the window."""
        if not self.window:
            return False
        w = np.concatenate(self.window)
        return bool((w.max(axis=0) > w.min(axis=0)).any())

    def clipped(self) -> list[tuple[int, float]]:
        """(channel, share of the window at a rail) of every channel clipped within the last
        ``CLIP_HOLD_S`` seconds."""
        if self.window_n >= max(int(CLIP_WINDOW_S * self.fs) // 2, 10):
            w = np.concatenate(self.window)
            for k in range(w.shape[1]):
                x = w[:, k]
                hi, lo = x.max(), x.min()
                if hi == lo:
                    continue  # constant: the stuck check's case
                share = float(_in_runs((x == hi) | (x == lo), CLIP_MIN_RUN).mean())
                if share >= CLIP_MIN_FRACTION:
                    self.clip_seen[k] = (self.seen, share)
        hold = int(CLIP_HOLD_S * self.fs)
        self.clip_seen = {k: v for k, v in self.clip_seen.items() if self.seen - v[0] <= hold}
        return [(k, share) for k, (_, share) in sorted(self.clip_seen.items())]


def stuck_samples(fs: float) -> int:
    """Equal samples in a row that make a channel stuck at rate ``fs`` [Hz] (at least 2)."""
    need = max(STUCK_MIN_SAMPLES, int(np.ceil(STUCK_S * fs)))
    return max(2, min(need, int(np.ceil(STUCK_MAX_S * fs))))


def _in_runs(mask: np.ndarray, min_run: int) -> np.ndarray:
    """Elements of ``mask`` inside runs of at least ``min_run`` consecutive True values."""
    edges = np.flatnonzero(np.diff(np.concatenate(([0], mask.astype(np.int8), [0]))))
    out = np.zeros(mask.size, bool)
    for a, b in zip(edges[::2], edges[1::2], strict=True):
        if b - a >= min_run:
            out[a:b] = True
    return out


class SensorChecks:
    """Stuck, dead and clipped channels of the output (and input) stream at rate ``fs``."""

    def __init__(self, fs: float) -> None:
        self.out = _Channels("output", fs)
        self.inp = _Channels("input", fs)

    def add(self, y: np.ndarray, u: np.ndarray | None) -> None:
        self.out.add(y)
        if u is not None:
            self.inp.add(u)

    def faults(self) -> list[tuple[int, str]]:
        """(HEALTH_* level, reason) of every current fault."""
        out: list[tuple[int, str]] = []
        for k, v in self.out.stuck():
            out.append((HEALTH_FAULT, f"output channel {k} stuck at {v:.6g}"))
        moving = self.out.moving()
        for k, v in self.inp.stuck():
            if moving:
                out.append((HEALTH_FAULT, f"input channel {k} stuck at {v:.6g} while the "
                            "outputs move (dead excitation)"))
            else:
                out.append((HEALTH_DEGRADED, f"input channel {k} stuck at {v:.6g}"))
        for s in (self.out, self.inp):
            for k, share in s.clipped():
                out.append((HEALTH_DEGRADED, f"{s.name} channel {k} clipped "
                            f"({100 * share:.0f} % of the last {CLIP_WINDOW_S:g} s at a rail)"))
        return out
