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

With fewer than :data:`MIN_ESTIMATES` estimates, or a window spanning less than a quarter of
its length, the latest estimate and its reported stds are used as they are, with no drift.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

#: Estimates a fit needs; fewer: the latest estimate as it is.
MIN_ESTIMATES = 6


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


def _n_eff(res: np.ndarray) -> float:
    """Independent samples in ``res`` under an AR(1) model of its lag-1 autocorrelation."""
    n = res.size
    den = float(res @ res)
    rho = float(res[1:] @ res[:-1]) / den if den > 0 else 0.0
    rho += (1.0 + 4.0 * rho) / n  # the short-series bias of the lag-1 estimate (Marriott-Pope)
    rho = min(max(rho, 0.0), 0.95)
    return max(n * (1.0 - rho) / (1.0 + rho), 2.0)


def model(t: np.ndarray, f: np.ndarray, f_std: np.ndarray, zeta: np.ndarray,
          zeta_std: np.ndarray, span: float) -> ModeModel:
    """The mode's model from its estimates over a window of length ``span`` [s] (arrays in time
    order; NaN stds = unknown). See the module docstring."""
    t, f = np.asarray(t, dtype=float), np.asarray(f, dtype=float)
    last = ModeModel(float(f[-1]), float(f_std[-1]), float(zeta[-1]), float(zeta_std[-1]))
    if t.size < MIN_ESTIMATES or t[-1] - t[0] < 0.25 * span:
        return last
    tc = t - t.mean()
    sxx = float(tc @ tc)
    if sxx <= 0:
        return last
    slope = float(tc @ (f - f.mean())) / sxx
    res = f - f.mean() - slope * tc
    n, n_eff = t.size, _n_eff(res)
    s2 = float(res @ res) / (n - 2)
    inflate = n / n_eff
    f_now = float(f.mean() + slope * tc[-1])
    lever = inflate * (1.0 / n + tc[-1] ** 2 / sxx)  # the line at its last point
    rep_f = _median_finite(f_std)
    # the residual scatter, or the reported std where larger (a line through correlated
    # estimates absorbs part of their error, so the scatter alone reads low)
    s2 = max(s2, rep_f**2) if math.isfinite(rep_f) else s2
    se_f = math.sqrt(s2 * lever)
    se_b = math.sqrt(s2 * inflate / sxx)
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
