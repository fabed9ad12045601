"""Residual analysis: fit, whiteness, residual-input cross-correlation, spectrum and coherence.

Standard model-validation tests (Ljung, *System Identification*, ch. 16) with their bounds:

* NRMSE fit per channel, ``100 (1 - ||y - yhat|| / ||y - mean(y)||)``;
* whiteness: normalised autocorrelation r(k), k = 1..L, against the 99 % bound 2.576 / sqrt(N)
  and the Ljung-Box portmanteau Q = N (N + 2) sum r(k)^2 / (N - k) ~ chi2(L);
* residual-input cross-correlation R_eu(tau) = E[e_t u_{t - tau}], tau = -L..L: positive lags
  are past inputs (a wrong or delayed input path), negative lags future inputs (feedback);
  a portmanteau N sum R^2 ~ chi2 on each side (the input is prewhitened by an AR fit first);
* residual spectrum (Welch) against its noise floor (running median) with the chi-square bound of
  the Welch estimate, and the magnitude-squared coherence with each input and its 99 % bound.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from scipy import linalg, signal, stats

Z99 = 2.5758293035489  # two-sided 99 % normal quantile
ALPHA = 0.01


def nrmse_fit(y: np.ndarray, yhat: np.ndarray) -> np.ndarray:
    """NRMSE fit [%] per channel: 100 (1 - ||y - yhat|| / ||y - mean(y)||)."""
    y, yhat = np.atleast_2d(y.T).T, np.atleast_2d(yhat.T).T
    num = np.linalg.norm(y - yhat, axis=0)
    den = np.linalg.norm(y - y.mean(axis=0), axis=0)
    return 100.0 * (1.0 - num / np.where(den > 0, den, np.nan))


#: Relative rank threshold of :func:`lstsq` on unit-norm columns: above the rounding of a
#: product of ~1e4 rows (n eps ~ 2e-12), far under any measured component (1e-10 of a signal's
#: amplitude is below a 24-bit converter's step, 6e-8).
RCOND = 1e-10


def lstsq(a: np.ndarray, b: np.ndarray, rcond: float = RCOND) -> np.ndarray:
    """Least-squares solution by pivoted QR (LAPACK gelsy through scipy; numpy's SVD-based
    lstsq was 100x slower on some regression matrices here), the minimum-norm one of rank
    ``rcond`` on unit-norm columns. A rank-deficient design (lags of a noise-free multisine:
    2 lags per line span the rest) then has a numerical rank that rounding does not decide:
    at gelsy's default (eps) the kept null directions took arbitrary coefficients, and the
    feedback score built on them moved by up to 50 points with a 1e-15 change of the input."""
    scale = np.linalg.norm(a, axis=0)
    scale = np.where(scale > 0, scale, 1.0)
    x = linalg.lstsq(a / scale, b, cond=rcond, lapack_driver="gelsy", check_finite=False)[0]
    return x / (scale[:, None] if x.ndim == 2 else scale)


def rms(x: np.ndarray) -> np.ndarray:
    """RMS per column."""
    return np.sqrt(np.mean(np.square(x), axis=0))


def _xcorr_fft(a: np.ndarray, b: np.ndarray, max_lag: int) -> np.ndarray:
    """Normalised cross-correlation c(tau) = sum_t a_t b_{t - tau} / (N sa sb), tau = -L..L."""
    n = a.size
    a = a - a.mean()
    b = b - b.mean()
    nfft = 1 << int(np.ceil(np.log2(2 * n)))
    full = np.fft.irfft(np.fft.rfft(a, nfft) * np.conj(np.fft.rfft(b, nfft)), nfft)
    lags = np.arange(-max_lag, max_lag + 1)
    c = full[lags % nfft]
    den = n * a.std() * b.std()
    return c / den if den > 0 else np.zeros_like(c)


@dataclass
class WhitenessTest:
    """Autocorrelation of one residual channel, its 99 % bound and the Ljung-Box test."""

    lags: np.ndarray
    r: np.ndarray
    bound: float
    q: float
    p_value: float

    @property
    def passed(self) -> bool:
        return bool(self.p_value >= ALPHA)

    @property
    def exceedances(self) -> int:
        return int(np.sum(np.abs(self.r) > self.bound))


def whiteness(e: np.ndarray, max_lag: int = 20) -> WhitenessTest:
    """Residual autocorrelation r(1..L) with the 99 % bound and the Ljung-Box statistic."""
    e = np.asarray(e, float).ravel()
    n = e.size
    r = _xcorr_fft(e, e, max_lag)[max_lag + 1 :]
    k = np.arange(1, max_lag + 1)
    q = float(n * (n + 2) * np.sum(r**2 / (n - k)))
    return WhitenessTest(k, r, Z99 / np.sqrt(n), q, float(stats.chi2.sf(q, max_lag)))


def prewhiten(u: np.ndarray, order: int = 10) -> tuple[np.ndarray, np.ndarray]:
    """AR(order) least-squares fit of u; returns (innovations of u, AR coefficients)."""
    u = np.asarray(u, float).ravel()
    u = u - u.mean()
    order = min(order, max(1, u.size // 10))
    reg = np.lib.stride_tricks.sliding_window_view(u, order)[:-1][:, ::-1]
    a = lstsq(reg, u[order:])
    w = u.copy()
    w[order:] = u[order:] - reg @ a
    w[:order] = 0.0
    return w, a


@dataclass
class CrossCorrelationTest:
    """R_eu(tau) of one residual/input pair (input prewhitened), bound and one-sided tests."""

    lags: np.ndarray
    r: np.ndarray
    bound: float
    p_past: float  # portmanteau over tau = 0..L (past and present inputs)
    p_future: float  # portmanteau over tau = -L..-1 (future inputs: feedback)

    @property
    def passed(self) -> bool:
        return bool(min(self.p_past, self.p_future) >= ALPHA / 2)

    def peak(self, side: str) -> tuple[int, float]:
        """(lag, value) of the largest |R| on 'past' (tau >= 0) or 'future' (tau < 0) lags."""
        sel = self.lags >= 0 if side == "past" else self.lags < 0
        k = int(np.argmax(np.abs(self.r[sel])))
        return int(self.lags[sel][k]), float(self.r[sel][k])


def cross_correlation(
    e: np.ndarray, u: np.ndarray, max_lag: int = 20, ar_order: int = 10
) -> CrossCorrelationTest:
    """R_eu(tau) = corr(e_t, w_{t - tau}), w the prewhitened input, with 99 % bounds."""
    e = np.asarray(e, float).ravel()
    w, a = prewhiten(u, ar_order)
    # filter e with the same whitening filter so that R_eu is the impulse-response shape
    ef = signal.lfilter(np.concatenate([[1.0], -a]), [1.0], e - e.mean())
    k0 = a.size
    r = _xcorr_fft(ef[k0:], w[k0:], max_lag)
    n = e.size - k0
    lags = np.arange(-max_lag, max_lag + 1)
    q_past = float(n * np.sum(r[lags >= 0] ** 2))
    q_fut = float(n * np.sum(r[lags < 0] ** 2))
    return CrossCorrelationTest(
        lags,
        r,
        Z99 / np.sqrt(n),
        float(stats.chi2.sf(q_past, max_lag + 1)),
        float(stats.chi2.sf(q_fut, max_lag)),
    )


def whitened(e: np.ndarray, *others: np.ndarray, order: int = 10) -> list[np.ndarray]:
    """e and ``others`` filtered by the AR(order) whitening filter of e (prewhitening: a
    correlation test between a coloured error and a regressor then has its white-noise null
    distribution). The first ``order`` samples are dropped."""
    _, a = prewhiten(e, order)
    filt = np.concatenate([[1.0], -a])
    out = [signal.lfilter(filt, [1.0], np.asarray(x, float) - np.mean(x))[a.size :] for x in
           (e, *others)]
    return out


def bartlett_factor(a: np.ndarray, b: np.ndarray, lags: int = 50) -> float:
    """Variance inflation of a sample cross-correlation of two independent autocorrelated
    series over the white-noise value 1/N (Bartlett): 1 + 2 sum_k rho_a(k) rho_b(k), at
    least 1 (what prewhitening leaves of the colour)."""
    lags = min(lags, a.size // 4)
    if lags < 1:
        return 1.0
    ra = _xcorr_fft(a, a, lags)[lags + 1 :]
    rb = _xcorr_fft(b, b, lags)[lags + 1 :]
    return float(max(1.0, 1.0 + 2.0 * np.sum(ra * rb)))


def higher_order_correlation(
    e: np.ndarray, z: np.ndarray, max_lag: int = 10, colored: bool = False
) -> tuple[np.ndarray, float, float]:
    """Billings-Voon type test corr(e_t, z'_{t - k}), k = 1..L, z' the cubic Hermite term.

    ``z`` is a measured signal (an output channel); He3(z / s) = (z / s)^3 - 3 z / s is
    uncorrelated with z itself for a Gaussian z, so a significant correlation of the one-step
    residual with its past values points to a missing cubic term. ``colored``: e is a coloured
    error (a free run's), both are prewhitened by e's AR filter first, lags 0..L then (the free
    run's error answers the force at once). Returns (r, bound, p-value).
    """
    e = np.asarray(e, float).ravel()
    z = np.asarray(z, float).ravel()
    s = z.std() if z.std() > 0 else 1.0
    zn = (z - z.mean()) / s
    he3 = zn**3 - 3.0 * zn
    # remove the linear part left by a non-Gaussian z
    he3 = he3 - zn * (he3 @ zn) / (zn @ zn)
    if colored:
        e, he3 = whitened(e, he3)
        c = _xcorr_fft(e, he3, max_lag)[max_lag:]
        n = e.size
        q = float(n * np.sum(c**2)) / bartlett_factor(e, he3)
        return c, Z99 / np.sqrt(n), float(stats.chi2.sf(q, max_lag + 1))
    r = _xcorr_fft(e, he3, max_lag)[max_lag + 1 :]
    n = e.size
    q = float(n * np.sum(r**2))
    return r, Z99 / np.sqrt(n), float(stats.chi2.sf(q, max_lag))


def error_windows(e: np.ndarray, fs: float, window_s: float | None = None) -> tuple:
    """RMS of the residual per time window: (window start times [s] from 0, rms (W, l))."""
    e = np.atleast_2d(np.asarray(e, float).T).T
    n = e.shape[0]
    w = int(round((window_s or max(n / fs / 20, 1.0 / fs)) * fs))
    w = max(1, min(w, n))
    k = n // w
    blocks = e[: k * w].reshape(k, w, -1)
    return np.arange(k) * w / fs, np.sqrt(np.mean(blocks**2, axis=1))


@dataclass
class Spectrum:
    """Welch PSD of the residual, its (white) noise floor and the 99.9 % chi-square bound."""

    f: np.ndarray
    psd: np.ndarray  # (F, l)
    floor: np.ndarray  # (F, l)
    bound_factor: float  # psd / floor above this is a significant narrow-band excess
    resolution_hz: float


def welch_nperseg(n: int, fs: float, min_res_hz: float | None = None) -> int:
    """Segment length: about 8 averages, at most 1024 samples."""
    seg = 1 << int(np.floor(np.log2(max(n // 4, 16))))
    return int(min(seg, 1024, n))


def residual_spectrum(e: np.ndarray, fs: float, nperseg: int | None = None) -> Spectrum:
    """Welch PSD (Hann, 50 % overlap, zero-padded x4) and the white-residual noise floor."""
    e = np.atleast_2d(np.asarray(e, float).T).T
    n = e.shape[0]
    nper = nperseg or welch_nperseg(n, fs)
    f, p = signal.welch(e, fs=fs, nperseg=nper, nfft=4 * nper, axis=0, detrend="constant")
    # floor: the level of a white residual (what a correct innovation model leaves), robust to
    # peaks: the median over frequency; the median of a chi2(2)/2 variable is ln 2 times its mean
    floor = np.broadcast_to(np.median(p, axis=0, keepdims=True) / np.log(2.0), p.shape).copy()
    k_avg = max(1, int(2 * n / nper) - 1)  # overlapping Hann segments
    dof = 2 * k_avg
    bound = float(stats.chi2.ppf(0.999, dof) / dof)
    return Spectrum(f, p, floor, bound, fs / nper)


def _running_median(x: np.ndarray, width: int) -> np.ndarray:
    pad = width // 2
    xp = np.pad(x, pad, mode="reflect")
    win = np.lib.stride_tricks.sliding_window_view(xp, width)
    return np.median(win, axis=1)


@dataclass
class Peak:
    """A narrow-band excess of the residual spectrum."""

    channel: int
    frequency_hz: float
    ratio: float  # peak psd / floor
    damping: float  # from the half-power width, NaN if unresolved
    band_power: float  # residual power within the half-power band


def spectral_peaks(
    spec: Spectrum, fmin: float = 0.0, margin: float = 2.0, max_peaks: int = 6
) -> list[Peak]:
    """Peaks with psd / floor above ``margin`` x the 99.9 % bound, strongest first."""
    out: list[Peak] = []
    df = spec.f[1] - spec.f[0]
    for c in range(spec.psd.shape[1]):
        p, fl = spec.psd[:, c], spec.floor[:, c]
        ratio = p / np.maximum(fl, 1e-300)
        idx, _ = signal.find_peaks(p)
        idx = idx[
            (spec.f[idx] > max(fmin, 2 * spec.resolution_hz))
            & (ratio[idx] > margin * spec.bound_factor)
        ]
        for i in idx:
            # parabolic interpolation of log psd around the bin
            if 0 < i < p.size - 1:
                a, b, g = np.log(p[i - 1 : i + 2])
                den = a - 2 * b + g
                d = 0.5 * (a - g) / den if den != 0 else 0.0
            else:
                d = 0.0
            fp = spec.f[i] + d * df
            half = p[i] / 2
            lo = i
            while lo > 0 and p[lo] > half:
                lo -= 1
            hi = i
            while hi < p.size - 1 and p[hi] > half:
                hi += 1
            width = (hi - lo) * df
            zeta = width / (2 * fp) if width > 1.5 * spec.resolution_hz else float("nan")
            out.append(
                Peak(c, float(fp), float(ratio[i]), float(zeta), float(np.sum(p[lo : hi + 1]) * df))
            )
    out.sort(key=lambda pk: -pk.ratio)
    return out[:max_peaks]


def coherence(e: np.ndarray, u: np.ndarray, fs: float, nperseg: int | None = None) -> tuple:
    """Magnitude-squared coherence of residual channel e with input u and its 99 % bound.

    Under no coherence with K independent segments, P(C > c) = (1 - c)^(K - 1).
    """
    e, u = np.asarray(e, float).ravel(), np.asarray(u, float).ravel()
    nper = nperseg or welch_nperseg(e.size, fs)
    f, c = signal.coherence(e, u, fs=fs, nperseg=nper)
    k = max(2, int(2 * e.size / nper) - 1)
    bound = 1.0 - ALPHA ** (1.0 / (k - 1))
    return f, c, float(bound)


def line_fraction(e: np.ndarray, fs: float, f0: float, rel_band: float = 0.1) -> tuple:
    """How much of the residual power near f0 one fixed sinusoid explains.

    The sinusoid frequency is refined on a fine grid around f0; a line (periodic disturbance)
    gives a fraction near 1, a noise- or input-driven mode a small one. Returns
    (fraction, refined frequency [Hz], amplitude).
    """
    e = np.asarray(e, float).ravel()
    e = e - e.mean()
    n = e.size
    t = np.arange(n) / fs
    grid = f0 * (1 + np.linspace(-0.03, 0.03, 61))
    ph = np.exp(-2j * np.pi * np.outer(grid, t))
    amp = np.abs(ph @ e) * 2 / n
    k = int(np.argmax(amp))
    f1 = float(grid[k])
    reg = np.column_stack([np.cos(2 * np.pi * f1 * t), np.sin(2 * np.pi * f1 * t)])
    th = lstsq(reg, e)
    fit = reg @ th
    b, a = signal.butter(
        2, [f0 * (1 - rel_band), min(f0 * (1 + rel_band), 0.49 * fs)], "bandpass", fs=fs
    )
    band = signal.filtfilt(b, a, e)
    p_band = float(np.mean(band**2))
    frac = float(np.mean(fit**2) / p_band) if p_band > 0 else 0.0
    return min(frac, 1.0), f1, float(np.hypot(*th))


def granger_feedback(u: np.ndarray, y: np.ndarray, lags: int = 10) -> tuple[float, float]:
    """Does the past output help predict the input (feedback, y -> u)? F-test of
    u_t on [u_{t-1..t-L}, y_{t-1..t-L}] against u_t on [u_{t-1..t-L}] (Granger).

    ``u`` (N,) is one input channel, ``y`` (N, l) the outputs. Returns (F, p-value); in open
    loop the past output carries no information about the input.
    """
    u = np.asarray(u, float).ravel()
    y = np.atleast_2d(np.asarray(y, float).T).T
    n = u.size

    def lagged(x: np.ndarray) -> np.ndarray:
        return np.column_stack(
            [x[lags - k : n - k, c] for k in range(1, lags + 1) for c in range(x.shape[1])]
        )

    target = u[lags:] - u[lags:].mean()
    x_r = lagged(u[:, None] - u.mean())
    x_f = np.hstack([x_r, lagged(y - y.mean(axis=0))])
    ss_r = float(np.sum((target - x_r @ lstsq(x_r, target)) ** 2))
    ss_f = float(np.sum((target - x_f @ lstsq(x_f, target)) ** 2))
    q = x_f.shape[1] - x_r.shape[1]
    dof = target.size - x_f.shape[1]
    f = ((ss_r - ss_f) / q) / max(ss_f / dof, 1e-300)
    return float(f), float(stats.f.sf(f, q, dof))


#: The rank test of :func:`compare_errors` takes batches of at least this many correlation
#: times of the loss (adjacent batch means then correlate by about 0.1; its false-alarm rate
#: on ringing errors stays that of the 10-batch t-test, see the tests) ...
BATCH_TIMES = 4.0
#: ... and runs only when there are at least this many of them (all 8 improving: p = 0.004).
MIN_RANK_BATCHES = 8


@dataclass
class ErrorComparison:
    """Is error e1 smaller than e0? Relative drop of the RMS and a one-sided p-value."""

    drop: float  # 1 - rms(e1) / rms(e0), channels weighted by 1 / var(y)
    p_value: float  # H0: E[loss(e1)] >= E[loss(e0)]
    batches: int


def simes(p_values) -> float:
    """Simes' (1986) global p-value of a family of tests: min over k of m p_(k) / k, the p-values
    sorted ascending. Its level holds for positively dependent tests (Sarkar & Chang 1997), e.g.
    held-out comparisons of related fits against the same error; never above Bonferroni's
    m p_(1), and well below it when several of the family's tests are small together."""
    p = np.sort(np.clip(np.asarray(list(p_values), float), 0.0, 1.0))
    if p.size == 0:
        return 1.0
    return float(min(1.0, np.min(p.size * p / np.arange(1, p.size + 1))))


def compare_errors(
    e0: np.ndarray,
    e1: np.ndarray,
    scale: np.ndarray | None = None,
    batches: int = 10,
    rank_batches: int = 0,
    log_ratio: bool = False,
) -> ErrorComparison:
    """Diebold-Mariano comparison of two error sequences on the same samples.

    The loss differential d_t = sum_c (e0_ct^2 - e1_ct^2) / s_c^2 is averaged over ``batches``
    contiguous batches (batch means absorb the autocorrelation of model errors); t = mean /
    (sd / sqrt(B)) is compared with Student's t with B - 1 degrees of freedom. With
    ``log_ratio`` the t-test is on the batches' log loss ratios instead
    (:func:`_log_ratio_t`: scale-free, every batch weighs the same).

    With ``rank_batches`` > 0 the Wilcoxon signed-rank test on that many (shorter) batch means
    is run too and p = 2 min(p_t, p_rank) (Bonferroni). The t-test alone cannot see a drop
    concentrated in a few batches (a transient, a sweep crossing a missing mode): with m
    batches carrying it, t is about sqrt(m) whatever the drop's size; the ranks see the same
    drop as most batches improving.
    """
    e0 = np.atleast_2d(np.asarray(e0, float).T).T
    e1 = np.atleast_2d(np.asarray(e1, float).T).T
    s2 = np.ones(e0.shape[1]) if scale is None else np.maximum(np.asarray(scale) ** 2, 1e-300)
    l0 = np.sum(e0**2 / s2, axis=1)
    l1 = np.sum(e1**2 / s2, axis=1)
    if not np.all(np.isfinite(l1)):
        return ErrorComparison(0.0, 1.0, 0)  # the new error diverges: no improvement
    if not np.all(np.isfinite(l0)):
        return ErrorComparison(1.0, 0.0, 0)  # the old one diverged, the new one is bounded
    tot0 = float(np.sum(l0))
    drop = 1.0 - float(np.sqrt(np.sum(l1) / tot0)) if tot0 > 0 else 0.0
    d, b = _batch_means(l0 - l1, batches)
    sd = float(np.std(d, ddof=1))
    mean = float(np.mean(d))
    if log_ratio:
        p = _log_ratio_t(l0, l1, batches)
    elif sd <= 0:
        p = 0.0 if mean > 0 else 1.0
    else:
        p = float(stats.t.sf(mean / (sd / np.sqrt(b)), b - 1))
    if rank_batches > 0:  # batches of >= BATCH_TIMES correlation times: about independent
        nb = min(rank_batches, int(l1.size / (BATCH_TIMES * correlation_time(l1))))
        if nb >= MIN_RANK_BATCHES:
            d_r, _ = _batch_means(l0 - l1, nb)
            p_rank = (
                float(stats.wilcoxon(d_r, alternative="greater").pvalue)
                if np.any(d_r != 0)
                else 1.0
            )
            p = min(1.0, 2.0 * min(p, p_rank))
    return ErrorComparison(drop, p, b)


def _log_ratio_t(l0: np.ndarray, l1: np.ndarray, batches: int) -> float:
    """One-sided p of a t-test on r_b = log(mean_b l0 / mean_b l1) over ``batches`` contiguous
    batches (H0: the batches' losses exchangeable, median r_b <= 0). The t-test on the
    differences is dominated by the batches where the loss is large (a cubic spring's error
    grows with the input's amplitude: suite case 1104004, loss 0.05..1.0 per batch, all ten
    batches improving 1.4- to 16-fold, p = 0.013); the log ratio weighs every batch the same
    (p = 2e-4 uncorrected). Batches of L samples, a few correlation times tau of the losses
    each, are not independent: for exponentially decaying correlation adjacent batch means
    correlate by about tau / (4 L), the variance of their mean is (1 + tau / (2 L)) times
    the independent one's, and t is divided by its square root (tau the larger of the two
    losses' own, which the difference's estimate understates on ringing errors)."""
    m0, b = _batch_means(l0, batches)
    m1, _ = _batch_means(l1, batches)
    if np.any(m0 <= 0) or np.any(m1 <= 0):  # a model predicting a batch exactly: no ratio
        return 1.0 if np.any(m0 <= 0) else 0.0
    r = np.log(m0 / m1)
    sd = float(np.std(r, ddof=1))
    if sd <= 0:
        return 0.0 if np.mean(r) > 0 else 1.0
    tau = max(correlation_time(l0), correlation_time(l1))
    t = float(np.mean(r)) / (sd / np.sqrt(b)) / np.sqrt(1.0 + tau / (2.0 * (l0.size // b)))
    return float(stats.t.sf(t, b - 1))


def correlation_time(x: np.ndarray, window: str = "sokal", max_lag: int | None = None) -> float:
    """Integrated autocorrelation time 1 + 2 sum rho_k of x [samples], at least 1. The sum runs
    to the first lag M >= 5 times the running sum (``window`` "sokal": Sokal's adaptive window)
    or up to the first lag where rho turns negative ("positive": Geyer's initial positive
    sequence, simplified), and over at most ``max_lag`` lags (default N - 1, "positive" N / 4)."""
    x = np.asarray(x, float).ravel()
    n = x.size
    if n < 4 or np.std(x) == 0:
        return 1.0
    default = n // 4 if window == "positive" else n - 1
    lag = max(1, min(max_lag or default, n - 1))
    r = _xcorr_fft(x, x, lag)[lag + 1 :]
    if window == "positive":
        neg = np.flatnonzero(r <= 0)
        return float(max(1.0, 1.0 + 2.0 * np.sum(r[: neg[0]] if neg.size else r)))
    tau = 1.0 + 2.0 * np.cumsum(r)
    ok = np.flatnonzero(np.arange(1, r.size + 1) >= 5.0 * tau)
    return float(max(1.0, tau[ok[0]] if ok.size else tau[-1]))


def _batch_means(d: np.ndarray, batches: int) -> tuple[np.ndarray, int]:
    """Means of ``batches`` contiguous batches of d (at least 2, each of >= 10 samples)."""
    b = int(max(2, min(batches, d.size // 10)))
    k = d.size // b
    return d[: b * k].reshape(b, k).mean(axis=1), b


#: AR order of the noise model of :func:`compare_predictions` (a few lightly damped modes).
NOISE_AR_ORDER = 20


def _ar_weighted_variance(eps: np.ndarray, delta: np.ndarray, order: int) -> float:
    """var(sum_t delta_t eps_t) for fixed delta and stationary AR(order) noise eps fitted to
    ``eps``: eps = eta / A(q), so sum delta eps = sum eta (delta filtered backwards by 1/A) and
    the variance is var(eta) times the energy of that filtered delta (the noise's whole memory,
    also where delta rings at the noise's own resonance). An AR fit with a root on or outside
    the unit circle gives inf (no test)."""
    w, a = prewhiten(eps, order)
    if a.size and np.max(np.abs(np.roots(np.r_[1.0, -a]))) >= 1.0:
        return np.inf
    s2 = float(np.mean(w[a.size :] ** 2))
    g = signal.lfilter([1.0], np.r_[1.0, -a], delta[::-1])[::-1]
    return s2 * float(np.sum(g**2))


def compare_predictions(
    e0: np.ndarray, e1: np.ndarray, scale: np.ndarray | None = None
) -> ErrorComparison:
    """Is model 1's prediction better than model 0's on this record? A Diebold-Mariano test
    conditional on the two predictions (fixed design; Harvey, Leybourne and Newbold's forecast
    encompassing form): with delta = e0 - e1 (the difference of the predictions, a function of
    the input and the estimation data only) the loss differential is
    d = e0^2 - e1^2 = 2 delta (e0 - delta / 2), and under "equally good" (e0 = delta / 2 + eps)
    its sum is 2 sum delta eps, whose randomness is the validation noise eps alone. Its variance
    is taken as the larger of (a) the HAC estimate of the products delta_t epsh_t (epsh = e0 -
    lambda delta, lambda the least-squares weight of delta in e0: heteroscedasticity) over its
    integrated correlation time and (b) the stationary-AR noise model's
    (:func:`_ar_weighted_variance`, channels added as fully correlated: an upper bound), which
    holds where delta is one burst as long as the noise's memory; Student's t with the
    effective number of samples delta weighs ((sum delta^2)^2 / sum delta^4, over the
    correlation time).

    The unconditional batch-mean test (:func:`compare_errors`) asks whether the loss falls over
    records like this one; a drop confined to where the input drives the effect (a multisine's
    crest, a sweep crossing a mode) is one or two batches there, never significant however
    large. Here the same burst counts by how far it stands above the noise.
    """
    e0 = np.atleast_2d(np.asarray(e0, float).T).T
    e1 = np.atleast_2d(np.asarray(e1, float).T).T
    s = np.ones(e0.shape[1]) if scale is None else np.maximum(np.asarray(scale, float), 1e-150)
    a0, a1 = e0 / s, e1 / s
    l0, l1 = np.sum(a0**2, axis=1), np.sum(a1**2, axis=1)
    if not np.all(np.isfinite(l1)):
        return ErrorComparison(0.0, 1.0, 0)
    if not np.all(np.isfinite(l0)):
        return ErrorComparison(1.0, 0.0, 0)
    tot0 = float(np.sum(l0))
    drop = 1.0 - float(np.sqrt(np.sum(l1) / tot0)) if tot0 > 0 else 0.0
    delta = a0 - a1
    w = np.sum(delta**2, axis=1)
    sdd = float(np.sum(w))
    if sdd <= 0 or e0.shape[0] < 4 * NOISE_AR_ORDER:
        return ErrorComparison(drop, 1.0, 0)
    lam = float(np.sum(delta * a0)) / sdd
    eps = a0 - lam * delta
    x = np.sum(delta * eps, axis=1)
    tau = correlation_time(x)
    v_hac = float(np.mean(x**2)) * tau * x.size
    v_ar = sum(np.sqrt(_ar_weighted_variance(eps[:, c], delta[:, c], NOISE_AR_ORDER))
               for c in range(e0.shape[1])) ** 2
    var = max(v_hac, v_ar)
    if not np.isfinite(var) or var <= 0:
        return ErrorComparison(drop, 1.0, 0)
    t = float(np.sum(l0 - l1)) / (2.0 * np.sqrt(var))
    n_eff = sdd**2 / max(float(np.sum(w**2)), 1e-300)
    dof = max(n_eff / tau - 1.0, 1.0)
    return ErrorComparison(drop, float(stats.t.sf(t, dof)), int(dof))


def compare_drop(
    e0: np.ndarray,
    e1: np.ndarray,
    scale: np.ndarray | None = None,
    rank_batches: int = 40,
    log_ratio: bool = False,
) -> ErrorComparison:
    """Drop from error ``e0`` to ``e1`` as every trial and scan is judged: the batch-mean test
    over records like this one (:func:`compare_errors`, on the log loss ratios with
    ``log_ratio``) and the one conditional on the two predictions
    (:func:`compare_predictions`, sees a drop confined to where the input drives the effect),
    combined by Bonferroni (two tests)."""
    batch = compare_errors(e0, e1, scale, rank_batches=rank_batches, log_ratio=log_ratio)
    cond = compare_predictions(e0, e1, scale)
    return replace(batch, p_value=float(min(1.0, 2.0 * min(batch.p_value, cond.p_value))))
