"""A share of one CPU core for the live node's realizations (pure: no rclpy).

A realization (Cholesky of the RLS factor, the projection's eigendecomposition, the
realization, modal extraction, spurious-mode tests, tracking) costs the cube of the window's
rows; the RLS update that absorbs each sample costs their square. On a slow or busy flight
computer the realizations are what make the estimator fall behind, and an estimator that falls
behind publishes late estimates, so the notch filters hold. :class:`RealizationBudget` is a
token bucket of CPU seconds: ``share`` of every wall-clock second accrues (at most ``burst_s``
in store) and each realization spends what it cost, measured. A publication period that finds
the store empty is absorbed by the RLS without realizing (``Pipeline._update``; counted as
``realizations_deferred``), so the estimate stays current and the realization rate falls to what
the machine affords; when the machine frees up, it returns to ``realization_rate``.

The budget is wall-clock, so only the live node (the worker process) uses one: the offline tool
realizes at ``realization_rate`` whatever it costs, and a live node with
``realization_budget: 0`` gives the offline numbers.
"""

from __future__ import annotations

import time
from collections.abc import Callable

#: Most CPU seconds held in store (after an idle spell the next realizations run at once, and
#: one realization costs at most tens of milliseconds).
BURST_S = 0.3


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

    def _refill(self) -> None:
        now = self._clock()
        self._store = min(self.burst_s, self._store + self.share * max(0.0, now - self._last))
        self._last = now

    def allow(self) -> bool:
        """May the next publication period realize?"""
        self._refill()
        return self._store >= 0.0

    def spend(self, seconds: float) -> None:
        self._refill()
        self._store -= max(0.0, float(seconds))
        self.spent_s += max(0.0, float(seconds))
