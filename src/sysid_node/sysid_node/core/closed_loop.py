"""Open-loop plant from closed-loop data (the paper's Sec. IV and Table 2).

Data: reference r (the test excitation), applied input u = r + K y and measured output y, with a
known controller K (:class:`~sysid_node.core.controller.DiscreteController`). Which method:

* **Naive direct DSRA** (Appendix A on (u, y) as if the loop were open) is *biased*: the least
  squares (A2) regresses future outputs on future inputs, and under feedback the future inputs
  carry the past noise (u_{k+1} depends on y_k). The bias grows with the share of noise in the
  loop; it is returned for contrast (``naive``).
* **Indirect** (identify the closed loop r -> y, then remove the known controller) is
  consistent but needs the closed loop of order n + n_K, including the well-damped controller
  and estimator poles that the data hardly determine; removing K algebraically amplifies their
  errors (tried: tens of percent on the plant modes at 5 % noise).
* **Joint input-output** (r -> [y; u], then G = T_yr T_ur^-1) has the same order inflation and
  the same pole-zero cancellations.
* **Used here: the direct prediction-error method (PEM)** on (u, y) with an innovation-form
  noise model, started from a consistent subspace estimate. PEM is consistent under feedback
  when the noise model can describe the noise (innovation form, K estimated) and the loop has a
  delay (LQG controllers are strictly proper), and it is asymptotically efficient: it also
  uses the noise-driven part of u, which the indirect and instrumental-variable methods throw
  away (Forssell & Ljung, ref. 22 of the paper). The start is the **instrumental-variable DSRA**:
  (A2) solved with the instruments [past u, y; future r] in place of [past u, y; future u]
  (r is independent of the noise, so the oblique projection, and with it A and C, is unbiased).

The known controller gives the reference when only u and y were logged (r = u - K y), and is
what :func:`~sysid_node.core.controller.check_closed_loop` and the envelope expansion need.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy import linalg, signal

from .batch import identify
from .controller import DiscreteController
from .hankel import Layout, window_rows
from .inputs import InputError, as_2d, check_rate, validate_batch
from .modal import ModalParameters, extract_modes
from .model import IdentifiedModel


@dataclass
class ClosedLoopData:
    """One closed-loop experiment: reference r (N, m), applied input u = r + K y (N, m),
    measured output y (N, l) at ``fs`` [Hz]; ``true_spectral_radius`` of the loop when known
    (simulation), NaN otherwise."""

    r: np.ndarray
    u: np.ndarray
    y: np.ndarray
    fs: float
    true_spectral_radius: float = float("nan")


@dataclass
class ClosedLoopResult:
    """Open-loop plant identified from closed-loop data, with the estimates it started from."""

    plant: IdentifiedModel  # direct PEM (the result)
    subspace: IdentifiedModel | None  # IV-DSRA with the reference as instrument
    naive: IdentifiedModel  # DSRA on (u, y) ignoring the loop: biased, for contrast
    start: str  # which estimate started the PEM ('reference-iv' or 'naive')
    iterations: int
    cost: float  # final sum of squared whitened one-step errors / 2
    converged: bool
    info: dict = field(default_factory=dict)

    @property
    def modes(self) -> list[ModalParameters]:
        return self.plant.modes


# --------------------------------------------------------------------- instrumental-variable DSRA
def iv_subspace(
    y: np.ndarray, u: np.ndarray, r: np.ndarray, block_rows: int, order: int | None = None
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(A, C, singular values) from the instrumental-variable form of (A2).

    With W_p = [U_{1|i}; Y_{1|i}] and future references R_f = R_{i+1|2i}, the regressors
    [W_p; U_f] and the outputs Y_f are projected onto the row space of the instruments
    [W_p; R_f] (one LQ factorisation of the stacked windows, the projection being the
    coefficients on the instruments' orthonormal rows), and (A2) is solved on the projections
    (two-stage least squares). Then steps 2-3 of Appendix A as in the batch DSRA: SVD of
    L_p W_p, Gamma_i = U_1 S_1^(1/2), A and C from its shift invariance. Channels are scaled to
    unit variance; C is returned in physical units.
    """
    m, l = u.shape[1], y.shape[1]
    su, sy, sr = np.std(u, axis=0), np.std(y, axis=0), np.std(r, axis=0)
    lay = Layout(block_rows, m, l)
    z = window_rows(u / su, y / sy, block_rows)
    rf = window_rows(r / sr, y / sy, block_rows)[:, lay.uf]
    big = np.hstack([z[:, : lay.n_past], rf, z[:, lay.uf], z[:, lay.yf]])
    lfac = linalg.qr(big, mode="r", check_finite=False)[0].T
    k = lay.n_past + block_rows * m  # instruments
    x_hat = np.vstack([lfac[: lay.n_past, :k], lfac[k : k + block_rows * m, :k]])
    y_hat = lfac[k + block_rows * m :, :k]
    theta = linalg.lstsq(x_hat.T, y_hat.T, check_finite=False)[0].T
    obl = theta[:, : lay.n_past] @ lfac[: lay.n_past, :k]
    u_svd, s, _ = linalg.svd(obl, full_matrices=False, check_finite=False)
    top = l * (block_rows - 1)
    if order is None:
        ratios = np.log(np.maximum(s[: top - 1], 1e-300)) - np.log(np.maximum(s[1:top], 1e-300))
        order = int(np.argmax(ratios) + 1)
    if not 1 <= order <= top:
        raise InputError(f"order must be in [1, {top}] for block_rows={block_rows}")
    gamma = u_svd[:, :order] * np.sqrt(s[:order])
    a = linalg.lstsq(gamma[:-l], gamma[l:], check_finite=False)[0]
    return a, gamma[:l] * sy[:, None], s


# --------------------------------------------------------------------- predictor in modal blocks
@dataclass
class _Blocks:
    """Real block-diagonal predictor matrix A_p = A - K C: 2x2 blocks [[al, be], [-be, al]]
    (eigenvalues al -+ i be) then 1x1 real blocks."""

    al: np.ndarray
    be: np.ndarray
    re: np.ndarray

    @property
    def n(self) -> int:
        return 2 * self.al.size + self.re.size

    def matrix(self) -> np.ndarray:
        nc = self.al.size
        a = np.zeros((self.n, self.n))
        i = 2 * np.arange(nc)
        a[i, i] = a[i + 1, i + 1] = self.al
        a[i, i + 1] = self.be
        a[i + 1, i] = -self.be
        j = 2 * nc + np.arange(self.re.size)
        a[j, j] = self.re
        return a

    def radius(self) -> float:
        return float(np.max(np.abs(np.concatenate([self.al + 1j * self.be, self.re])),
                            initial=0.0))


def _to_blocks(a: np.ndarray) -> tuple[_Blocks, np.ndarray]:
    """Real modal (block-diagonal) form of ``a``: (blocks, T) with T^-1 a T = blocks.matrix()."""
    lam, v = np.linalg.eig(a)
    cplx = np.flatnonzero(lam.imag > 1e-12)
    real = np.flatnonzero(np.abs(lam.imag) <= 1e-12)
    cols = []
    for i in cplx:
        cols += [v[:, i].real, v[:, i].imag]
    cols += [v[:, i].real for i in real]
    t = np.column_stack(cols)
    # v = vr + i vi for lam = al + i be: A [vr vi] = [vr vi] [[al, be], [-be, al]]
    return _Blocks(lam[cplx].real, lam[cplx].imag, lam[real].real), t


def _filter(pole: complex | float, x: np.ndarray) -> np.ndarray:
    """s_{k+1} = pole s_k + x_k, s_0 = 0, along axis 0 (strictly causal first-order filter)."""
    return signal.lfilter([0.0, 1.0], [1.0, -pole], x, axis=0)


class _Predictor:
    """One-step predictor x+ = A_p x + Bp u + K y, yhat = C x + D u in modal blocks, with the
    residual and its analytic Jacobian for Gauss-Newton / Levenberg-Marquardt."""

    def __init__(self, blocks: _Blocks, m: int, l: int, skip: int, weight: np.ndarray,
                 y: np.ndarray, u: np.ndarray) -> None:
        self.nc, self.nr = blocks.al.size, blocks.re.size
        self.n, self.m, self.l = blocks.n, m, l
        self.skip, self.w = skip, weight
        self.y, self.u = y, u
        self.yu = np.hstack([u, y])  # drives of [Bp K]

    def split(self, p: np.ndarray):
        nc, nr, n, m, l = self.nc, self.nr, self.n, self.m, self.l
        o = 2 * nc + nr
        blocks = _Blocks(p[:nc], p[nc : 2 * nc], p[2 * nc : o])
        bk = p[o : o + n * (m + l)].reshape(n, m + l)
        o += n * (m + l)
        c = p[o : o + l * n].reshape(l, n)
        o += l * n
        d = p[o : o + l * m].reshape(l, m)
        return blocks, bk, c, d

    @staticmethod
    def pack(blocks: _Blocks, bk: np.ndarray, c: np.ndarray, d: np.ndarray) -> np.ndarray:
        return np.concatenate([blocks.al, blocks.be, blocks.re, bk.ravel(), c.ravel(), d.ravel()])

    def states(self, blocks: _Blocks, bk: np.ndarray) -> np.ndarray:
        drive = self.yu @ bk.T  # (N, n)
        x = np.empty_like(drive)
        for b in range(self.nc):
            p = 2 * b
            lam = blocks.al[b] - 1j * blocks.be[b]
            w = _filter(lam, drive[:, p] + 1j * drive[:, p + 1])
            x[:, p], x[:, p + 1] = w.real, w.imag
        for b in range(self.nr):
            p = 2 * self.nc + b
            x[:, p] = _filter(blocks.re[b], drive[:, p])
        return x

    def residual(self, p: np.ndarray) -> np.ndarray:
        blocks, bk, c, d = self.split(p)
        if not blocks.radius() < 1.0:
            return np.full((self.y.shape[0] - self.skip) * self.l, 1e6)
        x = self.states(blocks, bk)
        e = (self.y - x @ c.T - self.u @ d.T)[self.skip :]
        return (e @ self.w.T).ravel()

    def jacobian(self, p: np.ndarray) -> np.ndarray:
        blocks, bk, c, d = self.split(p)
        n, m, l, nc, nr = self.n, self.m, self.l, self.nc, self.nr
        nk = self.y.shape[0] - self.skip
        x = self.states(blocks, bk)
        cols: list[np.ndarray] = []  # each (N - skip, l) of d yhat / d p
        sl = slice(self.skip, None)
        dal, dbe, dre = [], [], []
        dbk = np.zeros((n, m + l, nk, l))
        for b in range(nc):
            q = 2 * b
            lam = blocks.al[b] - 1j * blocks.be[b]
            cb = c[:, q : q + 2]
            g = _filter(lam, x[:, q] + 1j * x[:, q + 1])[sl]
            dal.append(np.outer(g.real, cb[:, 0]) + np.outer(g.imag, cb[:, 1]))
            dbe.append(np.outer(g.imag, cb[:, 0]) - np.outer(g.real, cb[:, 1]))
            f = _filter(lam, self.yu)[sl]  # (nk, m + l), drive entering state q
            # entering q: dx_q = Re f, dx_{q+1} = Im f; entering q+1: dx_q = -Im f, dx_{q+1} = Re f
            dbk[q] = np.einsum("kj,i->jki", f.real, cb[:, 0]) + np.einsum("kj,i->jki", f.imag,
                                                                          cb[:, 1])
            dbk[q + 1] = np.einsum("kj,i->jki", -f.imag, cb[:, 0]) + np.einsum(
                "kj,i->jki", f.real, cb[:, 1])
        for b in range(nr):
            q = 2 * nc + b
            g = _filter(blocks.re[b], x[:, q])[sl]
            dre.append(np.outer(g, c[:, q]))
            f = _filter(blocks.re[b], self.yu)[sl]
            dbk[q] = np.einsum("kj,i->jki", f, c[:, q])
        cols = dal + dbe + dre
        jac = np.empty((nk, l, len(cols) + n * (m + l) + l * n + l * m))
        for i, col in enumerate(cols):
            jac[:, :, i] = col
        o = len(cols)
        jac[:, :, o : o + n * (m + l)] = dbk.reshape(n * (m + l), nk, l).transpose(1, 2, 0)
        o += n * (m + l)
        xs = x[sl]
        for i in range(l):  # d yhat_i / d C_ij = x_j
            jac[:, :, o + i * n : o + (i + 1) * n] = 0.0
            jac[:, i, o + i * n : o + (i + 1) * n] = xs
        o += l * n
        us = self.u[sl]
        for i in range(l):
            jac[:, :, o + i * m : o + (i + 1) * m] = 0.0
            jac[:, i, o + i * m : o + (i + 1) * m] = us
        # residual = W (y - yhat): d residual = -W d yhat
        return -np.einsum("ij,kjp->kip", self.w, jac).reshape(nk * l, -1)


#: Largest condition number of the modal basis T of a predictor's A - K C used as a start:
#: beyond it A - K C is (nearly) defective, e.g. the deadbeat predictor that noise-free data
#: give (repeated eigenvalues at 0), and T^-1 amplifies rounding into garbage or fails.
MODAL_COND_MAX = 1e8


def _modal_predictor(a: np.ndarray, k: np.ndarray, c: np.ndarray
                     ) -> tuple[_Blocks, np.ndarray, np.ndarray, np.ndarray]:
    """(blocks, T, T^-1, K) of the predictor A - K C in modal form; when A - K C is (nearly)
    defective, of the output-error predictor K = 0 instead (A's modes; PEM re-estimates K)."""
    for gain in (k, np.zeros_like(k)):
        blocks, t = _to_blocks(a - gain @ c)
        if t.shape == a.shape and np.linalg.cond(t) < MODAL_COND_MAX:
            return blocks, t, np.linalg.inv(t), gain
    raise np.linalg.LinAlgError("the model's A has no well-conditioned modal form")


def _predictor_start(a: np.ndarray, b: np.ndarray, c: np.ndarray, d: np.ndarray,
                     k: np.ndarray) -> tuple[_Blocks, np.ndarray, np.ndarray, np.ndarray]:
    """Predictor (A - K C, [B - K D, K], C, D) in modal blocks (K = 0 if A - K C is defective)."""
    blocks, t, ti, k = _modal_predictor(a, k, c)
    bk = ti @ np.hstack([b - k @ d, k])
    return blocks, bk, c @ t, d


def _fit_linear(blocks: _Blocks, k_t: np.ndarray, c_t: np.ndarray, y: np.ndarray,
                u: np.ndarray, skip: int) -> tuple[np.ndarray, np.ndarray]:
    """Bp and D by least squares for a predictor with A_p, K and C fixed (yhat is linear in
    them): the start from the subspace estimate, which has no B, D, K of its own."""
    n, m, l = blocks.n, u.shape[1], y.shape[1]
    pred = _Predictor(blocks, m, l, skip, np.eye(l), y, u)
    x_k = pred.states(blocks, np.hstack([np.zeros((n, m)), k_t]))
    target = (y - x_k @ c_t.T)[skip:]
    cols = []
    for i in range(n):  # response of yhat to Bp[i, j]
        e = np.zeros((n, m + l))
        for j in range(m):
            e[:] = 0.0
            e[i, j] = 1.0
            cols.append((pred.states(blocks, e) @ c_t.T)[skip:])
    for i in range(l):
        for j in range(m):
            col = np.zeros((y.shape[0] - skip, l))
            col[:, i] = u[skip:, j]
            cols.append(col)
    phi = np.stack(cols, axis=2).reshape(-1, len(cols))
    sol = linalg.lstsq(phi, target.ravel(), check_finite=False)[0]
    return sol[: n * m].reshape(n, m), sol[n * m :].reshape(l, m)


@dataclass
class _Fit:
    a: np.ndarray
    b: np.ndarray
    c: np.ndarray
    d: np.ndarray
    k: np.ndarray
    lam_cov: np.ndarray  # innovation covariance
    cost: float
    nfev: int
    converged: bool
    pole_cov: dict  # discrete plant pole -> 2x2 covariance of (Re, Im)


@dataclass
class _LmResult:
    x: np.ndarray
    cost: float
    jtj: np.ndarray  # J'J at x
    nfev: int
    success: bool
    n_residuals: int


def _levenberg_marquardt(fun, jac, p0: np.ndarray, max_iterations: int,
                         ftol: float = 1e-10, xtol: float = 1e-10) -> _LmResult:
    """Levenberg-Marquardt with Marquardt's diagonal scaling on the normal equations J'J
    (J is tall and thin: forming J'J costs less than MINPACK's QR of J per step; the damping
    keeps the gauge-redundant modal parametrisation solvable)."""
    p = np.array(p0, dtype=float)
    r = fun(p)
    cost = 0.5 * float(r @ r)
    j = jac(p)
    jtj, g = j.T @ j, j.T @ r
    mu, nu, nfev, success = 1e-3, 2.0, 1, False
    for _ in range(max_iterations):
        scale = np.maximum(np.diag(jtj), 1e-12 * max(np.diag(jtj).max(initial=0.0), 1e-300))
        try:
            step = -linalg.solve(jtj + mu * np.diag(scale), g, assume_a="pos",
                                 check_finite=False)
        except (linalg.LinAlgError, ValueError):
            mu *= nu
            nu *= 2.0
            continue
        r_new = fun(p + step)
        nfev += 1
        cost_new = 0.5 * float(r_new @ r_new)
        predicted = -(g @ step + 0.5 * step @ jtj @ step)
        if cost_new < cost:
            rho = (cost - cost_new) / max(predicted, 1e-300)
            small = (cost - cost_new <= ftol * cost
                     or np.linalg.norm(step) <= xtol * (np.linalg.norm(p) + xtol))
            p, r, cost = p + step, r_new, cost_new
            j = jac(p)
            jtj, g = j.T @ j, j.T @ r
            mu *= max(1.0 / 3.0, 1.0 - (2.0 * rho - 1.0) ** 3)
            nu = 2.0
            if small:
                success = True
                break
        else:
            mu *= nu
            nu *= 2.0
            if mu > 1e12:
                success = True  # no descent left: a minimum to rounding
                break
    return _LmResult(p, cost, jtj, nfev, success, r.size)


def _pem(start: tuple, y: np.ndarray, u: np.ndarray, skip: int, weight: np.ndarray,
         max_iterations: int) -> _Fit:
    blocks, bk, c, d = start
    m, l = u.shape[1], y.shape[1]
    pred = _Predictor(blocks, m, l, skip, weight, y, u)
    p0 = pred.pack(blocks, bk, c, d)
    sol = _levenberg_marquardt(pred.residual, pred.jacobian, p0, max_iterations)
    blocks, bk, c, d = pred.split(sol.x)
    n = blocks.n
    ap = blocks.matrix()
    kk = bk[:, m:]
    a = ap + kk @ c
    b = bk[:, :m] + kk @ d
    x = pred.states(blocks, bk)
    e = (y - x @ c.T - u @ d.T)[skip:]
    lam_cov = e.T @ e / max(e.shape[0] - 1, 1)
    # parameter covariance (whitened residuals: unit variance when the weight is right)
    dof = max(sol.n_residuals - sol.x.size, 1)
    s2 = 2.0 * sol.cost / dof
    p_cov = s2 * linalg.pinvh(sol.jtj)
    pole_cov = _pole_covariance(blocks, bk, c, m, l, n, p_cov, a)
    return _Fit(a, b, c, d, kk, 0.5 * (lam_cov + lam_cov.T), float(sol.cost), int(sol.nfev),
                bool(sol.success), pole_cov)


def _pole_covariance(blocks: _Blocks, bk: np.ndarray, c: np.ndarray, m: int, l: int, n: int,
                     p_cov: np.ndarray, a: np.ndarray) -> dict:
    """Delta method: d lambda = w' dA v with A = A_p + K C, dA = dA_p + dK C + K dC."""
    lam, v = np.linalg.eig(a)
    w = np.linalg.inv(v)
    nc, nr = blocks.al.size, blocks.re.size
    n_p = p_cov.shape[0]
    kk = bk[:, m:]
    grads = np.zeros((lam.size, n_p), dtype=complex)
    o = 2 * nc + nr
    for i in range(nc):  # al, be
        for which, e in ((i, np.array([[1.0, 0.0], [0.0, 1.0]])),
                         (nc + i, np.array([[0.0, 1.0], [-1.0, 0.0]]))):
            da = np.zeros((n, n))
            da[2 * i : 2 * i + 2, 2 * i : 2 * i + 2] = e
            grads[:, which] = np.einsum("ji,jk,ki->i", w.T, da, v)
    for i in range(nr):
        da = np.zeros((n, n))
        da[2 * nc + i, 2 * nc + i] = 1.0
        grads[:, 2 * nc + i] = np.einsum("ji,jk,ki->i", w.T, da, v)
    # K = bk[:, m:]: dA = dK C ; index of bk[i, m + j] is o + i (m + l) + m + j
    wv_c = (w @ np.eye(n))  # rows w_q
    cv = c @ v  # (l, n)
    for i in range(n):
        for j in range(l):
            grads[:, o + i * (m + l) + m + j] = wv_c[:, i] * cv[j]
    oc = o + n * (m + l)
    wk = w @ kk  # (n_eig, l)
    for i in range(l):
        for j in range(n):
            grads[:, oc + i * n + j] = wk[:, i] * v[j]
    out = {}
    for q, mu in enumerate(lam):
        g = np.vstack([grads[q].real, grads[q].imag])
        out[complex(mu)] = g @ p_cov @ g.T
    return out


def _modes_with_std(fit: _Fit, fs: float, u_cov: np.ndarray, band, max_modes,
                    damping_bounds) -> tuple[list[ModalParameters], np.ndarray]:
    m = fit.b.shape[1]
    drive = linalg.block_diag(u_cov, fit.lam_cov) if m else fit.lam_cov
    modes, real_poles = extract_modes(fit.a, fit.c, fs, b_all=np.hstack([fit.b, fit.k]),
                                      drive_cov=drive, band=band,
                                      damping_bounds=damping_bounds, max_modes=max_modes)
    keys = np.array(list(fit.pole_cov.keys()))
    for md in modes:
        mu = md.pole_discrete
        cov_mu = fit.pole_cov[complex(keys[np.argmin(np.abs(keys - mu))])]
        cf = fs / mu
        jm = np.array([[cf.real, -cf.imag], [cf.imag, cf.real]])
        s = md.pole_continuous
        rad = abs(s)
        jf = np.array([s.real, s.imag]) / (2 * np.pi * rad)
        jz = np.array([-(s.imag**2), s.real * s.imag]) / rad**3
        cs = jm @ cov_mu @ jm.T
        md.frequency_std_hz = float(np.sqrt(max(jf @ cs @ jf, 0.0)))
        md.damping_std = float(np.sqrt(max(jz @ cs @ jz, 0.0)))
    return modes, real_poles


def _as_model(fit: _Fit, fs: float, u_cov: np.ndarray, band, max_modes,
              damping_bounds) -> IdentifiedModel:
    modes, real_poles = _modes_with_std(fit, fs, u_cov, band, max_modes, damping_bounds)
    n, m, l = fit.a.shape[0], fit.b.shape[1], fit.c.shape[0]
    return IdentifiedModel(
        A=fit.a, B=fit.b, C=fit.c, D=fit.d, K=fit.k, Q=fit.k @ fit.lam_cov @ fit.k.T,
        R=fit.lam_cov, S=fit.k @ fit.lam_cov, innovation_covariance=fit.lam_cov, fs=fs, order=n,
        singular_values=np.zeros(0), n_inputs=m, n_outputs=l, modes=modes,
        real_poles=real_poles, input_covariance=u_cov,
    )


def identify_closed_loop(
    y: np.ndarray,
    u: np.ndarray,
    r: np.ndarray | None = None,
    controller: DiscreteController | None = None,
    fs: float = 1.0,
    order: int | None = None,
    block_rows: int = 20,
    band: tuple[float, float] | None = None,
    max_modes: int | None = None,
    damping_bounds: tuple[float, float] | None = (-0.5, 0.5),
    max_iterations: int = 200,
) -> ClosedLoopResult:
    """Open-loop plant (modes, A, B, C, D, K) from closed-loop data u = r + K y.

    ``r`` is the recorded reference; without it, the known ``controller`` reconstructs it as
    u - K y; with neither, the direct PEM starts from the naive DSRA alone. ``order`` is the
    plant order (None: the singular-value gap of the IV projection, or of the naive DSRA).
    Damping bounds default to (-0.5, 0.5): open-loop unstable modes are what closed-loop
    identification is for. The PEM starts from whichever of the reference-IV subspace
    estimate and the naive DSRA predicts the data better (both reached the same optimum in
    every case we ran; one run halves the cost).
    """
    fs = check_rate(fs)
    y, u = validate_batch(y, u, block_rows)
    if u.shape[1] == 0:
        raise InputError("closed-loop identification needs the applied input u")
    if r is None and controller is not None:
        if controller.n_sensors != y.shape[1] or controller.n_actuators != u.shape[1]:
            raise InputError(
                f"controller reads {controller.n_sensors} output(s) and drives "
                f"{controller.n_actuators} input(s); the data has {y.shape[1]} and {u.shape[1]}")
        if abs(controller.fs - fs) > 1e-6 * fs:
            raise InputError(f"controller runs at {controller.fs:g} Hz, the data at {fs:g} Hz")
        r = controller.reference(u, y)
    subspace_ac = None
    if r is not None:
        r = as_2d(r, "r", u.shape[1])
        if r.shape[0] != y.shape[0]:
            raise InputError(f"r has {r.shape[0]} samples but y has {y.shape[0]}")
        if not np.all(np.isfinite(r)) or np.any(np.std(r, axis=0) <= 0):
            raise InputError("r must be finite with nonzero variance in every channel")
        a_iv, c_iv, _ = iv_subspace(y, u, r, block_rows, order)
        order = a_iv.shape[0]
        subspace_ac = (a_iv, c_iv)
    naive = identify(y, u, fs=fs, order=order, block_rows=block_rows, band=band,
                     max_modes=max_modes, damping_bounds=damping_bounds)
    order = naive.order
    u_cov = np.cov(u.T).reshape(u.shape[1], u.shape[1])
    skip = min(y.shape[0] // 10, 40 * block_rows)
    lam0 = naive.innovation_covariance
    weight = linalg.inv(linalg.cholesky(0.5 * (lam0 + lam0.T), lower=True))
    starts = {"naive": _predictor_start(naive.A, naive.B, naive.C, naive.D, naive.K)}
    subspace = None
    if subspace_ac is not None:
        a_iv, c_iv = subspace_ac
        start = _subspace_start(a_iv, c_iv, y, u, skip, lam0)
        if start is not None:
            starts["reference-iv"] = start
            blocks, bk, c_t, d_t = start
            subspace = _as_model(_fit_from_predictor(blocks, bk, c_t, d_t, u.shape[1]), fs,
                                 u_cov, band, max_modes, damping_bounds)
    initial = {}
    for name, (blocks, bk, c_t, d_t) in starts.items():
        pred = _Predictor(blocks, u.shape[1], y.shape[1], skip, weight, y, u)
        initial[name] = 0.5 * float(np.sum(pred.residual(pred.pack(blocks, bk, c_t, d_t)) ** 2))
    best = min(initial, key=initial.get)
    fit = _pem(starts[best], y, u, skip, weight, max_iterations)
    plant = _as_model(fit, fs, u_cov, band, max_modes, damping_bounds)
    return ClosedLoopResult(plant, subspace, naive, best, fit.nfev, fit.cost, fit.converged,
                            {"initial_cost": initial})


def _subspace_start(a: np.ndarray, c: np.ndarray, y: np.ndarray, u: np.ndarray, skip: int,
                    lam0: np.ndarray):
    """Predictor start from the IV (A, C): a Kalman gain from a generic disturbance on every
    state (any stabilising K will do, PEM re-estimates it), then Bp and D by least squares."""
    n = a.shape[0]
    # state disturbance whose output share is about 1 % of the innovation variance
    q = 1e-2 * np.trace(lam0) / max(np.trace(c.T @ c), 1e-300) * np.eye(n)
    try:
        p = linalg.solve_discrete_are(a.T, c.T, q, lam0)
        k = a @ p @ c.T @ linalg.inv(c @ p @ c.T + lam0)
    except (linalg.LinAlgError, ValueError, np.linalg.LinAlgError):
        return None
    if not np.max(np.abs(np.linalg.eigvals(a - k @ c))) < 1.0:
        return None
    try:
        blocks, t, ti, k = _modal_predictor(a, k, c)
    except np.linalg.LinAlgError:
        return None
    k_t, c_t = ti @ k, c @ t
    bp, d = _fit_linear(blocks, k_t, c_t, y, u, skip)
    return blocks, np.hstack([bp, k_t]), c_t, d


def _fit_from_predictor(blocks: _Blocks, bk: np.ndarray, c: np.ndarray, d: np.ndarray,
                        m: int) -> _Fit:
    kk = bk[:, m:]
    a = blocks.matrix() + kk @ c
    lam = np.linalg.eigvals(a)
    return _Fit(a, bk[:, :m] + kk @ d, c, d, kk, np.eye(c.shape[0]), float("nan"), 0, False,
                {complex(z): np.full((2, 2), np.nan) for z in lam})
