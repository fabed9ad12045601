"""Modal extraction: natural frequency, damping, shape, participation and uncertainty.

Each complex-conjugate pair of discrete poles mu of A_d gives one mode with continuous pole
s = fs ln(mu), frequency |s| / 2 pi [Hz] and damping ratio -Re(s) / |s| (the modal form (3)).
Real poles (and poles on the negative real axis) are reported apart.

Uncertainty (delta method): the (A4) least-squares estimate of A_d has covariance
cov(vec A_d) = Q_w (x) (X X')^{-1} (times sum w^2 / sum w under exponential forgetting); a
first-order perturbation of each eigenvalue, d mu = w' dA v (left/right eigenvectors, w' v = 1),
is mapped through s = fs ln(mu) to frequency and damping. It ignores the error of the estimated
states, so it is a lower bound; :class:`~sysid_node.core.tracking.ModeTracker` also reports the
empirical spread over successive realizations (the paper's Table 1 uses empirical spreads).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field

import numpy as np


@dataclass
class ModalParameters:
    """One structural mode (a complex pole pair)."""

    frequency_hz: float
    damping_ratio: float
    frequency_std_hz: float = float("nan")
    damping_std: float = float("nan")
    amplitude: float = float("nan")  # RMS contribution to the outputs, output units
    shape: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=complex))
    pole_discrete: complex = complex("nan")
    pole_continuous: complex = complex("nan")

    def to_dict(self) -> dict:
        """JSON-friendly dict (complex numbers as [re, im])."""
        d = asdict(self)
        d["shape"] = [[float(z.real), float(z.imag)] for z in np.asarray(self.shape)]
        for k in ("pole_discrete", "pole_continuous"):
            d[k] = [float(np.real(d[k])), float(np.imag(d[k]))]
        return d

    @classmethod
    def from_dict(cls, d: dict) -> ModalParameters:
        d = dict(d)
        d["shape"] = np.array([complex(a, b) for a, b in d.get("shape", [])], dtype=complex)
        for k in ("pole_discrete", "pole_continuous"):
            if k in d:
                d[k] = complex(*d[k])
        return cls(**d)


def mac(a: np.ndarray, b: np.ndarray) -> float:
    """Modal assurance criterion |a^H b|^2 / (|a|^2 |b|^2) in [0, 1]."""
    den = float(np.vdot(a, a).real * np.vdot(b, b).real)
    return float(abs(np.vdot(a, b)) ** 2 / den) if den > 0 else 0.0


def extract_modes(
    a: np.ndarray,
    c: np.ndarray,
    fs: float,
    *,
    b_all: np.ndarray | None = None,
    drive_cov: np.ndarray | None = None,
    a_cov_rows: np.ndarray | None = None,
    a_cov_cols: np.ndarray | None = None,
    band: tuple[float, float] | None = None,
    damping_bounds: tuple[float, float] | None = (0.0, 0.5),
    max_modes: int | None = None,
) -> tuple[list[ModalParameters], np.ndarray]:
    """Modes of the discrete model (A, C) and its real continuous poles [1/s].

    ``b_all`` (n, q) with ``drive_cov`` (q, q) is the white drive of the states (e.g. [B K] with
    blockdiag(cov u, cov e)) used for the amplitude; ``a_cov_rows`` / ``a_cov_cols`` are the
    Kronecker factors of cov(vec A) for the delta method. Spurious-mode rejection: modes outside
    ``band`` [Hz] or ``damping_bounds`` are dropped; at most ``max_modes`` are kept (largest
    amplitude first, or lightest damping when amplitudes are unknown), sorted by frequency.
    """
    n = a.shape[0]
    if n == 0:
        return [], np.zeros(0)
    mu, v = np.linalg.eig(a)
    try:
        w = np.linalg.inv(v)  # rows: left eigenvectors with w v = I
    except np.linalg.LinAlgError:
        w = np.linalg.pinv(v)
    with np.errstate(divide="ignore", invalid="ignore"):
        s_c = np.log(mu.astype(complex)) * fs
    tol = 1e-7
    is_real = (np.abs(mu.imag) <= tol * np.maximum(1.0, np.abs(mu))) | ~np.isfinite(s_c)
    real_poles = np.sort(s_c[is_real & np.isfinite(s_c)].real)
    modes: list[ModalParameters] = []
    index: list[int] = []
    phi = c @ v  # (l, n) complex shapes
    for k in np.flatnonzero((mu.imag > 0) & ~is_real):
        s = s_c[k]
        rad = abs(s)
        f = rad / (2 * np.pi)
        zeta = -s.real / rad
        amp = float("nan")
        if b_all is not None and drive_cov is not None and b_all.shape[1]:
            bk = w[k] @ b_all
            var_z = float(np.real(bk @ drive_cov @ bk.conj())) / max(1.0 - abs(mu[k]) ** 2, 1e-12)
            amp = float(np.sqrt(2.0 * max(var_z, 0.0)) * np.linalg.norm(phi[:, k]))
        shape = phi[:, k].copy()
        big = shape[np.argmax(np.abs(shape))]
        if abs(big) > 0:
            shape = shape / big
        modes.append(
            ModalParameters(
                frequency_hz=float(f),
                damping_ratio=float(zeta),
                amplitude=amp,
                shape=shape,
                pole_discrete=complex(mu[k]),
                pole_continuous=complex(s),
            )
        )
        index.append(k)
    selected = select_modes(modes, band, damping_bounds, max_modes)
    if a_cov_rows is not None and a_cov_cols is not None:
        for md in selected:
            k = index[next(j for j, x in enumerate(modes) if x is md)]
            md.frequency_std_hz, md.damping_std = _delta_std(
                mu[k], w[k], v[:, k], a_cov_rows, a_cov_cols, fs
            )
    return selected, real_poles


def select_modes(
    modes: list[ModalParameters],
    band: tuple[float, float] | None,
    damping_bounds: tuple[float, float] | None,
    max_modes: int | None,
) -> list[ModalParameters]:
    """Spurious-mode rejection by band, damping bounds and an upper bound on the mode count."""
    out = [
        md
        for md in modes
        if (band is None or band[0] <= md.frequency_hz <= band[1])
        and (damping_bounds is None or damping_bounds[0] <= md.damping_ratio <= damping_bounds[1])
    ]
    if max_modes is not None and len(out) > max_modes:
        if all(np.isfinite(md.amplitude) for md in out):
            out = sorted(out, key=lambda md: -md.amplitude)[:max_modes]
        else:
            out = sorted(out, key=lambda md: md.damping_ratio)[:max_modes]
    return sorted(out, key=lambda md: md.frequency_hz)


def _delta_std(
    mu: complex, wk: np.ndarray, vk: np.ndarray, qw: np.ndarray, pc: np.ndarray, fs: float
) -> tuple[float, float]:
    """First-order (delta-method) standard deviations of frequency [Hz] and damping ratio."""
    g = np.outer(wk, vk)  # d mu = sum_ij g_ij dA_ij
    gr, gi = g.real, g.imag
    c_rr = float(np.sum((gr.T @ qw @ gr) * pc))
    c_ii = float(np.sum((gi.T @ qw @ gi) * pc))
    c_ri = float(np.sum((gr.T @ qw @ gi) * pc))
    cov_mu = np.array([[c_rr, c_ri], [c_ri, c_ii]])
    cf = fs / mu  # ds = (fs / mu) d mu
    jm = np.array([[cf.real, -cf.imag], [cf.imag, cf.real]])
    s = fs * np.log(mu)
    sig, om = s.real, s.imag
    rad = abs(s)
    jf = np.array([sig, om]) / (2 * np.pi * rad)
    jz = np.array([-(om**2), sig * om]) / rad**3
    cov_s = jm @ cov_mu @ jm.T
    f_var = float(jf @ cov_s @ jf.T)
    z_var = float(jz @ cov_s @ jz.T)
    return float(np.sqrt(max(f_var, 0.0))), float(np.sqrt(max(z_var, 0.0)))
