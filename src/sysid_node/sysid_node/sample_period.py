"""The sample period that stamps measure when messages are lost (pure; both nodes use it)."""

from __future__ import annotations

import numpy as np

#: The shortest intervals are taken to span at most this many periods (:func:`unit_period`).
MAX_DIVISOR = 6
#: An interval is a whole multiple of the period within this fraction of a period ...
MULTIPLE_TOL = 0.2
#: ... and at least this fraction of the intervals must be, for the multiples to be trusted.
FIT_FRACTION = 0.8


def unit_period(p: np.ndarray) -> float:
    """The period of which the per-sample intervals ``p`` are whole multiples. Lost messages
    make an interval span 2, 3, ... periods, and a run of losses can fill most of the window,
    so neither the median nor a fixed quantile of ``p`` is the period. The shortest intervals
    (5 % quantile) span m periods for some small m: for m = 1, 2, ... the candidate period is
    refined on the intervals that are whole multiples of it (sum of intervals / sum of
    multiples, the short ones first so that jitter does not pick a wrong multiple), and the
    first candidate of which at least ``FIT_FRACTION`` of the intervals are whole multiples
    (within ``MULTIPLE_TOL`` of a period) is the period. Without one (stamps jitter by a large
    part of a period), the median of the intervals near the 20 % quantile."""
    base = float(np.quantile(p, 0.05))
    if base > 0:
        for m in range(1, MAX_DIVISOR + 1):
            t = base / m
            for longest in (4.0, 16.0, np.inf):  # multiples used to refine, growing
                k = np.maximum(np.rint(p / t), 1.0)
                fits = (np.abs(p / t - k) <= MULTIPLE_TOL) & (k <= longest)
                if not fits.any():
                    break
                t = float(np.sum(p[fits]) / np.sum(k[fits]))
            k = np.maximum(np.rint(p / t), 1.0)
            if np.mean(np.abs(p / t - k) <= MULTIPLE_TOL) >= FIT_FRACTION:
                return t
    q = np.quantile(p, 0.2)
    return float(np.median(p[(p >= q / 1.5) & (p <= 1.5 * q)]))
