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
    """One structural mode (a complex pole pair).

    ``amplitude`` is the mode's RMS contribution to the outputs (output units). ``contribution``
    and ``snr`` are scale-free: the mode's output variance over the innovation (noise) variance,
    summed over the output channels, and its spectral peak over the innovation's spectral level
    (``contribution x fs / (2 pi zeta f)``; a mode whose peak does not rise above the noise floor
    has ``snr < 1``). ``mpc`` is the modal phase collinearity of the shape (1 = real shape; NaN
    for one output). ``stable`` says whether the mode passed the spurious-mode tests of the
    realization that produced it (``spurious.py``; True when none were run) and
    ``stable_orders`` in how many of the check orders it reappeared (-1 = not checked);
    ``overfit_only``: it failed the overfit-level test alone (``spurious.py``, test 3), which
    :class:`~sysid_node.core.spurious.Persistence` may lift.
    """

    frequency_hz: float
    damping_ratio: float
    frequency_std_hz: float = float("nan")
    damping_std: float = float("nan")
    amplitude: float = float("nan")  # RMS contribution to the outputs, output units
    shape: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=complex))
    pole_discrete: complex = complex("nan")
    pole_continuous: complex = complex("nan")
    contribution: float = float("nan")
    snr: float = float("nan")
    mpc: float = float("nan")
    stable: bool = True
    stable_orders: int = -1
    overfit_only: bool = False

    def to_dict(self) -> dict:
        """JSON-friendly dict (complex numbers as [re, im])."""
        d = asdict(self)
        d["shape"] = [[float(z.real), float(z.imag)] for z in np.asarray(self.shape)]
        for k in ("pole_discrete", "pole_continuous"):
            d[k] = [float(np.real(d[k])), float(np.imag(d[k]))]
        for k in ("stable", "overfit_only"):
            d[k] = bool(d[k])
        return d

    @classmethod
    def from_dict(cls, d: dict) -> ModalParameters:
        d = dict(d)
        d["shape"] = np.array([complex(a, b) for a, b in d.get("shape", [])], dtype=complex)
        for k in ("pole_discrete", "pole_continuous"):
            if k in d:
                d[k] = complex(*d[k])
        return cls(**d)

    @property
    def rank_key(self) -> float:
        """Ranking by contribution (scale-free), else amplitude, else light damping first."""
        for x in (self.contribution, self.amplitude):
            if np.isfinite(x):
                return float(x)
        return -abs(self.damping_ratio)


def mac(a: np.ndarray, b: np.ndarray) -> float:
    """Modal assurance criterion |a^H b|^2 / (|a|^2 |b|^2) in [0, 1]."""
    den = float(np.vdot(a, a).real * np.vdot(b, b).real)
    return float(abs(np.vdot(a, b)) ** 2 / den) if den > 0 else 0.0


def mac_matrix(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """:func:`mac` of every row of ``a`` (K, l) with every row of ``b`` (J, l): (K, J)."""
    den = np.outer(np.sum(np.abs(a) ** 2, axis=1), np.sum(np.abs(b) ** 2, axis=1))
    num = np.abs(a.conj() @ b.T) ** 2
    return np.divide(num, den, out=np.zeros_like(num), where=den > 0)


def mpc(shapes: np.ndarray) -> np.ndarray:
    """Modal phase collinearity of each column of ``shapes`` (l, K): ((s1 - s2) / (s1 + s2))^2
    with s1, s2 the eigenvalues of the 2 x 2 second moment of (Re, Im); 1 for a real (normal
    mode) shape, 0 for a circular one; NaN for a single channel."""
    shapes = np.asarray(shapes)
    if shapes.shape[0] < 2:
        return np.full(shapes.shape[1], np.nan)
    re, im = shapes.real, shapes.imag
    sxx, syy, sxy = (re * re).sum(0), (im * im).sum(0), (re * im).sum(0)
    tot = sxx + syy
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(tot > 0, ((sxx - syy) ** 2 + 4 * sxy**2) / tot**2, np.nan)


def peak_over_floor(
    contribution: np.ndarray, zeta: np.ndarray, freq_hz: np.ndarray, fs: float
) -> np.ndarray:
    """A mode's spectral peak over the innovation's level, ``contribution x fs / (2 pi zeta f)``
    (``ModalParameters.snr``): a resonance's peak is its variance over its half-power
    bandwidth 2 zeta f, the white floor's level its variance over fs / 2."""
    return contribution * fs / (2 * np.pi * np.maximum(np.abs(zeta), 1e-6) * freq_hz)


def extract_modes(
    a: np.ndarray,
    c: np.ndarray,
    fs: float,
    *,
    b_all: np.ndarray | None = None,
    drive_cov: np.ndarray | None = None,
    a_cov_rows: np.ndarray | None = None,
    a_cov_cols: np.ndarray | None = None,
    noise_cov: np.ndarray | None = None,
    band: tuple[float, float] | None = None,
    damping_bounds: tuple[float, float] | None = (0.0, 0.5),
    max_modes: int | None = None,
    reflect_unstable: bool = False,
) -> tuple[list[ModalParameters], np.ndarray]:
    """Modes of the discrete model (A, C) and its real continuous poles [1/s].

    ``b_all`` (n, q) with ``drive_cov`` (q, q) is the white drive of the states (e.g. [B K] with
    blockdiag(cov u, cov e)): each mode's variance is the one it would have driven alone,
    w_k b_all drive_cov b_all' w_k^H / (1 - |mu_k|^2) (not the marginal variance of its modal
    coordinate, which cross-correlated noise poles inflate); ``noise_cov`` (l, l) the innovation
    covariance (output units) for ``contribution`` and ``snr``; ``a_cov_rows`` /
    ``a_cov_cols`` are the Kronecker factors of cov(vec A) for the delta method. Modes outside
    ``band`` [Hz] or ``damping_bounds`` are dropped; at most ``max_modes`` are kept (see
    :func:`select_modes`), sorted by frequency. Vectorised over the modes.
    ``reflect_unstable`` (needs the delta method's factors; only when ``damping_bounds`` exclude
    negative damping): a pole pair just outside the unit circle whose damping is within
    ``REFLECT_Z`` standard deviations of zero is a lightly damped mode whose young estimate
    scattered across the circle: it is reported as its reflection 1 / conj(mu) (same
    frequency, damping |zeta|; :func:`_reflect`).
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
    sel = np.flatnonzero((mu.imag > 0) & ~is_real)
    if sel.size == 0:
        return [], real_poles
    f_std = np.full(sel.size, np.nan)
    z_std = np.full(sel.size, np.nan)
    if a_cov_rows is not None and a_cov_cols is not None:
        f_std, z_std = _delta_std(mu[sel], w[sel], v[:, sel].T, a_cov_rows, a_cov_cols, fs)
    mu_k = mu[sel]
    if reflect_unstable and damping_bounds is not None and damping_bounds[0] >= 0.0:
        mu_k = _reflect(mu_k, z_std)  # only what the bounds would drop for its sign
    s = np.log(mu_k.astype(complex)) * fs
    rad = np.abs(s)
    freq = rad / (2 * np.pi)
    zeta = -s.real / rad
    phi = c @ v[:, sel]  # (l, K) complex shapes
    amp = np.full(sel.size, np.nan)
    contrib = np.full(sel.size, np.nan)
    snr = np.full(sel.size, np.nan)
    if b_all is not None and drive_cov is not None and b_all.shape[1]:
        bm = w[sel] @ b_all  # (K, q): modal drive
        var_z = np.maximum(np.real(((bm @ drive_cov) * bm.conj()).sum(axis=1)), 0.0)
        var_z = var_z / np.maximum(1.0 - np.abs(mu_k) ** 2, 1e-12)
        var_c = 2.0 * var_z[None, :] * np.abs(phi) ** 2  # (l, K): per-channel variance
        amp = np.sqrt(var_c.sum(axis=0))
        if noise_cov is not None:
            floor = np.maximum(np.real(np.diag(noise_cov)), 1e-300)
            contrib = (var_c / floor[:, None]).sum(axis=0)
            snr = peak_over_floor(contrib, zeta, freq, fs)
    big = phi[np.argmax(np.abs(phi), axis=0), np.arange(sel.size)]
    shapes = phi / np.where(np.abs(big) > 0, big, 1.0)[None, :]
    mpcs = mpc(shapes)
    modes = [
        ModalParameters(
            frequency_hz=float(freq[k]),
            damping_ratio=float(zeta[k]),
            frequency_std_hz=float(f_std[k]),
            damping_std=float(z_std[k]),
            amplitude=float(amp[k]),
            shape=shapes[:, k].copy(),
            pole_discrete=complex(mu_k[k]),
            pole_continuous=complex(s[k]),
            contribution=float(contrib[k]),
            snr=float(snr[k]),
            mpc=float(mpcs[k]),
        )
        for k in range(sel.size)
    ]
    return select_modes(modes, band, damping_bounds, max_modes), real_poles


#: Standard deviations (delta method) within which a pole's negative damping is taken for scatter
#: of a lightly damped mode across the unit circle (:func:`_reflect`): the 99 % quantile.
REFLECT_Z = 2.5758293035489004


def _reflect(mu: np.ndarray, z_std: np.ndarray) -> np.ndarray:
    """The poles ``mu`` with those outside the unit circle whose damping is within REFLECT_Z
    ``z_std`` of zero replaced by their reflections 1 / conj(mu): in output-only data over a
    short memory a 0.2-0.6 %-damped mode comes out at its frequency within 0.5 % but with a
    damping of -0.2 to -2 % in half or more of the realizations (random suite draws 16 and 30),
    and the damping bounds dropped it. A pole farther out (or without a standard deviation)
    stays as it is (and out of the bounds)."""
    r = np.abs(mu)
    with np.errstate(divide="ignore", invalid="ignore"):
        s = np.log(mu.astype(complex))
        zeta = -s.real / np.abs(s)
    near = (r > 1.0) & np.isfinite(z_std) & (-zeta <= REFLECT_Z * z_std)
    return np.where(near, mu / np.where(near, r**2, 1.0), mu)


def in_band(
    md: ModalParameters,
    band: tuple[float, float] | None,
    damping_bounds: tuple[float, float] | None,
) -> bool:
    """The mode lies in ``band`` [Hz] and within ``damping_bounds``."""
    return (band is None or band[0] <= md.frequency_hz <= band[1]) and (
        damping_bounds is None or damping_bounds[0] <= md.damping_ratio <= damping_bounds[1]
    )


def select_modes(
    modes: list[ModalParameters],
    band: tuple[float, float] | None,
    damping_bounds: tuple[float, float] | None,
    max_modes: int | None,
) -> list[ModalParameters]:
    """Modes in the band and damping bounds; at most ``max_modes``, the stable ones first, then
    by contribution (:attr:`ModalParameters.rank_key`); sorted by frequency."""
    out = [md for md in modes if in_band(md, band, damping_bounds)]
    if max_modes is not None and len(out) > max_modes:
        out = sorted(out, key=lambda md: (not md.stable, -md.rank_key))[:max_modes]
    return sorted(out, key=lambda md: md.frequency_hz)


def _delta_std(
    mu: np.ndarray, wl: np.ndarray, vr: np.ndarray, qw: np.ndarray, pc: np.ndarray, fs: float
) -> tuple[np.ndarray, np.ndarray]:
    """First-order (delta-method) standard deviations of frequency [Hz] and damping ratio of
    each eigenvalue ``mu[k]`` with left/right eigenvectors ``wl[k]``, ``vr[k]`` (w v = 1).

    d mu = w' dA v = sum_ij g_ij dA_ij with g = w v' (rank one), and cov(dA_ij, dA_i'j') =
    qw_ii' pc_jj', so every second moment of (Re d mu, Im d mu) is a sum of products of two
    quadratic forms (x' qw x2)(y' pc y2) over Re/Im parts of w and v; vectorised over modes.
    """
    a, c = wl.real, wl.imag
    b, d = vr.real, vr.imag
    qa, qc = a @ qw, c @ qw  # quadratic forms x1[k]' m x2[k] for every k as row sums (BLAS)
    pb, pd = b @ pc, d @ pc
    aa, ac, cc = (qa * a).sum(1), (qa * c).sum(1), (qc * c).sum(1)
    bb, bd, dd = (pb * b).sum(1), (pb * d).sum(1), (pd * d).sum(1)
    # Re g = a b' - c d', Im g = a d' + c b'; sum (x1 y1')(x2 y2') qw pc = (x1'qw x2)(y1'pc y2)
    c_rr = aa * bb - 2 * ac * bd + cc * dd
    c_ii = aa * dd + 2 * ac * bd + cc * bb
    c_ri = aa * bd + ac * bb - ac * dd - cc * bd
    cov_mu = np.stack([np.stack([c_rr, c_ri], -1), np.stack([c_ri, c_ii], -1)], -2)
    cf = fs / mu  # ds = (fs / mu) d mu
    jm = np.stack([np.stack([cf.real, -cf.imag], -1), np.stack([cf.imag, cf.real], -1)], -2)
    s = fs * np.log(mu)
    sig, om = s.real, s.imag
    rad = np.abs(s)
    jf = np.stack([sig, om], -1) / (2 * np.pi * rad)[:, None]
    jz = np.stack([-(om**2), sig * om], -1) / (rad**3)[:, None]
    cov_s = jm @ cov_mu @ np.swapaxes(jm, -1, -2)
    f_var = (jf * (cov_s @ jf[:, :, None])[:, :, 0]).sum(axis=1)
    z_var = (jz * (cov_s @ jz[:, :, None])[:, :, 0]).sum(axis=1)
    return np.sqrt(np.maximum(f_var, 0.0)), np.sqrt(np.maximum(z_var, 0.0))
