"""The sample period that stamps measure when messages are lost (pure; both nodes use it)."""

from __future__ import annotations

import numpy as np

#: The median interval is taken to span at most this many periods (:func:`unit_period`).
MAX_DIVISOR = 64
#: An interval is a whole multiple of the period within this fraction of a period ...
MULTIPLE_TOL = 0.2
#: ... and at least this fraction of the intervals must be, for the multiples to be trusted.
FIT_FRACTION = 0.8


def unit_period(p: np.ndarray) -> float:
    """The period of which the per-sample intervals ``p`` are whole multiples.

    Lost messages make an interval span 2, 3, ... periods, and a run of losses can fill most of
    the window, so neither the median nor a fixed quantile of ``p`` is the period; a few samples
    off the grid (late ones sorted in) make short intervals, so neither is the shortest. The
    median interval spans m periods for some m: for m = 1, 2, ... the candidate period (median
    / m) is refined on the intervals that are whole multiples of it (sum of intervals / sum of
    multiples, the short multiples first so that jitter does not pick a wrong one), and the
    first - largest - candidate of which at least ``FIT_FRACTION`` of the intervals are whole
    multiples (within ``MULTIPLE_TOL`` of a period) is the period. Without one (stamps jitter
    by a large part of a period), the median interval."""
    base = float(np.quantile(p, 0.5, method="lower"))  # an interval that occurred: m periods
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
    return float(np.median(p))
