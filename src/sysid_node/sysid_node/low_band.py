"""The low group of a split automatic band: an estimator of its own at a rate of its own.

With the automatic band (``freq_max: 0``) one recursive DSRA serves every mode from the lowest
peak to the band edge. Its Hankel window (block rows over the rate, Eq. (A1)) must span half a
period of the lowest peak, within a row budget (``params.effective_block_rows``): a 2 Hz mode at
750 Hz would need 190 block rows. When that budget caps the window (``params.window_capped``)
and the peaks leave a gap (``core.band.split_frequency``), the modes below the gap come from a
second estimator fed the same samples, low-passed and decimated to the lowest rate at which the
default block rows span their share of a period of the lowest peak (half, a full one output-only
from one output: ``params.window_periods``) and the split stays below a third of the rate:
its window spans the lowest mode, its memory holds as many samples per period as the
main estimator's when that one's window fits, and its model order is not spent on the modes
above. The main estimator's modes below the split are replaced by this one's
(``pipeline.Pipeline._update``); both realize at ``realization_rate`` in data time.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import replace
from typing import Any

import numpy as np

from sysid_node import params as P
from sysid_node.decimation import Decimator

#: The low group's rate is at least this many times the split frequency (its modes below a
#: third of the rate, inside the decimation filter's pass band at 0.4 x the rate) ...
RATE_PER_SPLIT = 3.0
#: The largest decimation factor of the low group.
MAX_FACTOR = 100
#: Realizations the low group keeps for :meth:`LowBand.current` (those of a piece fed at once).
RECENT_REALIZATIONS = 16


def max_split_hz(values: dict[str, Any], n_outputs: int, n_inputs: int, fs: float,
                 low_hz: float) -> float:
    """The highest split [Hz] at which the low group's Hankel window can still span half a
    period of ``low_hz`` [Hz] (``params.window_capped`` false at its rate, a divisor of ``fs``
    [Hz]): the rate may be at most 2 ``low_hz`` times the row budget, and the split at most
    1/RATE_PER_SPLIT of it. Infinite with configured block rows."""
    if int(values.get("block_rows", 0)) > 0 or not (math.isfinite(low_hz) and low_hz > 0):
        return math.inf
    cap = P.max_auto_rows(n_outputs, n_inputs)
    factor = min(MAX_FACTOR, max(1, math.ceil(fs / (2.0 * low_hz * cap) - 1e-9)))
    return fs / factor / RATE_PER_SPLIT


class LowBand:
    """Decimator and RecursiveDSRA of the group below ``split_hz`` [Hz].

    ``fs`` [Hz] is the main estimator's rate (the samples this one is fed), ``low_hz`` the
    band's lowest peak (the window and the memory follow it as for the main estimator),
    ``n_peaks`` the clear structure peaks below the split (the model order,
    ``params.effective_max_order``)."""

    def __init__(self, estimator_cls: type, values: dict[str, Any], n_outputs: int,
                 n_inputs: int, fs: float, split_hz: float, low_hz: float,
                 n_peaks: int = 0) -> None:
        self.split_hz = float(split_hz)
        rows = P.effective_block_rows(values, n_outputs, n_inputs)  # the default window
        # the lowest rate at which the default rows span their share of the lowest period
        rate = max(RATE_PER_SPLIT * split_hz,
                   low_hz * rows / P.window_periods(n_outputs, n_inputs))
        factor = max(1, min(MAX_FACTOR, math.floor(fs / rate + 1e-9)))
        self.decimator = Decimator(factor, fs)
        self.rate = fs / factor
        self.block_rows = P.effective_block_rows(values, n_outputs, n_inputs, self.rate, low_hz)
        top = n_outputs * (self.block_rows - 1)
        self.max_order = max_order = P.effective_max_order(values, n_peaks, top)
        self.low_hz = low_hz
        self.estimator = estimator_cls(
            n_outputs,
            n_inputs=n_inputs,
            fs=self.rate,
            block_rows=self.block_rows,
            max_order=max_order,
            forgetting_factor=P.effective_lambda(values, self.rate, low_hz),
            realization_interval=self.interval(values),
            band=(values["freq_min"], min(split_hz, P.NYQUIST_SAFE_FRACTION * self.rate)),
            damping_bounds=(values["damping_min"], values["damping_max"]),
            max_modes=values["max_modes"],
            stabilize=values["spurious_rejection"],
        )
        self._fs = fs
        self._period_ns = 1e9 / fs
        self._n = 0  # samples fed (the decimator's grid)
        #: (data time [s] on the main estimator's clock, modes below split_hz) of the recent
        #: realizations
        self._recent: deque = deque(maxlen=RECENT_REALIZATIONS)

    def interval(self, values: dict[str, Any]) -> int:
        return max(1, round(self.rate / values["realization_rate"]))

    def describe(self) -> str:
        rate = f"{self.rate:g} Hz"
        if self.decimator.factor > 1:
            rate += f" (decimated by {self.decimator.factor})"
        return (f"band split at {self.split_hz:.4g} Hz: the modes below it from a second "
                f"estimator at {rate}, block rows {self.block_rows}, order {self.max_order}")

    def update(self, u: np.ndarray | None, y: np.ndarray, realize: bool = True,
               end_s: float = math.nan) -> None:
        """Feed samples at the main estimator's rate (``realize`` False: absorb only); ``end_s``
        the main estimator's data time [s] after them."""
        stamps = np.round((self._n + np.arange(len(y))) * self._period_ns).astype(np.int64)
        self._n += len(y)
        _, yd, ud = self.decimator.process(stamps, y, u)
        if not len(yd):
            return
        if not realize:
            self.estimator.absorb(ud, yd)
            return
        est = self.estimator
        models = est.update(ud, yd) or []
        # contribution is over the innovation variance, which for the same noise level
        # (spectral density) scales with the rate: on the main estimator's scale, so that
        # the ranking of the two groups' modes (max_modes) compares like with like
        scale = self.rate / self._fs
        for mdl in models:
            lag = est.samples_seen / self.rate - float(getattr(mdl, "time_s", math.nan))
            t = end_s - lag if math.isfinite(lag) else end_s
            self._recent.append((t, [replace(m, contribution=m.contribution * scale)
                                     for m in mdl.modes if m.frequency_hz < self.split_hz]))

    def current(self, now_s: float, realization_rate: float) -> list:
        """The modes of the latest realization made by data time ``now_s`` [s] (within one
        sample at this rate), unless it is older than two realization periods (an estimator
        that stopped realizing says nothing). Each of the main estimator's realizations thus
        gets this estimator's own of the same time, not the latest of the piece both were fed:
        two main realizations in a piece would count one low realization twice in the
        tracker (its confirmation and its median)."""
        made = [(t, m) for t, m in self._recent if t <= now_s + 1.0 / self.rate]
        if not made:
            return []
        t, modes = made[-1]
        return modes if now_s - t <= 2.0 / realization_rate else []

    def restart(self) -> None:
        """Data resumes after a gap: no Hankel row may span it."""
        self.decimator.restart()
        est = self.estimator  # RecursiveDSRA.update skips a NaN sample and restarts after it
        est.update(np.full((1, est.n_inputs), np.nan) if est.n_inputs else None,
                   np.full((1, est.n_outputs), np.nan))

    def apply_live(self, values: dict[str, Any], changes: dict[str, Any]) -> None:
        est = self.estimator
        if "spurious_rejection" in changes:
            est.stabilize = bool(values["spurious_rejection"])
        if {"forgetting_factor", "memory_time_constant", "memory_periods"} & changes.keys():
            est.set_forgetting_factor(P.effective_lambda(values, self.rate, self.low_hz))
        if "max_modes" in changes:
            est.max_modes = values["max_modes"]
        if "realization_rate" in changes:
            est.realization_interval = self.interval(values)
