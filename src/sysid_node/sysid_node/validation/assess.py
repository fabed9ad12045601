"""Compare a fitted model with the measurement on the validation part (``compare``).

Per output channel: the free-run (simulation) fit, what MATLAB's ``compare`` shows by default,
and the one-step-ahead fit; the residual tests of :mod:`.residuals` on the one-step residual
(whiteness, cross-correlation with the input, spectrum); and where the model's error lies
(channel, time windows, frequency band).

The *primary* prediction is the one the user's question is about: the free run from the
measured input (the model's prediction of the measurement) when there is an input; the one-step
prediction for output-only data.

Whether the model fails: does it predict the validation samples as well as the samples it
was fitted to? The mean square primary error on both is compared by an F-test whose degrees of
freedom are the errors' effective sample sizes (N over the integrated autocorrelation time);
a fit of 0 % or less (no better than the output's mean) always fails. (Neither the model's own
noise model, whose subspace estimate overstates the noise, nor the input-output coherence,
biased low at lightly damped modes with short Welch segments, gives a usable floor.)
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import signal, stats

from . import residuals as rs
from .data import ValidationData
from .models import FittedModel
from .split import Split

P_FAIL = 0.01
CARRY_OVER = 2.0  # a validation NRMSE over twice the estimation one is a failure to carry over
OUTLIER_WINDOW_P = 0.01
#: The drop of a trial is also tested on the ranks of this many batch means (see
#: residuals.compare_errors: a drop confined to a few batches).
RANK_BATCHES = 40


@dataclass
class Where:
    """Where the primary error lies."""

    channel: int
    channel_name: str
    windows: list[tuple[float, float, float]]  # (start s, end s, rms / overall rms)
    band_hz: tuple[float, float]
    peak_hz: float
    band_share: float  # share of the error power inside band_hz

    def to_dict(self) -> dict:
        return {
            "channel": self.channel,
            "channel_name": self.channel_name,
            "time_windows_s": [
                {"start": round(a, 3), "end": round(b, 3), "rms_ratio": round(r, 2)}
                for a, b, r in self.windows
            ],
            "band_hz": [round(self.band_hz[0], 4), round(self.band_hz[1], 4)],
            "peak_hz": round(self.peak_hz, 4),
            "band_share": round(self.band_share, 3),
        }

    def text(self) -> str:
        t = (
            "; worst time windows "
            + ", ".join(f"{a:.1f}-{b:.1f} s ({r:.1f}x)" for a, b, r in self.windows[:3])
            if self.windows
            else "; spread evenly over time"
        )
        return (
            f"channel {self.channel_name}{t}; {100 * self.band_share:.0f} % of the error power "
            f"in {self.band_hz[0]:.3g}-{self.band_hz[1]:.3g} Hz (peak {self.peak_hz:.3g} Hz)"
        )


@dataclass
class Assessment:
    """``compare`` and the residual tests of one model on the validation part."""

    primary: str  # "free_run" or "one_step"
    fit_percent: np.ndarray  # one-step fit per channel [%]
    fit_free_run_percent: np.ndarray | None  # free-run fit per channel [%]
    free_run_note: str  # why there is no free-run fit (empty when there is one)
    residual: np.ndarray  # one-step residual on the validation part (Nv, l)
    free_error: np.ndarray | None  # free-run error on the validation part (Nv, l)
    prediction: np.ndarray  # one-step prediction, whole record
    simulation: np.ndarray | None  # free run, whole record
    y_std: np.ndarray  # (l,) std of the measured validation outputs
    whiteness: list[rs.WhitenessTest]
    xcorr: dict[tuple[int, int], rs.CrossCorrelationTest]  # (output, input)
    spectrum: rs.Spectrum  # of the one-step residual
    windows: tuple[np.ndarray, np.ndarray]  # primary error RMS per window
    fit_estimation: np.ndarray  # (l,) primary fit on the estimation samples [%]
    noise_ratio: np.ndarray  # (l,) primary error variance, validation / estimation samples
    noise_p: float  # p-value of "validation error no larger than estimation error"
    where: Where
    primary_note: str = ""  # why the primary prediction is not the free run, if it is not

    @property
    def residual_rms(self) -> np.ndarray:
        return rs.rms(self.residual)

    @property
    def primary_error(self) -> np.ndarray:
        """Error of the primary prediction; a diverged free run counts as the measured output
        (a fit of 0 %): never NaN."""
        if self.primary != "free_run":
            return self.residual
        if self.free_error is None:
            return self.residual + self.prediction[-self.residual.shape[0] :]
        return self.free_error

    @property
    def primary_fit(self) -> np.ndarray:
        if self.primary != "free_run":
            return self.fit_percent
        if self.fit_free_run_percent is None:
            return np.zeros_like(self.fit_percent)
        return self.fit_free_run_percent

    @property
    def primary_nrmse(self) -> float:
        """Mean over channels of ||e|| / ||y - mean y|| of the primary prediction."""
        return float(np.mean(1.0 - self.primary_fit / 100.0))

    @property
    def fails(self) -> bool:
        """The model does not carry over to the validation samples: its relative error there
        is significantly (F-test) and materially (more than :data:`CARRY_OVER` times in RMS)
        larger than on its estimation samples; or it is no better than the output's mean."""
        worse = bool(np.any(self.noise_ratio > CARRY_OVER**2))
        return (self.noise_p < P_FAIL and worse) or bool(np.any(self.primary_fit <= 0.0))

    @property
    def white(self) -> bool:
        return all(w.passed for w in self.whiteness)

    @property
    def uncorrelated(self) -> bool:
        return all(x.passed for x in self.xcorr.values())

    def summary(self) -> dict:
        def pct(v):
            return None if v is None else [_round(x, 3) for x in v]

        return {
            "primary": self.primary,
            "fit_percent": pct(self.fit_percent),
            "fit_free_run_percent": pct(self.fit_free_run_percent),
            "free_run_note": self.free_run_note,
            "primary_nrmse": _round(self.primary_nrmse, 5),
            "residual_rms": [float(v) for v in self.residual_rms],
            "free_run_rms": None
            if self.free_error is None
            else [float(v) for v in rs.rms(self.free_error)],
            "whiteness_p": [float(w.p_value) for w in self.whiteness],
            "whiteness_passed": self.white,
            "xcorr_p_past": [float(x.p_past) for x in self.xcorr.values()],
            "xcorr_p_future": [float(x.p_future) for x in self.xcorr.values()],
            "xcorr_passed": self.uncorrelated,
            "fit_estimation_percent": [_round(v, 3) for v in self.fit_estimation],
            "error_ratio_to_estimation": [_round(v, 3) for v in self.noise_ratio],
            "error_ratio_p": float(self.noise_p),
            "fails": self.fails,
            "where": self.where.to_dict(),
        }


def _round(v: float, nd: int) -> float | None:
    return round(float(v), nd) if np.isfinite(v) else None


def _failure_test(
    pe: np.ndarray, pe_est: np.ndarray, y_val: np.ndarray, y_est: np.ndarray
) -> tuple[np.ndarray, float]:
    """(ratio, p) of "the model predicts the validation data as well as the data it was
    fitted to": the squared NRMSE (error power over output power) on validation over
    estimation samples, one-sided F-test with the effective sample sizes (N over the
    integrated autocorrelation time)."""
    rel_val = np.mean(pe**2, axis=0) / np.maximum(np.var(y_val, axis=0), 1e-300)
    rel_est = np.mean(pe_est**2, axis=0) / np.maximum(np.var(y_est, axis=0), 1e-300)
    ratio = rel_val / np.maximum(rel_est, 1e-300)
    ps = []
    for c in range(pe.shape[1]):
        d1 = max(pe.shape[0] / rs.correlation_time(pe[:, c], "positive"), 1.0)
        d2 = max(pe_est.shape[0] / rs.correlation_time(pe_est[:, c], "positive"), 1.0)
        ps.append(float(stats.f.sf(ratio[c], d1, d2)) if np.isfinite(ratio[c]) else 0.0)
    return ratio, float(min(1.0, min(ps) * len(ps)))


def _primary(free_err: np.ndarray | None) -> str:
    """The free run whenever there is one (the model's prediction of the measurement)."""
    return "free_run" if free_err is not None and np.all(np.isfinite(free_err)) else "one_step"


def _where(data: ValidationData, e: np.ndarray, split: Split, fit: np.ndarray) -> Where:
    l = e.shape[1]
    c = int(np.nanargmin(fit)) if l > 1 and np.any(np.isfinite(fit)) else 0
    ec = e[:, c]
    fs = data.fs
    # time: windows whose mean square exceeds the chi-square 99 % bound of the overall one
    tau = rs.correlation_time(ec, "positive", max_lag=min(ec.size // 4, int(10 * fs)))
    w = max(int(round(ec.size / 20)), 1)
    k = ec.size // w
    ms = np.mean(ec[: k * w].reshape(k, w) ** 2, axis=1)
    overall = float(np.mean(ec**2)) or 1e-300
    dof = max(w / tau, 1.0)
    bound = stats.chi2.ppf(1 - OUTLIER_WINDOW_P / max(k, 1), dof) / dof
    tv = data.t[split.val]
    hot = [
        (float(tv[j * w]), float(tv[(j + 1) * w - 1] + 1.0 / fs), float(np.sqrt(ms[j] / overall)))
        for j in np.argsort(-ms)
        if ms[j] / overall > bound
    ]
    # band: the shortest band around the PSD peak holding 68 % of the error power
    nper = rs.welch_nperseg(ec.size, fs)
    f, p = signal.welch(ec, fs=fs, nperseg=nper, detrend="constant")
    tot = float(np.sum(p)) or 1e-300
    i0 = int(np.argmax(p))
    lo = hi = i0
    acc = p[i0]
    while acc < 0.68 * tot and (lo > 0 or hi < p.size - 1):
        left = p[lo - 1] if lo > 0 else -1.0
        right = p[hi + 1] if hi < p.size - 1 else -1.0
        if right >= left:
            hi += 1
            acc += p[hi]
        else:
            lo -= 1
            acc += p[lo]
    name = data.output_names[c] if c < len(data.output_names) else f"y{c}"
    return Where(c, name, hot, (float(f[lo]), float(f[hi])), float(f[i0]), float(acc / tot))


def errors(
    fm: FittedModel, data: ValidationData, split: Split
) -> tuple[np.ndarray, np.ndarray, np.ndarray | None, np.ndarray | None, str]:
    """(prediction, one-step residual, free run, free-run error, note) on the validation
    samples; the free run is None (with the reason in ``note``) for output-only data or a
    diverging simulation."""
    with np.errstate(all="ignore"):
        yhat = fm.predict(data)
        ysim = fm.simulate(data)
    val = split.val
    yv = data.y[val]
    e = yv - yhat[val]
    if not np.all(np.isfinite(e)):
        e = np.where(np.isfinite(e), e, 1e3 * max(float(np.max(np.abs(yv))), 1e-300))
    if ysim is None:
        return yhat, e, None, None, "output-only data: no input to simulate from"
    scale = 1e3 * max(float(np.max(np.abs(data.y))), 1e-300)
    if not np.all(np.abs(ysim[val]) < scale):
        return yhat, e, None, None, "the free run diverges (unstable simulation): no free-run fit"
    return yhat, e, ysim, yv - ysim[val], ""


def assess(
    fm: FittedModel,
    data: ValidationData,
    split: Split,
    max_lag: int = 20,
    primary: str | None = None,
) -> Assessment:
    """One-step and free-run comparison and the residual tests on the validation samples.

    ``primary`` forces the primary prediction (an augmented model is scored on the baseline's).
    """
    yhat, e, ysim, free_err, note = errors(fm, data, split)
    val = split.val
    yv = data.y[val]
    fit_free = None if ysim is None else rs.nrmse_fit(yv, ysim[val])
    if primary is None:
        primary = _primary(free_err)
    pe = free_err if primary == "free_run" and free_err is not None else e
    fit_one = rs.nrmse_fit(yv, yhat[val])
    est = split.est
    ye = data.y[est]
    if primary == "free_run" and free_err is not None:
        pe_est = ye - ysim[est]
    else:
        pe_est = ye - yhat[est]
    ratio, noise_p = _failure_test(pe, pe_est, yv, ye)
    fit_est = rs.nrmse_fit(ye, ye - pe_est)
    white = [rs.whiteness(e[:, c], max_lag) for c in range(e.shape[1])]
    xc = {
        (c, j): rs.cross_correlation(e[:, c], data.u[val, j], max_lag)
        for c in range(e.shape[1])
        for j in range(data.n_inputs)
    }
    pfit = fit_free if primary == "free_run" and fit_free is not None else fit_one
    return Assessment(
        primary,
        fit_one,
        fit_free,
        note,
        e,
        free_err,
        yhat,
        ysim,
        np.std(yv, axis=0),
        white,
        xc,
        rs.residual_spectrum(e, data.fs),
        _windows(pe, data.t[val], data.fs),
        fit_est,
        ratio,
        noise_p,
        _where(data, pe, split, pfit),
    )


def _windows(e: np.ndarray, tv: np.ndarray, fs: float) -> tuple[np.ndarray, np.ndarray]:
    """Error RMS over 20 windows of the validation samples: (window start times [s], rms)."""
    w = max(1, e.shape[0] // 20)
    k = e.shape[0] // w
    return tv[: k * w : w], np.sqrt(np.mean(e[: k * w].reshape(k, w, -1) ** 2, axis=1))


def primary_error(
    fm: FittedModel, data: ValidationData, split: Split, primary: str
) -> np.ndarray | None:
    """The primary error of a model on the validation samples (None: a diverging free run)."""
    _, e, _, free_err, _ = errors(fm, data, split)
    return free_err if primary == "free_run" else e


def compare_primary(before: Assessment, e1: np.ndarray | None) -> rs.ErrorComparison:
    """Drop of the primary error from the ``before`` model's to ``e1`` (same kind), scaled by
    the measurement's spread per channel (:func:`.residuals.compare_drop`; the batch t-test
    on the log loss ratios: a trial's error falls most where the input is largest)."""
    if e1 is None:
        return rs.ErrorComparison(0.0, 1.0, 0)
    return rs.compare_drop(before.primary_error, e1, before.y_std, RANK_BATCHES, log_ratio=True)
