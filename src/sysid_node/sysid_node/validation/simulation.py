"""Free-run (simulation) of identified models and the output-error least squares of B and D.

With A and C fixed (the DSRA realization, Appendix A steps 3-4), the free-run output

    y_t = C A^t x0 + sum_{s<t} C A^(t-1-s) B u_s + D u_t + Phi_t theta

is linear in the initial state x0, in B, D and in the coefficients theta of additive regressors
Phi (bias, harmonics). Least squares on this *simulation* error gives the B and D that make the
model's free run closest to the measurement (the (A4) regression of the paper fits a one-step
relation between noisy Kalman states instead, which can leave a poor free run: the "simulation
focus" of subspace identification). The convolutions use the Markov parameters C A^p, computed
by repeated squaring and applied by FFT: no per-sample loop, no eigenvector basis (robust to
repeated or defective poles).

A cubic stiffness q = y_c^3 fed back as an input makes the free run nonlinear; it is solved by
fixed-point (Picard) iteration of whole-record linear simulations, with a sample-by-sample
recursion as the fallback when the iteration does not contract.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import linalg

#: A free run is declared diverged beyond this many times the largest measured amplitude.
DIVERGENCE_FACTOR = 1e3


def spectral_radius(a: np.ndarray) -> float:
    """Largest eigenvalue modulus (0 for an empty matrix)."""
    return float(np.max(np.abs(np.linalg.eigvals(a)), initial=0.0)) if a.size else 0.0


def markov_kernel(a: np.ndarray, c: np.ndarray, n_samples: int, tol: float = 1e-13) -> np.ndarray:
    """H_p = C A^p for p = 0..P-1 as a (P, l, n) array, P <= n_samples.

    Blocks are doubled with the squared powers of A (log2 N matrix products); the kernel is cut
    where the remaining terms are below ``tol`` times its largest entry (stable A).
    """
    n, l = a.shape[0], c.shape[0]
    h = np.empty((max(n_samples, 1), l, n))
    h[0] = c
    power, k = a.copy(), 1
    scale = max(float(np.abs(c).max(initial=0.0)), 1e-300)
    while k < n_samples:
        m = min(k, n_samples - k)
        with np.errstate(over="ignore", invalid="ignore"):
            h[k : k + m] = h[:m] @ power
        tail = float(np.abs(h[k : k + m]).max(initial=0.0))
        k += m
        if not np.isfinite(tail):
            raise FloatingPointError("unstable dynamics: the Markov parameters overflow")
        if tail < tol * scale:
            break
        with np.errstate(over="ignore", invalid="ignore"):
            power = power @ power
    return h[:k]


class LinearDynamics:
    """Fixed (A, C) and their Markov kernel: simulation regressors for B, D, x0.

    Convolutions with the kernel are products of real FFTs; the kernel's transform is kept
    per FFT length, so many regressors or simulations of one (A, C) cost one FFT each.
    """

    def __init__(self, a: np.ndarray, c: np.ndarray, kernel: np.ndarray):
        self.A, self.C, self.kernel = a, c, kernel
        self._spectra: dict[int, np.ndarray] = {}

    @classmethod
    def build(cls, a: np.ndarray, c: np.ndarray, n_samples: int) -> LinearDynamics:
        return cls(a, c, markov_kernel(a, c, n_samples))

    @property
    def order(self) -> int:
        return self.A.shape[0]

    @property
    def n_outputs(self) -> int:
        return self.C.shape[0]

    def _spectrum(self, nfft: int) -> np.ndarray:
        """rfft of the kernel delayed by one sample (the state update), (F, l, n)."""
        if nfft not in self._spectra:
            k = self.kernel[: nfft - 1]
            pad = np.zeros((nfft,) + k.shape[1:])
            pad[1 : 1 + k.shape[0]] = k
            self._spectra = {nfft: np.fft.rfft(pad, axis=0)}
        return self._spectra[nfft]

    def _nfft(self, n_s: int) -> int:
        return int(2 ** np.ceil(np.log2(max(n_s + min(n_s, self.kernel.shape[0]), 2))))

    def input_regressors(self, v: np.ndarray) -> np.ndarray:
        """(N, l, n): output response at t to a unit entry B[i, .] driven by v (N,),
        sum_{s<t} C A^(t-1-s) e_i v_s."""
        v = np.asarray(v, float).ravel()
        nfft = self._nfft(v.size)
        spec = np.fft.rfft(v, nfft)[:, None, None] * self._spectrum(nfft)
        return np.fft.irfft(spec, nfft, axis=0)[: v.size]

    def initial_regressors(self, n_samples: int) -> np.ndarray:
        """(N, l, n): C A^t (zero beyond the kernel's length)."""
        out = np.zeros((n_samples, self.n_outputs, self.order))
        p = min(n_samples, self.kernel.shape[0])
        out[:p] = self.kernel[:p]
        return out

    def simulate(self, b: np.ndarray, v: np.ndarray, x0: np.ndarray | None = None) -> np.ndarray:
        """sum_{s<t} C A^(t-1-s) B v_s (+ C A^t x0) for v (N, m): (N, l), without D."""
        v = np.atleast_2d(np.asarray(v, float).T).T
        n_s = v.shape[0]
        nfft = self._nfft(n_s)
        drive = np.fft.rfft(v, nfft, axis=0) @ b.T  # (F, n): B v in the frequency domain
        spec = np.einsum("fln,fn->fl", self._spectrum(nfft), drive)
        y = np.fft.irfft(spec, nfft, axis=0)[:n_s]
        if x0 is not None:
            p = min(n_s, self.kernel.shape[0])
            y[:p] += self.kernel[:p] @ x0
        return y


@dataclass
class OutputErrorFit:
    """Least-squares solution of the simulation error with A, C fixed."""

    B: np.ndarray  # (n, m)
    D: np.ndarray  # (l, m)
    x0: np.ndarray  # (n,)
    theta: np.ndarray | None  # (p, l) additive regressor coefficients
    rms: np.ndarray  # (l,) simulation-error RMS on the fitted rows


@dataclass
class _Design:
    """The weighted least-squares problem of :func:`fit_output_error` and its solution."""

    matrix: np.ndarray  # (Nr l, k) weighted regressors
    target: np.ndarray  # (Nr l,) weighted measurements
    sol: np.ndarray  # (k,)
    weights: np.ndarray  # (l,) 1 / std of each channel
    fit: OutputErrorFit


def _design(
    dyn: LinearDynamics,
    y: np.ndarray,
    inputs: np.ndarray,
    rows,
    additive: np.ndarray | None,
    direct: np.ndarray | None,
    estimate_x0: bool = True,
) -> _Design:
    y = np.atleast_2d(np.asarray(y, float).T).T
    inputs = np.atleast_2d(np.asarray(inputs, float).T).T
    direct = inputs if direct is None else np.atleast_2d(np.asarray(direct, float).T).T
    n_s, l = y.shape
    n, m = dyn.order, inputs.shape[1]
    w = 1.0 / np.maximum(np.std(y[rows], axis=0), 1e-300)
    blocks = [dyn.input_regressors(inputs[:, j])[rows] for j in range(m)]  # (Nr, l, n) each
    if estimate_x0:
        blocks.append(dyn.initial_regressors(n_s)[rows])
    nr = y[rows].shape[0]
    shared = np.concatenate(blocks, axis=2) if blocks else np.zeros((nr, l, 0))
    pc = direct if additive is None else np.hstack([direct, additive])
    pc = pc[rows]  # (Nr, q): its own coefficient on each channel
    q = pc.shape[1]
    ns = shared.shape[2]
    design = np.zeros((nr, l, ns + q * l))
    design[:, :, :ns] = shared
    for c in range(l):
        design[:, c, ns + c * q : ns + (c + 1) * q] = pc
    design = (design * w[None, :, None]).reshape(nr * l, -1)
    target = (y[rows] * w[None, :]).reshape(nr * l)
    scale = np.linalg.norm(design, axis=0)
    scale = np.where(scale > 0, scale, 1.0)
    sol = linalg.lstsq(design / scale, target, lapack_driver="gelsy", check_finite=False)[0]
    sol = sol / scale
    resid = (target - design @ sol).reshape(nr, l) / w[None, :]
    b = sol[: n * m].reshape(m, n).T
    k = n * m
    x0 = sol[k : k + n] if estimate_x0 else np.zeros(n)
    k += n if estimate_x0 else 0
    coef = sol[k:].reshape(l, q).T  # (q, l)
    md = direct.shape[1]
    theta = coef[md:] if additive is not None else None
    rms = np.sqrt(np.mean(resid**2, axis=0))
    return _Design(design, target, sol, w, OutputErrorFit(b, coef[:md].T, x0, theta, rms))


def fit_output_error(
    dyn: LinearDynamics,
    y: np.ndarray,
    inputs: np.ndarray,
    rows,
    additive: np.ndarray | None = None,
    direct: np.ndarray | None = None,
    estimate_x0: bool = True,
) -> OutputErrorFit:
    """B, D, x0 and theta minimising || y - ysim ||^2 over ``rows`` (channels weighted by 1/std).

    ``inputs`` (N, m) drive the state (B); ``direct`` (N, m_d) act directly on the output (D;
    default: the inputs themselves); ``additive`` (N, p) regressors act on every output channel
    with their own coefficients.
    """
    return _design(dyn, y, inputs, rows, additive, direct, estimate_x0).fit


def simulate_linear(
    dyn: LinearDynamics,
    b: np.ndarray,
    d: np.ndarray,
    inputs: np.ndarray,
    x0: np.ndarray | None = None,
) -> np.ndarray:
    """Free run y = C A^t x0 + sum C A^(t-1-s) B u_s + D u_t, (N, l)."""
    inputs = np.atleast_2d(np.asarray(inputs, float).T).T
    return dyn.simulate(b, inputs, x0) + inputs @ d.T


def cubic_coordinate(a: np.ndarray, c_row: np.ndarray, fs: float, integrals: int) -> np.ndarray:
    """Row vector c_z with z = c_z x the spring's coordinate: the output row itself, or its
    p-fold integral C A_c^-p (A_c = fs log A, the continuous-time dynamics; exact for the
    state-driven part of a velocity / acceleration output)."""
    if integrals == 0:
        return np.asarray(c_row, float).copy()
    lam, v = np.linalg.eig(a)
    with np.errstate(divide="ignore"):
        s = fs * np.log(lam.astype(complex))
    s = np.where(np.abs(s) > 1e-9 * fs, s, 1e-9 * fs)
    inv = (v * (1.0 / s) ** integrals) @ np.linalg.inv(v)
    return np.real(np.asarray(c_row, float) @ inv)


def integrate(y: np.ndarray, fs: float, times: int, f_min: float) -> np.ndarray:
    """The ``times``-fold time integral of a measured signal (velocity -> displacement, or
    acceleration -> displacement), Y(f) / (i 2 pi f)^times by FFT, zero below ``f_min`` [Hz]
    (no drift from the low-frequency noise); non-causal, for regressors only."""
    y = np.asarray(y, float)
    if times == 0:
        return y.copy()
    n = y.size
    f = np.fft.rfftfreq(n, 1.0 / fs)
    spec = np.fft.rfft(y - y.mean())
    gain = np.zeros_like(f, dtype=complex)
    keep = f >= max(f_min, fs / n)
    gain[keep] = (1.0 / (2j * np.pi * f[keep])) ** times
    return np.fft.irfft(spec * gain, n)


def next_sample(q: np.ndarray) -> np.ndarray:
    """q_{t+1} aligned with t (the last sample repeated)."""
    out = np.empty_like(q)
    out[:-1], out[-1] = q[1:], q[-1]
    return out


def spring_inputs(u: np.ndarray, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(state drive, direct drive) of a cubic spring force q = z^3 as one more input: the state
    sees its mean over the sample (q_t + q_t+1) / 2 (first-order hold: the force is smooth),
    the output its value at the sample: ([u, q_mean], [u, q])."""
    q = np.asarray(q, float).ravel()
    return np.column_stack([u, 0.5 * (q + next_sample(q))]), np.column_stack([u, q])


def simulate_cubic(
    dyn: LinearDynamics,
    b: np.ndarray,
    d: np.ndarray,
    u: np.ndarray,
    x0: np.ndarray | None = None,
    max_iter: int = 100,
    rtol: float = 1e-8,
) -> tuple[np.ndarray, np.ndarray]:
    """Free run of a linear structure with a cubic spring (Lur'e form):

        x+ = A x + B_u u + b_q (q_t + q_t+1) / 2,  y = C x + D_u u + d_q q_t,
        q = z^3,  z = c_z x,

    ``b`` = [B_u, b_q], ``d`` = [D_u, d_q], ``dyn`` holding C with the coordinate row c_z
    appended (l + 1 rows). The force's mean over the sample makes each step an implicit
    equation z = p + g z^3 (g = c_z b_q / 2); the explicit form x+ = A x + b_q q_t diverges for
    a stiff spring at low sample rates. Picard iteration over the whole record first (one
    linear simulation per iteration; it may wander before it contracts); when it has not
    converged after ``max_iter`` iterations, the sample-by-sample recursion with Newton on each
    sample's cubic (the nonlinear feedback has no closed form). Returns
    (y (N, l), z (N,)), NaN from the sample where the free run diverges.
    """
    u = np.atleast_2d(np.asarray(u, float).T).T
    l, m = d.shape[0], u.shape[1]
    q = np.zeros(u.shape[0])
    scale = max(float(np.max(np.abs(dyn.simulate(b[:, :m], u, x0)))), 1e-300)
    z_prev = None
    with np.errstate(all="ignore"):
        for _ in range(max_iter):
            v, w = spring_inputs(u, q)
            out = dyn.simulate(b, v, x0)
            z = out[:, l]
            if z_prev is not None:
                step = float(np.max(np.abs(z - z_prev)))
                if not step < 1e2 * scale:  # diverging (or NaN): the recursion decides
                    break
                if step <= rtol * scale:
                    return out[:, :l] + w @ d.T, z
            z_prev, q = z, z**3
    return _cubic_recursion(dyn.A, b, dyn.C, d, u, x0, scale)


def _cubic_root(p: float, g: float) -> float:
    """The root of z = p + g z^3 reached by Newton from p (NaN at a fold: no nearby root)."""
    z = p
    for _ in range(50):
        f = z - p - g * z**3
        df = 1.0 - 3.0 * g * z * z
        if df <= 0.0:
            return float("nan")
        step = f / df
        z -= step
        if abs(step) <= 1e-13 * max(abs(z), 1e-300):
            return z
    return z if abs(z - p - g * z**3) <= 1e-9 * max(abs(z), 1e-300) else float("nan")


def _cubic_recursion(
    a: np.ndarray,
    b: np.ndarray,
    c_ext: np.ndarray,
    d: np.ndarray,
    u: np.ndarray,
    x0: np.ndarray | None,
    scale: float,
) -> tuple[np.ndarray, np.ndarray]:
    """Sample-by-sample free run (fallback of :func:`simulate_cubic`; NaN after divergence)."""
    n_s, m = u.shape
    c, cz = c_ext[:-1], c_ext[-1]
    x = np.zeros(a.shape[0]) if x0 is None else np.asarray(x0, float).copy()
    bq, dq = b[:, m], d[:, m]
    g = 0.5 * float(cz @ bq)
    drive = u @ b[:, :m].T  # (N, n)
    direct = u @ d[:, :m].T
    y = np.full((n_s, c.shape[0]), np.nan)
    z = np.full(n_s, np.nan)
    lim = DIVERGENCE_FACTOR * scale
    q = float(cz @ x) ** 3
    for t in range(n_s):
        yt = c @ x + direct[t] + dq * q
        if not np.all(np.abs(yt) < lim):
            break
        y[t], z[t] = yt, cz @ x
        v = a @ x + drive[t] + 0.5 * q * bq
        zn = _cubic_root(float(cz @ v), g) if g else float(cz @ v)
        q = zn**3
        x = v + 0.5 * q * bq
    return y, z


def real_modal_basis(a: np.ndarray) -> tuple[np.ndarray, np.ndarray, list[int]]:
    """(T, eigenvalues, kinds) with T^-1 A T block-diagonal: [[Re l, Im l], [-Im l, Re l]] per
    complex pair (kind 2, basis [Re v, Im v]) and [l] per real pole (kind 1)."""
    lam, v = np.linalg.eig(a)
    tol = 1e-9 * max(1.0, float(np.max(np.abs(lam), initial=0.0)))
    cols, eig, kinds = [], [], []
    for k in np.flatnonzero(lam.imag > tol):
        cols += [v[:, k].real, v[:, k].imag]
        eig.append(lam[k])
        kinds.append(2)
    for k in np.flatnonzero(np.abs(lam.imag) <= tol):
        cols.append(v[:, k].real)
        eig.append(complex(lam[k].real))
        kinds.append(1)
    return np.column_stack(cols), np.array(eig), kinds


def block_matrix(eig: np.ndarray, kinds: list[int]) -> np.ndarray:
    """The real block-diagonal matrix of :func:`real_modal_basis` for given eigenvalues."""
    n = sum(kinds)
    a = np.zeros((n, n))
    k = 0
    for lam, kind in zip(eig, kinds, strict=True):
        if kind == 2:
            a[k : k + 2, k : k + 2] = [[lam.real, lam.imag], [-lam.imag, lam.real]]
        else:
            a[k, k] = lam.real
        k += kind
    return a


def refine_poles(
    a: np.ndarray,
    c: np.ndarray,
    y: np.ndarray,
    rows,
    signals,
    extra0: np.ndarray,
    additive: np.ndarray | None = None,
    max_nfev: int = 30,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Output-error refinement of the complex poles of A and of extra parameters (variable
    projection, Golub-Pereyra with Kaufman's Jacobian).

    In the real modal basis T of A (C T fixed: the mode shapes), the eigenvalues
    lambda = exp(sigma + i omega) of every complex pair and the parameters ``extra`` (e.g. a
    spring's stiffness) are adjusted to minimise the free-run error; B, D, x0 and theta are
    solved by least squares for each value (:func:`fit_output_error`) with the drives
    ``signals(extra) -> (state inputs, direct inputs)``. The Jacobian of the projected residual
    is -P_perp dy/dx at fixed linear parameters: for a 2 x 2 rotation-scaling block
    d(A_k^p)/d sigma = p A_k^p and d(A_k^p)/d omega = p A_k^p J, so each column is one more
    convolution with the Markov kernel times p. Returns (A', C', T, extra) with A' the refined
    block-diagonal dynamics and C' = C T.
    """
    from scipy.optimize import least_squares

    t, eig, kinds = real_modal_basis(a)
    ct = c @ t
    pairs = [k for k, kind in enumerate(kinds) if kind == 2]
    offsets = np.cumsum([0, *kinds])[:-1]
    real = [k for k, kind in enumerate(kinds) if kind == 1]
    eig[real] = np.clip(eig[real].real, -0.999, 0.999)  # an unstable real pole: reflected in
    y = np.atleast_2d(np.asarray(y, float).T).T
    n_s = y.shape[0]
    npr = len(pairs)
    logs = np.log(eig[pairs]) if npr else np.zeros(0, complex)
    extra0 = np.atleast_1d(np.asarray(extra0, float))
    ne = extra0.size
    x0 = np.concatenate([logs.real, logs.imag, extra0])
    if x0.size == 0:
        return block_matrix(eig, kinds), ct, t, extra0
    lo = np.concatenate([np.full(npr, -np.pi), np.full(npr, 1e-4), np.full(ne, -np.inf)])
    hi = np.concatenate([np.full(npr, -1e-7), np.full(npr, np.pi - 1e-4), np.full(ne, np.inf)])
    x0 = np.clip(x0, np.maximum(lo, -1e300) + 1e-12, np.minimum(hi, 1e300) - 1e-12)
    rot = np.array([[0.0, 1.0], [-1.0, 0.0]])
    memo: dict = {}

    def model(x: np.ndarray) -> np.ndarray:
        e = eig.copy()
        e[pairs] = np.exp(x[:npr] + 1j * x[npr : 2 * npr])
        return block_matrix(e, kinds)

    def evaluate(x: np.ndarray):
        key = x.tobytes()
        if key not in memo:
            memo.clear()
            dyn = LinearDynamics.build(model(x), ct, n_s)
            v, dr = signals(x[2 * npr :])
            des = _design(dyn, y, v, rows, additive, dr)
            memo[key] = (dyn, v, dr, des)
        return memo[key]

    def resid(x: np.ndarray) -> np.ndarray:
        *_, des = evaluate(x)
        return des.target - des.matrix @ des.sol

    def jac(x: np.ndarray) -> np.ndarray:
        dyn, v, dr, des = evaluate(x)
        oe = des.fit
        w = des.weights
        q, r = linalg.qr(des.matrix, mode="economic", check_finite=False)
        dg = np.abs(np.diag(r))
        q = q[:, dg > 1e-10 * max(dg.max(initial=0.0), 1e-300)]
        p_idx = np.arange(dyn.kernel.shape[0], dtype=float)[:, None, None]
        cols = []
        for which in ("sigma", "omega"):
            for k in pairs:
                blk = slice(offsets[k], offsets[k] + 2)
                g = p_idx * dyn.kernel[:, :, blk]  # (P, l, 2): p C_k A_k^p
                if which == "omega":
                    g = g @ rot
                sub = LinearDynamics(dyn.A[blk, blk], dyn.C[:, blk], g)
                dy = sub.simulate(oe.B[blk], v, oe.x0[blk])
                cols.append(dy[rows].reshape(-1, y.shape[1]) * w)
        for j in range(ne):
            step = 1e-6 * max(1.0, abs(x[2 * npr + j]))
            xe = x[2 * npr :].copy()
            xe[j] += step
            v2, d2 = signals(xe)
            dy = dyn.simulate(oe.B, (v2 - v) / step) + ((d2 - dr) / step) @ oe.D.T
            cols.append(dy[rows] * w)
        out = np.column_stack([col.ravel() for col in cols])
        return -(out - q @ (q.T @ out))

    sol = least_squares(
        resid, x0, jac=jac, bounds=(lo, hi), max_nfev=max_nfev, x_scale="jac", method="trf"
    )
    return model(sol.x), ct, t, sol.x[2 * npr :]

