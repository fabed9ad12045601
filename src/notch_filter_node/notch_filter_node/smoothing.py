"""A mode's model from its recent estimates (pure numpy): frequency and drift from a straight-line
fit, damping from the median, each with an uncertainty that counts correlated estimates once.

Successive estimates of a recursive identifier share most of their data, so their errors are
correlated: ``n`` estimates carry about ``n_eff = n (1 - rho) / (1 + rho)`` independent ones
(``rho``: lag-1 autocorrelation of the fit residuals, AR(1) approximation, corrected for its
bias in short series). With
``n_eff`` the uncertainties are honest whatever the estimate rate:

- frequency: least-squares line ``f(t) = a + b (t - t_mean)`` over the window, evaluated at the
  latest estimate; its standard error that of a line at its end point (with ``n_eff``), from the
  residual scatter or the estimates' own reported std where that is larger (a scatter that
  happens to be small does not make the estimate better than the identifier says it is);
- drift rate ``b`` with its standard error;
- damping: the median of the window (robust to a stray estimate), standard error
  ``1.2533 s / sqrt(n_eff)`` from the scatter ``s`` (1.4826 MAD), again not below the reported
  std over ``sqrt(n_eff)``.

The identifier's memory (``memory``: the time constant tau of its forgetting, with the Hankel
window's length ``i / fs``; both carried by sysid_msgs/ModalEstimate) says two more things:

- its estimates are correlated over about tau (the integral time of their errors measured on
  drifting-mode draws: 0.3-0.5 s at tau 0.5 s, 1.1-1.6 s at tau 1 s), so a window of length ``W``
  holds at most ``1 + W / tau`` independent ones, whatever their lag-1 autocorrelation says
  (the AR(1) estimate reads low on a short window a line has been fitted through);
- a drifting mode's estimate lags its stamp by ``lag = tau + i / fs`` (the data's weighted mean
  age plus half the past-and-future Hankel window; measured 0.65-0.67 s at 0.675 s and 1.17-1.18 s
  at 1.175 s), so the frequency is extrapolated by ``b lag``, its variance grown by
  ``(se_b lag)^2``. Without it the estimate of a drift sits several of its stds behind the mode
  once the memory is long (``benchmarks/notch_width_budget.py``).

A drift that starts or stops inside the window bends the estimates, and the whole window's line
then sits several of its stds off where it matters, at the latest estimate. The line through the
window's recent half is fitted too; both are unbiased without a change and the whole window's is
the more precise, so their difference has the variance ``se_half^2 - se_whole^2`` (Hausman's test
for nested estimators). When it is more than :data:`CHANGE_SIGMAS` of that, the half's frequency is
the model's, its variance grown by the same amount (a half taken by chance is off by more than its
own se). The drift rate stays the whole window's: it only ages a late estimate, and a half
window's rate, about three times as uncertain, would widen every late notch at once (a phase-lag
spike at the crossover).

With fewer than :data:`MIN_ESTIMATES` estimates, or a window spanning less than a quarter of
its length, the latest estimate and its reported stds are used as they are, with no drift.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

#: Estimates a fit needs; fewer: the latest estimate as it is.
MIN_ESTIMATES = 6
#: The frequency of the line through the window's recent half replaces the whole window's
#: when the two differ by more than this many standard deviations of their difference (the
#: usual three-sigma rule; benchmarks/notch_drift_suite.py gives its effect).
CHANGE_SIGMAS = 3.0


@dataclass(frozen=True)
class ModeModel:
    """Frequency [Hz], damping [-], their standard errors, drift rate [Hz/s] and its error."""

    frequency: float
    frequency_std: float
    damping: float
    damping_std: float
    drift: float = 0.0
    drift_std: float = 0.0
    n_eff: float = 1.0


def _median_finite(x: np.ndarray) -> float:
    """Median of the finite values (NaN if none); plain sort, no numpy dispatch overhead."""
    v = sorted(float(a) for a in np.asarray(x, dtype=float).ravel() if math.isfinite(a))
    if not v:
        return math.nan
    m = len(v) // 2
    return v[m] if len(v) % 2 else 0.5 * (v[m - 1] + v[m])


def estimator_memory(forgetting_factor: float, sample_rate: float,
                     block_rows: int) -> tuple[float, float]:
    """(tau, lag) [s] of a recursive identifier from its forgetting factor lambda, rate [Hz] and
    Hankel block rows i: ``tau = -1 / (fs ln lambda)`` (the memory_time_constant that gives
    lambda), ``lag = tau + i / fs``; (NaN, 0) when unknown (lambda outside (0, 1), no rate)."""
    lam, fs = float(forgetting_factor), float(sample_rate)
    if not (0.0 < lam < 1.0 and math.isfinite(fs) and fs > 0):
        return math.nan, 0.0
    tau = -1.0 / (fs * math.log(lam))
    return tau, tau + max(int(block_rows), 0) / fs


def _n_eff(res: np.ndarray) -> float:
    """Independent samples in ``res`` under an AR(1) model of its lag-1 autocorrelation."""
    n = res.size
    den = float(res @ res)
    rho = float(res[1:] @ res[:-1]) / den if den > 0 else 0.0
    rho += (1.0 + 4.0 * rho) / n  # the short-series bias of the lag-1 estimate (Marriott-Pope)
    rho = min(max(rho, 0.0), 0.95)
    return max(n * (1.0 - rho) / (1.0 + rho), 2.0)


def _line(t: np.ndarray, f: np.ndarray, f_std: np.ndarray, memory: float,
          lag: float) -> tuple[float, float, float, float, float] | None:
    """(frequency, its standard error, slope, slope error, n_eff) of the line through ``f(t)``
    at the latest estimate plus ``lag`` (see the module docstring); None if it cannot be fitted."""
    tc = t - t.mean()
    sxx = float(tc @ tc)
    if sxx <= 0:
        return None
    slope = float(tc @ (f - f.mean())) / sxx
    res = f - f.mean() - slope * tc
    n, n_eff = t.size, _n_eff(res)
    if math.isfinite(memory) and memory > 0:  # estimates correlated over the memory
        n_eff = max(min(n_eff, 1.0 + float(t[-1] - t[0]) / memory), 1.0)
    s2 = float(res @ res) / (n - 2)
    inflate = n / n_eff
    f_now = float(f.mean() + slope * tc[-1])
    lever = inflate * (1.0 / n + tc[-1] ** 2 / sxx)  # the line at its last point
    rep_f = _median_finite(f_std)
    # the residual scatter, or the reported std where larger (a line through correlated
    # estimates absorbs part of their error, so the scatter alone reads low)
    s2 = max(s2, rep_f**2) if math.isfinite(rep_f) else s2
    se_b = math.sqrt(s2 * inflate / sxx)
    f_now += slope * lag  # the estimate lags its stamp: where the drift has taken the mode
    return f_now, math.sqrt(s2 * lever + (se_b * lag) ** 2), slope, se_b, n_eff


def model(t: np.ndarray, f: np.ndarray, f_std: np.ndarray, zeta: np.ndarray,
          zeta_std: np.ndarray, span: float, memory: float = math.nan,
          lag: float = 0.0) -> ModeModel:
    """The mode's model from its estimates over a window of length ``span`` [s] (arrays in time
    order; NaN stds = unknown); ``memory`` [s] and ``lag`` [s]: the identifier's
    (:func:`estimator_memory`; NaN / 0 = unknown). See the module docstring."""
    t, f = np.asarray(t, dtype=float), np.asarray(f, dtype=float)
    f_std = np.asarray(f_std, dtype=float)
    last = ModeModel(float(f[-1]), float(f_std[-1]), float(zeta[-1]), float(zeta_std[-1]))
    if t.size < MIN_ESTIMATES or t[-1] - t[0] < 0.25 * span:
        return last
    lag = lag if math.isfinite(lag) and lag > 0 else 0.0
    fit = _line(t, f, f_std, memory, lag)
    if fit is None:
        return last
    recent = t >= t[-1] - 0.5 * span
    if recent.sum() >= MIN_ESTIMATES and t[-1] - t[recent][0] >= 0.125 * span:
        short = _line(t[recent], f[recent], f_std[recent], memory, lag)
        # the drift changed within the window (a drift that starts or stops): the whole
        # window's line is biased where it matters, its recent half is not. Without a change
        # both are unbiased and the whole window's the more precise, so their difference has
        # the variance se_half^2 - se_whole^2 (Hausman): a larger difference is the change
        spread = math.sqrt(max(short[1] ** 2 - fit[1] ** 2, 0.0)) if short else math.inf
        if short is not None and abs(short[0] - fit[0]) > CHANGE_SIGMAS * spread:
            # its frequency, taken because it is far from the whole window's: that choice is
            # part of its error (a half taken by chance on a steady drift is off by more than
            # its se); the drift rate stays the whole window's (module docstring)
            fit = (short[0], math.hypot(short[1], spread), *fit[2:])
    f_now, se_f, slope, se_b, n_eff = fit
    z = np.asarray(zeta, dtype=float)
    z = z[np.isfinite(z)]
    if z.size >= MIN_ESTIMATES:
        z_med = _median_finite(z)
        dev = z - z_med
        s_z = 1.4826 * _median_finite(np.abs(dev))
        nz = _n_eff(dev - dev.mean())
        se_z = 1.2533 * s_z / math.sqrt(nz)
        rep_z = _median_finite(zeta_std)
        if math.isfinite(rep_z):
            se_z = max(se_z, rep_z / math.sqrt(nz))
    else:
        z_med, se_z = last.damping, last.damping_std
    return ModeModel(f_now, se_f, z_med, se_z, slope, se_b, n_eff)
