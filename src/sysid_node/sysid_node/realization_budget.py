"""A share of one CPU core for the live node's realizations (pure: no rclpy).

A realization (Cholesky of the RLS factor, the projection's eigendecomposition, the
realization, modal extraction, spurious-mode tests, tracking) costs the cube of the window's
rows; the RLS update that absorbs each sample costs their square. On a slow or busy flight
computer the realizations are what make the estimator fall behind, and an estimator that falls
behind publishes late estimates, so the notch filters hold. :class:`RealizationBudget` is a
token bucket of CPU seconds: ``share`` of every wall-clock second accrues (at most ``burst_s``
in store) and each realization spends what it cost, measured in CPU time of the thread (a
process descheduled in the middle of one, as a busy VM does for up to a second, did not spend
the stall: charging wall-clock time stopped the realizations for seconds after each stall,
and a new mode was confirmed seconds late). On a VM the hypervisor's steal can still inflate a
thread's CPU time tenfold for a moment, so a charge is capped at ``OUTLIER_FACTOR`` times the
median of the last ``RECENT`` ones: a stall costs what a realization costs, while a machine that
really slows down raises the median within a few realizations. A publication period that finds
the store empty is absorbed by the RLS without realizing (``Pipeline._update``; counted as
``realizations_deferred``), so the estimate stays current and the realization rate falls to what
the machine affords; when the machine frees up, it returns to ``realization_rate``.

The budget is wall-clock, so only the live node (the worker process) uses one: the offline tool
realizes at ``realization_rate`` whatever it costs, and a live node with
``realization_budget: 0`` gives the offline numbers.
"""

from __future__ import annotations

import statistics
import time
from collections import deque
from collections.abc import Callable

#: Most CPU seconds held in store (after an idle spell the next realizations run at once, and
#: one realization costs at most tens of milliseconds).
BURST_S = 0.3
#: A charge above this many times the median of the recent ones is a stall, charged at the cap
OUTLIER_FACTOR = 3.0
#: Charges the median is taken over (it applies from the fourth on)
RECENT = 16


class RealizationBudget:
    """Token bucket: ``share`` [0-1] of a core accrues per wall-clock second; :meth:`allow` is
    True while the store is not negative, :meth:`spend` takes a realization's cost [s]."""

    def __init__(self, share: float, burst_s: float = BURST_S,
                 clock: Callable[[], float] = time.monotonic) -> None:
        self.share = float(share)
        self.burst_s = float(burst_s)
        self._clock = clock
        self._store = self.burst_s
        self._last = clock()
        self.spent_s = 0.0  # total spent [s]
        self._recent: deque[float] = deque(maxlen=RECENT)

    def _refill(self) -> None:
        now = self._clock()
        self._store = min(self.burst_s, self._store + self.share * max(0.0, now - self._last))
        self._last = now

    def allow(self) -> bool:
        """May the next publication period realize?"""
        self._refill()
        return self._store >= 0.0

    def spend(self, seconds: float) -> float:
        """Charge a realization's measured cost [s] (capped, see the module docstring); return
        the charge."""
        self._refill()
        cost = max(0.0, float(seconds))
        self._recent.append(cost)
        if len(self._recent) >= 4:
            cost = min(cost, OUTLIER_FACTOR * statistics.median(self._recent))
        self._store -= cost
        self.spent_s += cost
        return cost
