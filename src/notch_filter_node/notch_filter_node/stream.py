"""Checks of the incoming signal stream and event bookkeeping of the node (pure, no rclpy).

- :class:`StampCheck`: every message's first stamp against the previous one (a message sent twice
  is dropped, one from the past is dropped, a jump back by more than ``restart_jump`` is a
  restarted stream), and the sample rate measured from the stamps over the last ``window``
  messages: each gives ``(first stamp - previous first stamp) / previous sample count``; a lost
  message makes that a multiple of the period, never less, so the period is the median of the
  intervals within a factor 1.5 of their 20th percentile (lost messages and jitter do not move
  it, a real rate change does within a fifth of the window).
- :func:`missing_samples` / :func:`bridge`: a message that starts more than half a period after
  the expected next sample follows lost ones; the filter is run over a straight line between
  the last sample and the new one in their place (outputs not published), so its memory stays
  on the stream's time base instead of seeing a phase jump.
- :class:`LayoutTracker`: the channel layout (names, or count when unnamed). Channels are mapped
  to the bank's by name, so a reorder is filtered correctly at once; a new layout (other names
  or count) is adopted once it has come ``confirm`` messages in a row: until then its known
  channels are filtered and the others pass through (and the node says so). A layout flapping
  every message never rebuilds the bank.
- :class:`EventLog`: counts events by key, says which lines to log (the first of a kind at once,
  then one summary per ``period`` with the count since) and what happened recently (the
  diagnostics level follows recent events, not the first one ever).
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from sysid_node.sample_period import unit_period

OK, DUPLICATE, OUT_OF_ORDER, RESTART = "", "duplicate", "out_of_order", "restart"
#: The measured period is recomputed every this many messages.
RECOMPUTE = 4


class StampCheck:
    """Order of the stream's stamps and the rate they measure."""

    def __init__(self, window: int = 64, restart_jump_s: float = 1.0,
                 min_intervals: int = 16) -> None:
        self.window = int(window)
        self.restart_jump_ns = int(restart_jump_s * 1e9)
        self.min_intervals = int(min_intervals)
        self.first_ns: int | None = None
        self.count = 0
        self._periods: deque[float] = deque(maxlen=self.window)
        self._added = 0  # intervals since the period was last computed
        self._period = math.nan

    def check(self, first_ns: int) -> str:
        """'' when the message (first sample stamped ``first_ns``) comes after the previous one,
        else DUPLICATE, OUT_OF_ORDER or RESTART (a jump back by more than the restart jump)."""
        if self.first_ns is None or first_ns > self.first_ns:
            return OK
        if first_ns == self.first_ns:
            return DUPLICATE
        if self.first_ns - first_ns > self.restart_jump_ns:
            return RESTART
        return OUT_OF_ORDER

    def accept(self, first_ns: int, samples: int) -> None:
        """Record an accepted message of ``samples`` samples (after :meth:`check`)."""
        if self.first_ns is not None and first_ns > self.first_ns and self.count > 0:
            self._periods.append((first_ns - self.first_ns) * 1e-9 / self.count)
            self._added += 1
        self.first_ns, self.count = int(first_ns), int(samples)

    def restart(self) -> None:
        """Forget the history (the stream restarted, or the bank was rebuilt)."""
        self.first_ns, self.count = None, 0
        self._periods.clear()
        self._added, self._period = 0, math.nan

    def period(self) -> float:
        """Measured sample period [s], NaN until ``min_intervals`` are known (recomputed every
        ``RECOMPUTE`` messages: per-message cost stays small at high rates)."""
        if len(self._periods) < self.min_intervals:
            return math.nan
        if self._added >= RECOMPUTE or not math.isfinite(self._period):
            self._period = unit_period(np.asarray(self._periods))
            self._added = 0
        return self._period

    def rate(self) -> float:
        """Measured sample rate [Hz], NaN while unknown."""
        p = self.period()
        return 1.0 / p if p > 0 else math.nan


def missing_samples(prev_last_ns: int | None, first_ns: int, fs: float) -> int:
    """Samples lost between a message's last sample and the next message's first (0 if none
    or unknown)."""
    if prev_last_ns is None or not fs > 0:
        return 0
    return max(int(round((first_ns - prev_last_ns) * 1e-9 * fs)) - 1, 0)


def bridge(last_row: np.ndarray, first_row: np.ndarray, missing: int) -> np.ndarray:
    """``missing`` rows on the straight line between two samples (both excluded)."""
    w = (np.arange(1, missing + 1) / (missing + 1))[:, None]
    return (1.0 - w) * last_row[None, :] + w * first_row[None, :]


@dataclass
class Layout:
    """Channel names (may be empty: unnamed) and count."""

    names: tuple[str, ...]
    count: int

    def key(self) -> tuple:
        return (self.names, self.count) if self.names else ((), self.count)


@dataclass
class Mapping:
    """Where each channel of a message goes in the bank: ``index[j]`` is the bank channel of the
    message's channel j, -1 = not in the bank (passed through). ``event`` is '' (the bank's
    layout), 'reordered', 'pending' (a new layout not confirmed yet) or 'adopted' (the bank must
    be rebuilt for it now; ``kept[i]`` is the old bank channel of new bank channel i, or -1)."""

    index: np.ndarray
    event: str = ""
    kept: np.ndarray | None = None
    unknown: list[str] = field(default_factory=list)


class LayoutTracker:
    """The bank's channel layout and the rule for changing it (see the module docstring)."""

    def __init__(self, confirm: int = 5) -> None:
        self.confirm = max(int(confirm), 1)
        self.layout: Layout | None = None
        self._pending: Layout | None = None
        self._seen = 0

    def observe(self, names: Sequence[str], count: int) -> Mapping:
        names = tuple(str(n) for n in names) if len(names) == count else ()
        new = Layout(names, int(count))
        if self.layout is None:
            self.layout = new
            return Mapping(np.arange(count), "adopted", np.full(count, -1))
        cur = self.layout
        if new.key() == cur.key():
            self._pending, self._seen = None, 0
            return Mapping(np.arange(count))
        index = self._map(cur, new)
        if (new.names and cur.names and sorted(new.names) == sorted(cur.names)
                and len(set(new.names)) == len(new.names)):
            self._pending, self._seen = None, 0
            return Mapping(index, "reordered")
        if self._pending is not None and self._pending.key() == new.key():
            self._seen += 1
        else:
            self._pending, self._seen = new, 1
        unknown = [new.names[j] if new.names else f"#{j}" for j in np.flatnonzero(index < 0)]
        if self._seen >= self.confirm:
            self.layout, self._pending, self._seen = new, None, 0
            return Mapping(np.arange(count), "adopted", index, unknown)
        return Mapping(index, "pending", None, unknown)

    @staticmethod
    def _map(cur: Layout, new: Layout) -> np.ndarray:
        """Bank channel of each of ``new``'s channels (by name when both are named, else by
        position), -1 where there is none."""
        if cur.names and new.names:
            pos = {n: i for i, n in enumerate(cur.names)}
            return np.array([pos.get(n, -1) for n in new.names], dtype=int)
        k = np.arange(new.count)
        return np.where(k < cur.count, k, -1)


class EventLog:
    """Event counts, throttled log lines and recent events (times in seconds, any clock)."""

    def __init__(self, period: float = 5.0, recent: float = 10.0) -> None:
        self.period = float(period)
        self.recent_s = float(recent)
        self.counts: dict[str, int] = {}
        self._last_log: dict[str, float] = {}
        self._since: dict[str, int] = {}
        self._times: dict[str, deque[float]] = {}

    def add(self, key: str, text: str, now: float, n: int = 1) -> str | None:
        """Count ``n`` events of ``key``; the line to log now, or None (summarised later)."""
        self.counts[key] = self.counts.get(key, 0) + n
        self._times.setdefault(key, deque(maxlen=1000)).append(now)
        last = self._last_log.get(key, -math.inf)
        if now - last >= self.period:
            more = self._since.pop(key, 0)
            self._last_log[key] = now
            return text + (f" (and {more} more since the last report)" if more else "")
        self._since[key] = self._since.get(key, 0) + n
        return None

    def due(self, now: float) -> list[str]:
        """Summaries of events not logged yet whose period has passed."""
        out = []
        for key, more in list(self._since.items()):
            if more and now - self._last_log.get(key, -math.inf) >= self.period:
                out.append(f"{more} more '{key}' event(s) in the last {self.period:g} s "
                           f"({self.counts[key]} in total)")
                self._last_log[key] = now
                del self._since[key]
        return out

    def recent(self, now: float) -> dict[str, int]:
        """Events per key within the last ``recent`` seconds."""
        out = {}
        for key, times in self._times.items():
            while times and now - times[0] > self.recent_s:
                times.popleft()
            if times:
                out[key] = len(times)
        return out
