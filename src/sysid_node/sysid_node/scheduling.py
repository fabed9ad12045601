"""The LPV model (2) used online (pure): the scheduling signal's value at an estimate's stamp
and the modes the model predicts there, as ``ModeRecord`` for ``EstimateRecord.predicted_modes``.

The scheduling signal (e.g. rotor speed) arrives as stamped samples (``scheduling_topic``). Its
value at a stamp is the newest sample stamped at or before it (never a later one: a record then
depends only on data up to its own stamp, so a live run and an offline run over the recorded
bag give the same value however the messages were chunked), and NaN when that sample is older
than ``max_age_s`` (a dead scheduling topic gives no prediction rather than a stale one).
Inside the model's range of operating points the predicted modes are the model's at that value
(ids 1..K, the LPV model's mode numbers, stable over time); outside it none are predicted
(``lpv_in_range`` false: an LPV model is not extrapolated). The prediction's frequency standard
deviation combines the model's own (interpolated from the identified local models, when the
file has it) with the scheduling signal's measured scatter propagated through d f / d theta.

Channel: a multi-channel scheduling message is read at the channel named like the model's
scheduling variable (``rotor_speed`` or ``rotor_speed[Hz]``), else at channel 0.
"""

from __future__ import annotations

import math
import os
from functools import lru_cache
from typing import Any

import numpy as np

from .core.inputs import InputError
from .core.lpv import LpvModel
from .records import EstimateRecord, ModeRecord

#: Samples of the scheduling signal kept (a few seconds at the usual 10-100 Hz).
HISTORY = 512


class SchedulePredictor:
    """Scheduling samples in, LPV-predicted modes out (see the module docstring).
    ``lpv=None``: the scheduling value only (no prediction)."""

    def __init__(self, lpv: LpvModel | None, max_age_s: float = 1.0, channel: int = 0) -> None:
        self.lpv = lpv
        self.max_age_ns = int(max_age_s * 1e9)
        self.channel = int(channel)
        self._t = np.zeros(0, dtype=np.int64)
        self._v = np.zeros(0)
        self.rejected = 0  # non-finite or out-of-order samples dropped
        #: at the latest record: scheduling value, age of the sample used [s], in range
        self.last: tuple[float, float, bool] = (math.nan, math.nan, False)

    @property
    def range(self) -> tuple[float, float]:
        """Operating points covered by the model."""
        if self.lpv is None:
            return math.nan, math.nan
        return float(self.lpv.points[0]), float(self.lpv.points[-1])

    def push(self, stamps_ns: np.ndarray, values: np.ndarray,
             names: tuple[str, ...] | list[str] | None = None) -> None:
        """Add samples ``values`` (N,) or (N, channels) stamped ``stamps_ns`` (N,); ``names``:
        the channel names the messages carry (choose the channel, see the module docstring)."""
        if names and self.lpv is not None:
            base = [str(n).split("[")[0].strip() for n in names]
            if self.lpv.scheduling in base:
                self.channel = base.index(self.lpv.scheduling)
        t = np.asarray(stamps_ns, dtype=np.int64).ravel()
        v = np.asarray(values, dtype=float)
        if v.ndim == 2:
            v = v[:, self.channel] if v.shape[1] > self.channel else np.full(t.size, np.nan)
        v = v.ravel()
        last = self._t[-1] if self._t.size else np.iinfo(np.int64).min
        ok = np.isfinite(v) & (t > last)
        ok &= np.concatenate([[True], np.diff(t) > 0]) if t.size else ok
        self.rejected += int(np.sum(~ok))
        self._t = np.concatenate([self._t, t[ok]])[-HISTORY:]
        self._v = np.concatenate([self._v, v[ok]])[-HISTORY:]

    def _index(self, stamp_ns: int) -> int:
        """Index of the newest sample stamped at or before ``stamp_ns`` (-1: none)."""
        return int(np.searchsorted(self._t, stamp_ns, side="right")) - 1

    def value_at(self, stamp_ns: int) -> float:
        """Scheduling value at ``stamp_ns`` (NaN when none is recent enough)."""
        k = self._index(stamp_ns)
        if k < 0 or stamp_ns - self._t[k] > self.max_age_ns:
            return math.nan
        return float(self._v[k])

    def scatter(self, stamp_ns: int | None = None) -> float:
        """Standard deviation of the scheduling signal about a straight line over its recent
        samples up to ``stamp_ns`` (its measurement noise, in its unit; 0 with fewer than 4)."""
        end = self._t.size if stamp_ns is None else self._index(stamp_ns) + 1
        n = min(end, 50)
        if n < 4:
            return 0.0
        t = (self._t[end - n:end] - self._t[end - n]) * 1e-9
        v = self._v[end - n:end]
        coef = np.polyfit(t, v, 1)
        return float(np.std(v - np.polyval(coef, t), ddof=2))

    def predict(self, stamp_ns: int) -> tuple[float, list[ModeRecord]]:
        """(scheduling value, predicted modes) at ``stamp_ns``; (NaN, []) without a value, and
        (value, []) without a model or outside its range. Updates :attr:`last`."""
        k = self._index(stamp_ns)
        theta = self.value_at(stamp_ns)
        age = (stamp_ns - int(self._t[k])) * 1e-9 if k >= 0 else math.nan
        lo, hi = self.range
        inside = math.isfinite(theta) and lo <= theta <= hi
        self.last = (theta, age, inside)
        if not inside:
            return theta, []
        lpv = self.lpv
        f, z = (a[0] for a in lpv.modes(theta))
        # d f / d theta by a central difference inside the range
        step = 1e-3 * max(hi - lo, 1e-9)
        a, b = max(theta - step, lo), min(theta + step, hi)
        dfdt = (lpv.modes(b)[0][0] - lpv.modes(a)[0][0]) / (b - a) if b > a else 0.0 * f
        sd_theta = self.scatter(stamp_ns)
        f_std_model, z_std_model = lpv.mode_std(theta)
        shapes = lpv.shapes(theta)
        out = []
        for j in range(f.size):
            sf = math.hypot(float(np.nan_to_num(f_std_model[j])), float(dfdt[j] * sd_theta))
            phi = shapes[:, j]
            big = phi[np.argmax(np.abs(phi))] if phi.size else 1.0
            out.append(ModeRecord(
                id=j + 1, status="tracked", frequency_hz=float(f[j]),
                frequency_std_hz=sf if sf > 1e-9 * f[j] else math.nan,
                damping_ratio=float(z[j]),
                damping_std=float(z_std_model[j]), amplitude=math.nan, age_s=0.0,
                shape=phi / big if abs(big) > 0 else phi))
        return theta, out

    def annotate(self, records: list[EstimateRecord]) -> None:
        """Fill each record's ``scheduling_value`` and ``predicted_modes`` at its stamp."""
        for r in records:
            r.scheduling_value, r.predicted_modes = self.predict(r.stamp_ns)

    def status(self) -> dict[str, Any]:
        """/diagnostics keys at the latest record: ``scheduling_value`` [unit of the signal],
        ``scheduling_age_s`` (data time from the sample used to the record; NaN: none),
        ``lpv_in_range`` (a prediction was made)."""
        theta, age, inside = self.last
        return {"scheduling_value": theta, "scheduling_age_s": age, "lpv_in_range": inside}


def load_model(path: str) -> LpvModel:
    """The LPV model file ``path`` (InputError with a one-line reason: missing, unreadable,
    not an LPV model)."""
    if not os.path.isfile(path):
        raise InputError(f"LPV model file {path} does not exist")
    return LpvModel.load(path)


def model_error(path: str) -> str:
    """'' if ``path`` holds a readable LPV model, else the one-line reason (cached per file
    version: parameter checks call it often)."""
    try:
        st = os.stat(path)
    except OSError:
        return f"LPV model file {path} does not exist"
    return _model_error(path, st.st_mtime_ns, st.st_size)


@lru_cache(maxsize=8)
def _model_error(path: str, _mtime_ns: int, _size: int) -> str:
    try:
        load_model(path)
    except InputError as err:
        return str(err)
    return ""


def predictor_from(values: dict[str, Any]) -> SchedulePredictor | None:
    """The predictor the parameters ask for: None when ``scheduling_topic`` is empty."""
    if not values.get("scheduling_topic"):
        return None
    path = values.get("lpv_model", "")
    return SchedulePredictor(load_model(path) if path else None,
                             float(values.get("scheduling_timeout", 1.0)))
