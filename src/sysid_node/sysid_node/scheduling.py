"""The LPV model (2) used online (pure): the scheduling signal's value at an estimate's stamp
and the modes the model predicts there, as ``ModeRecord`` for ``EstimateRecord.predicted_modes``.

The scheduling signal (e.g. rotor speed) arrives as stamped samples; its value at a stamp is
the linear interpolation between the samples around it, or the latest sample before it when it
is the newest, and NaN when that sample is older than ``max_age_s`` (a dead scheduling topic
gives no prediction rather than a stale one). The prediction's frequency standard deviation
combines the LPV model's own (interpolated from the identified local models, when the file has
it) with the scheduling signal's measured scatter propagated through d f / d theta.
"""

from __future__ import annotations

import math

import numpy as np

from .core.lpv import LpvModel
from .records import ModeRecord

#: Samples of the scheduling signal kept (a few seconds at the usual 10-100 Hz).
HISTORY = 512


class SchedulePredictor:
    """Scheduling samples in, LPV-predicted modes out (see the module docstring)."""

    def __init__(self, lpv: LpvModel, max_age_s: float = 1.0, channel: int = 0) -> None:
        self.lpv = lpv
        self.max_age_ns = int(max_age_s * 1e9)
        self.channel = int(channel)
        self._t = np.zeros(0, dtype=np.int64)
        self._v = np.zeros(0)
        self.rejected = 0  # non-finite or out-of-order samples dropped

    @property
    def range(self) -> tuple[float, float]:
        """Operating points covered by the model (outside: the end model, flagged)."""
        return float(self.lpv.points[0]), float(self.lpv.points[-1])

    def push(self, stamps_ns: np.ndarray, values: np.ndarray) -> None:
        """Add samples ``values`` (N,) or (N, channels) stamped ``stamps_ns`` (N,)."""
        t = np.asarray(stamps_ns, dtype=np.int64).ravel()
        v = np.asarray(values, dtype=float)
        v = v[:, self.channel] if v.ndim == 2 else v.ravel()
        last = self._t[-1] if self._t.size else np.iinfo(np.int64).min
        ok = np.isfinite(v) & (t > last)
        ok &= np.concatenate([[True], np.diff(t) > 0]) if t.size else ok
        self.rejected += int(np.sum(~ok))
        self._t = np.concatenate([self._t, t[ok]])[-HISTORY:]
        self._v = np.concatenate([self._v, v[ok]])[-HISTORY:]

    def value_at(self, stamp_ns: int) -> float:
        """Scheduling value at ``stamp_ns`` (NaN when none is recent enough)."""
        if not self._t.size:
            return math.nan
        k = int(np.searchsorted(self._t, stamp_ns, side="right"))
        if k == 0:
            return math.nan  # only samples after the stamp
        if stamp_ns - self._t[k - 1] > self.max_age_ns:
            return math.nan
        if k < self._t.size:  # between two samples: interpolate
            t0, t1 = self._t[k - 1], self._t[k]
            return float(self._v[k - 1] + (self._v[k] - self._v[k - 1]) * (stamp_ns - t0)
                         / (t1 - t0))
        return float(self._v[k - 1])

    def scatter(self) -> float:
        """Standard deviation of the scheduling signal about a straight line over its recent
        samples (its measurement noise, in its unit; 0 with fewer than 4 samples)."""
        n = min(self._t.size, 50)
        if n < 4:
            return 0.0
        t = (self._t[-n:] - self._t[-n]) * 1e-9
        v = self._v[-n:]
        coef = np.polyfit(t, v, 1)
        return float(np.std(v - np.polyval(coef, t), ddof=2))

    def predict(self, stamp_ns: int) -> tuple[float, list[ModeRecord]]:
        """(scheduling value, predicted modes) at ``stamp_ns``; (NaN, []) without a value.
        Mode ids are the LPV model's mode numbers (1, 2, ...), stable over time."""
        theta = self.value_at(stamp_ns)
        if not math.isfinite(theta):
            return math.nan, []
        f, z = self.lpv.modes(theta)
        f, z = f[0], z[0]
        lo, hi = self.range
        step = 1e-3 * max(hi - lo, 1e-9)
        f_lo, _ = self.lpv.modes(min(max(theta, lo) + step, hi))
        f_hi, _ = self.lpv.modes(max(min(theta, hi) - step, lo))
        dfdt = (f_lo[0] - f_hi[0]) / max(min(max(theta, lo) + step, hi)
                                         - max(min(theta, hi) - step, lo), 1e-300)
        sd_theta = self.scatter()
        f_std_model, z_std_model = self.lpv.mode_std(theta)
        shapes = self.lpv.shapes(theta)
        out = []
        for k in range(f.size):
            sf = math.hypot(float(np.nan_to_num(f_std_model[k])), float(dfdt[k] * sd_theta))
            phi = shapes[:, k]
            big = phi[np.argmax(np.abs(phi))] if phi.size else 1.0
            out.append(ModeRecord(
                id=k + 1, status="tracked", frequency_hz=float(f[k]),
                frequency_std_hz=sf if sf > 1e-9 * f[k] else math.nan,
                damping_ratio=float(z[k]),
                damping_std=float(z_std_model[k]), amplitude=math.nan, age_s=0.0,
                shape=phi / big if abs(big) > 0 else phi))
        return theta, out
