"""The DSRA realization from the square-root (LQ) factor of the windowed data, shared by the
batch (Appendix A) and the recursive (Appendix B) algorithm.

Both work on ``L``, a lower-triangular factor of the (weighted) data product
``Z Z' = L L'`` with ``Z = [U_{1|i}; Y_{1|i}; U_{i+1|2i}; Y_{i+1|2i}]`` (A1): the batch gets it from
a QR factorisation of ``Z'`` (``Z = L Q``), the recursive estimator from the Cholesky factor of its
exponentially weighted information matrix. Every matrix of Appendix A is a product ``M Q``, so the
steps can be carried out on the coefficient matrices ``M`` (``Q`` has orthonormal rows):

1. (A2) ``[L_p T_d] = L_{f,1:r} L_{1:r,1:r}^{-1}`` by triangular solves (no normal equations);
2. SVD of ``L_p [U_{1|i}; Y_{1|i}] = U S V'``;
3. Kalman states (A3) ``X_{i+1} = S_1^{1/2} V_1' = S_1^{-1/2} U_1' L_p W_p`` and the shifted
   states ``X_{i+2}`` from the same problem with one more past block row;
4. (A4) ``[X_{i+2}; Y_{i+1|i+1}] = [A B; C D] [X_{i+1}; U_{i+1|i+1}]``, with A and C taken from
   the shift invariance of ``Gamma_i = U_1 S_1^{1/2}`` (see :func:`realize`) and B, D by least
   squares; its residuals give the noise covariances Q, S, R (process, cross, measurement).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import linalg

from .hankel import Layout


@dataclass
class Projection:
    """Result of steps 1-2 for one data factor; realizations of any order are cheap from it."""

    layout: Layout
    L: np.ndarray  # (d, d) lower-triangular data factor
    theta: np.ndarray  # [L_p T_d], (l i, r)
    U: np.ndarray  # left singular vectors of the oblique projection
    s: np.ndarray  # raw singular values
    o_full: np.ndarray  # L_p W_p as coefficients of Q, (l i, d)
    o_shift: np.ndarray  # L_p^- W_p^+ for the shifted states, (l (i-1), d)
    sum_w: float  # sum of sample weights (number of columns for the batch)
    sum_w2: float  # sum of squared weights

    @property
    def singular_values(self) -> np.ndarray:
        """Singular values normalised per column (RMS units, comparable across data lengths)."""
        return self.s / np.sqrt(max(self.sum_w, 1e-300))


@dataclass
class Realization:
    """Discrete model in the scaled units of the projection, plus the (A4) statistics."""

    A: np.ndarray
    B: np.ndarray
    C: np.ndarray
    D: np.ndarray
    Q: np.ndarray
    S: np.ndarray
    R: np.ndarray
    a_cov_rows: np.ndarray  # Q_w: covariance of the state-equation residuals
    a_cov_cols: np.ndarray  # (X X')^{-1} block times the forgetting correction
    u_cov: np.ndarray  # covariance of the input (scaled units)
    x_cov: np.ndarray  # covariance of the (A3) Kalman states: S_1 / sum w (balanced basis)


def _lower_solve_right(lmat: np.ndarray, rhs: np.ndarray) -> np.ndarray:
    """X with X lmat = rhs for lower-triangular lmat (i.e. rhs lmat^{-1})."""
    return linalg.solve_triangular(lmat, rhs.T, lower=True, trans="T", check_finite=False).T


def project(L: np.ndarray, layout: Layout, sum_w: float, sum_w2: float) -> Projection:
    """Steps 1-2: the least-squares problem (A2) and the SVD of L_p [U_{1|i}; Y_{1|i}]."""
    i, m, l = layout.i, layout.m, layout.l
    d = layout.dim
    n_past = layout.n_past
    r = n_past + i * m  # regressors [past; future inputs]
    yf = layout.yf
    theta = _lower_solve_right(L[:r, :r], L[yf, :r])
    o_full = np.zeros((l * i, d))
    o_full[:, :n_past] = theta[:, :n_past] @ L[:n_past, :n_past]
    # left singular vectors/values of L_p W_p from the small Gram matrix (l i x l i)
    op = o_full[:, :n_past]
    ev, u_svd = linalg.eigh(op @ op.T, check_finite=False)
    ev, u_svd = ev[::-1], u_svd[:, ::-1]
    # sign convention (largest entry of each vector positive): the state basis, and so A, B,
    # C, does not flip with rounding
    big = u_svd[np.argmax(np.abs(u_svd), axis=0), np.arange(u_svd.shape[1])]
    u_svd = u_svd * np.where(big < 0, -1.0, 1.0)
    s = np.sqrt(np.maximum(ev, 0.0))
    # shifted problem: Y_{i+2|2i} on [W_p^+; U_{i+2|2i}], W_p^+ = [U_{1|i+1}; Y_{1|i+1}]
    r2 = r + l
    theta2 = _lower_solve_right(L[:r2, :r2], L[yf.start + l :, :r2])
    wp_plus = np.concatenate((np.arange(n_past + m), np.arange(r, r2)))
    o_shift = np.zeros((l * (i - 1), d))
    o_shift[:, :r2] = theta2[:, wp_plus] @ L[wp_plus, :r2]
    return Projection(layout, L, theta, u_svd, s, o_full, o_shift, sum_w, sum_w2)


class ShiftBasis:
    """One QR of Gamma_i^- (the extended observability matrix without its last block row) for
    the largest order needed; its leading columns serve every smaller order, because the
    columns of Gamma_i = U_1 S_1^{1/2} are nested across orders. Realizations of several orders
    from one projection (the multi-order stabilization) then cost one triangular solve each."""

    def __init__(self, proj: Projection, top: int) -> None:
        l = proj.layout.l
        self.top = int(top)
        self.gamma = proj.U[:, :top] * np.sqrt(np.maximum(proj.s[:top], 1e-300))
        q, self.r = linalg.qr(self.gamma[:-l], mode="economic", check_finite=False)
        self.qt_up = q.T @ self.gamma[l:]  # Q' Gamma_i^+
        self.qt_shift = q.T @ proj.o_shift  # Q' (coefficients of the shifted states)

    def a_matrix(self, n: int) -> np.ndarray:
        """A of order n: least squares Gamma_i^- A = Gamma_i^+ on the leading n columns."""
        return linalg.solve_triangular(self.r[:n, :n], self.qt_up[:n, :n], check_finite=False)

    def shifted_states(self, n: int) -> np.ndarray:
        """Coefficients of the shifted Kalman states X_{i+2} of order n."""
        return linalg.solve_triangular(self.r[:n, :n], self.qt_shift[:n], check_finite=False)


def realize(proj: Projection, n: int, basis: ShiftBasis | None = None) -> Realization:
    """Steps 3-4: Kalman states (A3) of order n and the realization (A4).

    A and C come from the shift invariance of the extended observability matrix
    Gamma_i = U_1 S_1^{1/2} (C = first block row, Gamma_i^- A = Gamma_i^+), in the basis of the
    (A3) states; B and D then follow from (A4) by least squares with A and C fixed. Taking A
    from the state regression (A4) as printed is biased for finite i when the Kalman filter
    converges slowly (lightly damped modes with output noise, short records: the paper's Sec. II
    example at i = 20 and 2 s of data); the shift form is not (Van Overschee & De Moor 1996,
    Sec. 4.3, their "robust" variant). The (A4) residuals give the noise covariances Q, S, R.
    ``basis`` (a :class:`ShiftBasis` of at least order n) is reused when given.
    """
    lay = proj.layout
    m, l = lay.m, lay.l
    L = proj.L
    if basis is None or basis.top < n:
        basis = ShiftBasis(proj, n)
    u1 = proj.U[:, :n]
    s1 = np.maximum(proj.s[:n], 1e-300)
    x1 = (u1.T @ proj.o_full) / np.sqrt(s1)[:, None]
    x2 = basis.shifted_states(n)
    a_mat = basis.a_matrix(n)
    c_mat = basis.gamma[:l, :n]
    uf1 = L[lay.uf.start : lay.uf.start + m]
    yf1 = L[lay.yf.start : lay.yf.start + l]
    tgt = np.vstack([x2 - a_mat @ x1, yf1 - c_mat @ x1])
    if m:  # (A4) with A, C fixed: [B; D] by QR of the input coefficients
        bd = linalg.lstsq(uf1.T, tgt.T, check_finite=False)[0].T
        res = tgt - bd @ uf1
    else:
        bd = np.zeros((n + l, 0))
        res = tgt
    cov = res @ res.T / max(proj.sum_w, 1e-300)
    cov = 0.5 * (cov + cov.T)
    # (X X')^{-1} of the state regressors for the delta-method covariance of A (modal.py)
    reg = np.vstack([x1, uf1])
    qr_r = linalg.qr(reg.T, mode="r", check_finite=False)[0][: n + m]
    diag = np.abs(np.diag(qr_r))
    tol = max(diag.max(initial=0.0), 1e-300) * 1e-12
    qr_r = qr_r + np.diag(np.where(diag < tol, tol, 0.0))
    rinv = linalg.solve_triangular(qr_r, np.eye(n + m), check_finite=False)
    p_reg = rinv @ rinv.T
    factor = proj.sum_w2 / max(proj.sum_w, 1e-300)
    return Realization(
        A=a_mat,
        B=bd[:n],
        C=c_mat,
        D=bd[n:],
        Q=cov[:n, :n],
        S=cov[:n, n:],
        R=cov[n:, n:],
        a_cov_rows=cov[:n, :n],
        a_cov_cols=p_reg[:n, :n] * factor,
        u_cov=uf1 @ uf1.T / max(proj.sum_w, 1e-300),
        x_cov=np.diag(s1) / max(proj.sum_w, 1e-300),
    )


def shift_poles(basis: ShiftBasis, orders: list[int]) -> list[np.ndarray]:
    """Discrete poles (eigenvalues of A) of the realizations of several ``orders`` (each at most
    ``basis.top``) from one projection, A by the shift invariance of Gamma_i as in
    :func:`realize`: one triangular solve and one small eigenvalue problem per order. Used for
    the multi-order stabilization of every realization (``spurious.py``)."""
    return [np.linalg.eigvals(basis.a_matrix(n)) for n in orders]


def kalman_gain(
    a: np.ndarray,
    c: np.ndarray,
    q: np.ndarray,
    s: np.ndarray,
    r: np.ndarray,
    riccati: bool = True,
) -> tuple[np.ndarray, np.ndarray]:
    """Steady-state Kalman gain K and innovation covariance for the innovation form
    x+ = A x + B u + K e, y = C x + D u + e; falls back to K = S R^{-1} (the residual
    regression: the (A3) states are Kalman states, so their residuals are K e) when the Riccati
    equation has no stabilising solution, or when ``riccati`` is False (the recursive
    realizations: no Riccati equation per realization; :meth:`IdentifiedModel.predictor` makes
    the predictor stable when the model is used for prediction)."""
    n, l = a.shape[0], c.shape[0]
    r_reg = r + 1e-12 * max(np.trace(r) / max(l, 1), 1e-300) * np.eye(l)
    if not riccati:
        k = linalg.solve(r_reg, s.T, assume_a="pos").T
        if np.all(np.isfinite(k)):
            return k, r_reg
    try:
        with np.errstate(all="ignore"):
            p = linalg.solve_discrete_are(a.T, c.T, q + 1e-12 * np.eye(n), r_reg, s=s)
        re = c @ p @ c.T + r_reg
        k = linalg.solve(re, (a @ p @ c.T + s).T, assume_a="pos").T
        if np.all(np.isfinite(k)) and np.max(np.abs(np.linalg.eigvals(a - k @ c))) < 1.0:
            return k, 0.5 * (re + re.T)
    except (linalg.LinAlgError, ValueError, np.linalg.LinAlgError):
        pass
    k = linalg.solve(r_reg, s.T, assume_a="pos").T
    return k, r_reg
