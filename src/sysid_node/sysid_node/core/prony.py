"""Prony's method: damped exponentials fitted to a free decay (the industry baseline of Table 1).

The V-22 practice the paper compares DSRA with is to excite one mode with a sine dwell, stop,
and fit the free decay with the *modified Prony* method (Osborne & Smyth, ref. 20 of the
paper). The decay of ``l`` channels is modelled with common poles,

    y_t = sum_j a_j z_j^t + e_t,   t = 0 .. n-1.

* **Classical Prony** (``modified=False``): the recurrence sum_{k=0..p} g_k y_{t+k} = 0 fitted
  by total least squares (g = the smallest right singular vector of the data's Hankel matrix);
  the poles are the roots of sum_k g_k z^k. Biased when the data are noisy: the recurrence's
  equation error is not the fit error.
* **Modified Prony** (default): the exact nonlinear least-squares fit of the exponentials to the
  data, min ||y - sum_j a_j z_j^t||^2 over poles and amplitudes, which is the estimator the
  modified Prony method computes (it removes the classical bias). Osborne & Smyth's eigenvalue
  iteration on B(g) = Y'(X'X)^-1 Y - V(c) is numerically hopeless for lightly damped modes
  sampled well above their frequency (X'X is then nearly singular: eigenvalues of B spread over
  16 decades in the V-22 wing case, and the iteration stalls far from the minimum), so the same
  minimum is found by variable projection (Golub & Pereyra): the amplitudes are eliminated by
  linear least squares and the continuous poles (sigma, omega) refined by Levenberg-Marquardt
  from the classical estimate.

Poles outside ``band`` or ``damping_bounds`` are dropped (the noise-induced poles of an order
chosen larger than twice the number of modes, Braun & Ram, ref. 19).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import linalg, optimize

from .inputs import InputError, as_2d, check_rate
from .modal import ModalParameters, select_modes


@dataclass
class PronyResult:
    """Modes of a decay (sorted by frequency) and the fit's bookkeeping."""

    modes: list[ModalParameters]
    poles: np.ndarray  # all discrete poles of the fitted recurrence
    coefficients: np.ndarray  # g, lowest power first, unit norm
    iterations: int
    converged: bool
    residual_rms: np.ndarray  # per channel, of the fitted exponentials


def _hankel(y: np.ndarray, p: int) -> np.ndarray:
    """(n - p, p + 1, l) with [t, k, c] = y[t + k, c]."""
    n = y.shape[0]
    idx = np.arange(n - p)[:, None] + np.arange(p + 1)[None, :]
    return y[idx]


def prony(
    y: np.ndarray,
    fs: float,
    order: int,
    modified: bool = True,
    band: tuple[float, float] | None = None,
    damping_bounds: tuple[float, float] | None = (0.0, 0.5),
    max_modes: int | None = None,
) -> PronyResult:
    """Fit ``order`` damped exponentials with common poles to a free decay ``y`` (N,) or
    (N, l) sampled at ``fs`` [Hz]; ``modified=False`` stops at the classical Prony estimate.
    Returns the oscillatory modes (frequency, damping ratio, amplitude: the largest initial
    amplitude over the channels, shape: initial complex amplitudes normalised)."""
    fs = check_rate(fs)
    y = as_2d(y, "y")
    n, l = y.shape
    if not np.all(np.isfinite(y)):
        raise InputError("y has NaN/Inf values")
    if order < 2 or 3 * order > n:
        raise InputError(f"order must be in [2, {n // 3}] for {n} samples, got {order}")
    scale = np.std(y, axis=0)
    if np.any(scale <= 0):
        raise InputError("y has a channel of zero variance")
    ys = y / scale
    hy = _hankel(ys, order)
    _, _, vt = linalg.svd(hy.transpose(0, 2, 1).reshape(-1, order + 1), full_matrices=False)
    g = vt[-1]
    poles = np.roots(g[::-1])
    it, converged = 0, True
    if modified:
        poles, it, converged = _refine(ys, fs, _start_poles(ys, order))
    t = np.arange(n) / fs
    with np.errstate(divide="ignore", invalid="ignore"):
        s_all = np.log(poles.astype(complex)) * fs
    keep = np.isfinite(s_all) & (s_all.real * t[-1] <= 50.0)  # no growth by more than e^50
    poles, s_all = poles[keep], s_all[keep]
    basis = _basis(s_all, t)
    amps = linalg.lstsq(basis, ys.astype(complex), check_finite=False)[0]  # (p, l)
    fit = np.real(basis @ amps)
    resid = np.sqrt(np.mean((ys - fit) ** 2, axis=0)) * scale
    amps = amps * scale[None, :]
    modes = []
    for j in np.flatnonzero(s_all.imag > 1e-9 * np.abs(s_all)):
        s = s_all[j]
        rad = abs(s)
        shape = amps[j]
        big = shape[np.argmax(np.abs(shape))]
        modes.append(ModalParameters(
            frequency_hz=float(rad / (2 * np.pi)), damping_ratio=float(-s.real / rad),
            amplitude=float(2 * np.abs(big)), shape=shape / big if abs(big) > 0 else shape,
            pole_discrete=complex(poles[j]), pole_continuous=complex(s)))
    modes = select_modes(modes, band, damping_bounds, max_modes)
    return PronyResult(modes, poles, g / np.linalg.norm(g), it, converged, resid)


def _basis(s: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Columns exp(s_j t) (complex)."""
    return np.exp(t[:, None] * s[None, :])


def _real_basis(sig: np.ndarray, om: np.ndarray, sr: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Real columns e^(sigma t) cos(omega t), e^(sigma t) sin(omega t), e^(s_r t)."""
    env = np.exp(t[:, None] * sig[None, :])
    return np.hstack([env * np.cos(t[:, None] * om[None, :]),
                      env * np.sin(t[:, None] * om[None, :]), np.exp(t[:, None] * sr[None, :])])


def _start_poles(ys: np.ndarray, order: int) -> np.ndarray:
    """Start of the nonlinear fit: linear prediction of a higher order L with the data matrix
    truncated to rank ``order`` (Kumaresan & Tufts), its roots, and of those the ``order``
    that carry the most energy in an amplitude fit (the others are noise roots)."""
    n = ys.shape[0]
    lp = int(min(max(4 * order, 20), n // 3))
    hy = _hankel(ys, lp)  # (n - lp, lp + 1, l)
    x = hy[:, :lp, :].transpose(0, 2, 1).reshape(-1, lp)
    b = hy[:, lp, :].reshape(-1)
    u, sv, vt = linalg.svd(x, full_matrices=False)
    r = min(order, sv.size)
    coef = -vt[:r].T @ ((u[:, :r].T @ b) / sv[:r])
    roots = np.roots(np.concatenate([[1.0], coef[::-1]]))
    roots = roots[np.abs(roots) < 1.0 + 1.0 / n]
    t = np.arange(n)
    vand = roots[None, :] ** t[:, None]
    amps = linalg.lstsq(vand, ys.astype(complex), check_finite=False)[0]
    energy = np.sum(np.abs(amps) ** 2, axis=1) * np.sum(np.abs(vand) ** 2, axis=0)
    keep: list[int] = []
    used = 0  # poles taken (a pair counts two)
    for j in np.argsort(-energy):
        if roots[j].imag < -1e-12:  # its conjugate carries the pair
            continue
        need = 2 if roots[j].imag > 1e-12 else 1
        if used + need <= order:
            keep.append(j)
            used += need
    sel = roots[keep]
    return np.concatenate([sel, np.conj(sel[sel.imag > 1e-12])])


def _refine(ys: np.ndarray, fs: float, poles: np.ndarray) -> tuple[np.ndarray, int, bool]:
    """Variable projection: continuous poles refined to the least-squares fit of the data."""
    with np.errstate(divide="ignore", invalid="ignore"):
        s = np.log(poles.astype(complex)) * fs
    ok = np.isfinite(s)
    s = s[ok]
    cplx = s[s.imag > 1e-9 * np.abs(s)]
    real = s[np.abs(s.imag) <= 1e-9 * np.abs(s)].real
    nc = cplx.size
    t = np.arange(ys.shape[0]) / fs

    big = np.full(ys.size, 1e3 * np.sqrt(ys.shape[0]))

    def residual(p: np.ndarray) -> np.ndarray:
        if np.max(np.concatenate([p[:nc], p[2 * nc :]]), initial=-np.inf) * t[-1] > 50.0:
            return big  # growth by e^50 over the record: not a decay, reject the trial
        phi = _real_basis(p[:nc], p[nc : 2 * nc], p[2 * nc :], t)
        coef = linalg.lstsq(phi, ys, check_finite=False)[0]
        return (ys - phi @ coef).ravel()

    p0 = np.concatenate([cplx.real, cplx.imag, real])
    if p0.size == 0:
        return poles, 0, True
    sol = optimize.least_squares(residual, p0, method="lm", x_scale="jac", max_nfev=200 * p0.size)
    sig, om, sr = sol.x[:nc], sol.x[nc : 2 * nc], sol.x[2 * nc :]
    s_new = np.concatenate([sig + 1j * np.abs(om), sig - 1j * np.abs(om), sr + 0j])
    return np.exp(s_new / fs), int(sol.nfev), bool(sol.success)


def decay_start(u: np.ndarray, fraction: float = 1e-3) -> int:
    """First sample after which the excitation ``u`` (N,) or (N, m) stays below ``fraction``
    of its peak (the end of a sine dwell); N when it never does."""
    u = as_2d(u, "u")
    mag = np.max(np.abs(u), axis=1)
    above = np.flatnonzero(mag > fraction * mag.max())
    return int(above[-1] + 1) if above.size else 0
