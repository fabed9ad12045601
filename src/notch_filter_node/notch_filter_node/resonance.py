"""Gain stabilization of a lightly damped mode by notches (pure numpy): peak reduction and width.

A structural mode is the resonance ``G(s) = w_m^2 / (s^2 + 2 zeta w_m s + w_m^2)`` excited by
broadband input; what a notch bank ``N`` buys the flight-control loop is how far it lowers that
resonance peak:

    peak reduction [dB] = 20 log10( max_f |G| / max_f |G N| )

(gain stabilization; MIL-F-9490-style margins are stated on this peak). A notch as wide as the
mode's own half-power band reduces the peak far less than its depth, since the mode's shoulders
stay; a well-damped mode (``1 / (2 zeta)`` close to 1) cannot be reduced below its static gain.

The bank's digital sections are the bilinear transform of the analogue prototype prewarped at the
centre (:mod:`notch_filter_node.sections`), so the digital magnitude at ``f`` is the analogue one
at the warped frequency: ``|N|^2 = (x^2 + zz^2) / (x^2 + zp^2)``,
``x = (w0^2 - wa^2) / (2 w0 wa)``, ``wa = fs/pi tan(pi f / fs)``. The mode is continuous-time.

The maximum over frequency is taken on a grid that follows the resonance:
``f = f_m (1 + zeta sinh(s))`` for uniformly spaced ``s`` (a step of ``zeta/10`` of the mode's
frequency at the peak, coarser away from it), wide enough that ``|G|`` at its ends is below the
peak by more than the reduction sought (``|N| <= 1`` everywhere, so nothing outside can be the
maximum), then refined by a parabola through the largest sample and its neighbours.

:func:`design_zp` finds the narrowest notch (smallest pole damping ``zp`` at a fixed depth) whose
peak reduction reaches a required value for every mode in an uncertainty box (frequency interval,
damping interval); the peak reduction falls as the mode moves off the notch centre and as its
damping grows, so the region (an ellipse in frequency x damping) is sampled on its upper
boundary. :func:`design_pair` does the same for a staggered pair of sections, which covers an
interval with less phase lag at a crossover below the mode than one notch.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from notch_filter_node.sections import (
    DEPTH_OFF_DB,
    StaticNotch,
    bandwidth_from_zp,
    damping_lag_deg,
    pole_zero_damping,
    warp,
)

#: Grid step in s (``f = f_m (1 + zeta sinh s)``): a tenth of the mode's half-power half-width.
GRID_STEP = 0.1
#: Smallest damping ratio the grid is built for (an undamped mode has an infinite peak).
ZETA_FLOOR = 1e-4
#: Angles on the upper half of an uncertainty ellipse at which it is checked: frequency offset
#: ``cos`` of the half-width, damping ``sin`` of the way from its centre to its top.
BOX_ANGLES = np.radians([0.0, 30.0, 60.0, 90.0, 120.0, 150.0, 180.0])
#: The width search decides on unrefined grid maxima with this margin [dB]: more than their
#: underestimate of the refined peak (about 0.05 dB), so a design delivers its requirement.
DECISION_MARGIN_DB = 0.1
#: Half-distances between a notch pair's sections tried, in units of the box's half-width plus
#: the mode's half-power half-width ``zeta f`` (a known mode is best notched by a pair too).
PAIR_SPREADS = np.array([0.5, 0.7, 0.9, 1.1])
#: Pole damping of a pair's sections searched, in units of the single notch's.
PAIR_ZP_MIN, PAIR_ZP_MAX = 0.1, 0.7


def mode_gain(f: np.ndarray, f_mode: np.ndarray, zeta: np.ndarray) -> np.ndarray:
    """``|G(j 2 pi f)|`` of the unit-static-gain second-order mode (broadcast)."""
    r = np.asarray(f, dtype=float) / f_mode
    return 1.0 / np.sqrt((1.0 - r * r) ** 2 + (2.0 * zeta * r) ** 2)


def mode_peak(zeta: np.ndarray) -> np.ndarray:
    """Peak of :func:`mode_gain` (``1 / (2 zeta sqrt(1 - zeta^2))``; 1 for zeta >= 1/sqrt 2)."""
    z = np.asarray(zeta, dtype=float)
    zc = np.minimum(z, 1.0 / np.sqrt(2.0))
    return np.where(z < 1.0 / np.sqrt(2.0), 1.0 / (2.0 * zc * np.sqrt(1.0 - zc * zc)), 1.0)


def notch_gain2(
    f: np.ndarray, center: np.ndarray, zp: np.ndarray, zz: np.ndarray, fs: float
) -> np.ndarray:
    """``|N|^2`` of prewarped bilinear notch sections at ``f`` (broadcast; exact)."""
    w0 = warp(center, fs)
    wa = warp(np.minimum(f, 0.4999999 * fs), fs)
    x = (w0 * w0 - wa * wa) / (2.0 * w0 * wa)
    x2 = x * x
    return (x2 + zz * zz) / (x2 + zp * zp)


def resonance_grid(
    f_mode: np.ndarray, zeta: np.ndarray, span_db: float, fs: float
) -> np.ndarray:
    """Frequencies ``(..., n)`` around each mode (shape ``(...)``) where ``|G|`` is within
    ``span_db`` of its peak (the whole low-frequency plateau if the peak is lower than that)."""
    f_mode = np.asarray(f_mode, dtype=float)
    z = np.maximum(np.asarray(zeta, dtype=float), ZETA_FLOOR)
    a = 2.0 * z * 10.0 ** (span_db / 20.0)  # |1 - r^2| beyond which |G| < peak / 10^(span/20)
    u_hi = np.sqrt(1.0 + a) - 1.0 + z
    u_lo = np.where(a < 0.99, 1.0 - np.sqrt(np.maximum(1.0 - a, 1e-4)) + z, 0.99)
    u_lo = np.minimum(u_lo, 0.99)
    u_top = 0.4999 * fs / f_mode - 1.0
    u_hi = np.minimum(u_hi, np.maximum(u_top, 0.0))
    s_hi = np.arcsinh(u_hi / z)
    s_lo = np.arcsinh(u_lo / z)
    n = int(np.ceil(np.max(s_hi + s_lo) / GRID_STEP)) + 3
    q = np.linspace(0.0, 1.0, n)
    s = -s_lo[..., None] + q * (s_hi + s_lo)[..., None]
    return f_mode[..., None] * (1.0 + z[..., None] * np.sinh(s))


def _refined_max(v: np.ndarray) -> np.ndarray:
    """Largest value along the last axis, refined by a parabola through it and its neighbours."""
    flat = v.reshape(-1, v.shape[-1])
    rows = np.arange(flat.shape[0])
    k = np.clip(np.argmax(flat, axis=-1), 1, flat.shape[-1] - 2)
    y0, y1, y2 = flat[rows, k - 1], flat[rows, k], flat[rows, k + 1]
    den = y0 - 2.0 * y1 + y2
    ok = den < 0
    top = y1 - np.where(ok, (y2 - y0) ** 2 / (8.0 * np.where(ok, den, -1.0)), 0.0)
    return np.maximum(top, flat.max(axis=-1)).reshape(v.shape[:-1])


def peak_reduction_db(
    f_mode: np.ndarray,
    zeta: np.ndarray,
    center: np.ndarray,
    zp: np.ndarray,
    zz: np.ndarray,
    fs: float,
    span_db: float = 80.0,
) -> np.ndarray:
    """Peak reduction [dB] of the modes ``(f_mode, zeta)`` (shape ``(...)``) by the cascade of
    the sections ``(center, zp, zz)`` (shape ``(k,)``, or ``(..., k)`` for one cascade per mode).
    ``span_db`` bounds the grid (a reduction larger than it is reported as about ``span_db``)."""
    f_mode = np.asarray(f_mode, dtype=float)
    zeta = np.maximum(np.asarray(zeta, dtype=float), ZETA_FLOOR)
    f = resonance_grid(f_mode, zeta, span_db, fs)  # (..., n)
    g2 = mode_gain(f, f_mode[..., None], zeta[..., None]) ** 2
    center, zp, zz = (np.asarray(a, dtype=float) for a in (center, zp, zz))
    if center.size:  # sections on the second-to-last axis: (k,) or (..., k) broadcast
        n2 = notch_gain2(f[..., None, :], center[..., None], zp[..., None], zz[..., None], fs)
        g2 = g2 * np.prod(n2, axis=-2)
    db = 10.0 * np.log10(np.maximum(g2, 1e-300))
    return 20.0 * np.log10(mode_peak(zeta)) - _refined_max(db)


def box_modes(
    f_lo: np.ndarray, f_hi: np.ndarray, zeta_hi: np.ndarray, zeta_c: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Sample modes ``(..., m)`` of an uncertainty region: frequency ``[f_lo, f_hi]`` and
    damping from ``zeta_c`` (its centre) up to ``zeta_hi``, an ellipse (a joint confidence
    region: the corner "frequency at its edge and damping at its top" is not in it); default
    ``zeta_c = zeta_hi``, the whole interval at ``zeta_hi``. Only the upper boundary is sampled
    (:data:`BOX_ANGLES`): at any frequency the reduction only grows as the damping falls (a
    lighter mode's resonance is narrower, so more of it sits inside the notch)."""
    f_lo, f_hi = np.asarray(f_lo, dtype=float), np.asarray(f_hi, dtype=float)
    zeta_hi = np.asarray(zeta_hi, dtype=float)
    zeta_c = zeta_hi if zeta_c is None else np.asarray(zeta_c, dtype=float)
    mid, half = 0.5 * (f_lo + f_hi), 0.5 * (f_hi - f_lo)
    f = mid[..., None] + np.cos(BOX_ANGLES) * half[..., None]
    z = zeta_c[..., None] + np.sin(BOX_ANGLES) * (zeta_hi - zeta_c)[..., None]
    return f, np.broadcast_to(z, f.shape)


def region_confidence(sigma_k: float, damping_sigma_k: float) -> float:
    """Probability that the true mode lies where the notch is designed for, when the
    estimate's frequency and damping errors are independent Gaussians of the reported stds:
    the region of :func:`box_modes` (frequency ``+- sigma_k`` stds; damping up to
    ``damping_sigma_k`` stds above the estimate on an ellipse) together with every lower damping
    at those frequencies (a lighter mode is reduced more). With ``u``, ``v`` the standardized
    frequency and damping errors:

        P = P(v <= 0) P(|u| <= sigma_k) + int_0^dk phi(v) P(|u| <= sigma_k sqrt(1 - v^2/dk^2)) dv

    (the defaults 3 and 2 give 0.965). The figure holds only as far as the stds are
    calibrated (benchmarks/notch_width_budget.py measures that)."""
    from scipy.special import ndtr

    kf, kz = float(sigma_k), float(damping_sigma_k)
    inside = 1.0 - 2.0 * ndtr(-kf)  # P(|u| <= kf)
    if kz <= 0.0:
        return 0.5 * inside
    v = np.linspace(0.0, kz, 401)
    half = kf * np.sqrt(np.maximum(1.0 - (v / kz) ** 2, 0.0))
    g = np.exp(-0.5 * v * v) / np.sqrt(2.0 * np.pi) * (1.0 - 2.0 * ndtr(-half))
    return float(0.5 * inside + np.sum(0.5 * (g[1:] + g[:-1]) * np.diff(v)))


def worst_peak_reduction_db(
    f_lo: np.ndarray,
    f_hi: np.ndarray,
    zeta_hi: np.ndarray,
    center: np.ndarray,
    zp: np.ndarray,
    zz: np.ndarray,
    fs: float,
    zeta_c: np.ndarray | None = None,
) -> np.ndarray:
    """Smallest peak reduction [dB] over the uncertainty regions (shape ``(...)``, see
    :func:`box_modes`) of the cascade ``(center, zp, zz)``: ``(k,)`` is one bank for all,
    ``(..., k)`` one per region."""
    f, z = box_modes(f_lo, f_hi, zeta_hi, zeta_c)
    center, zp, zz = (np.asarray(a, dtype=float) for a in (center, zp, zz))
    # no cascade lowers a peak by more than its summed depths: the grid need not go further
    depth = 20.0 * np.log10(zp / np.maximum(zz, 1e-12)) if zp.size else np.zeros(1)
    span = float(min(np.max(np.sum(depth, axis=-1)) + 6.0, 80.0))
    if center.ndim > 1:  # one cascade per box: shared by the box's sample modes
        center, zp, zz = center[..., None, :], zp[..., None, :], zz[..., None, :]
    return np.min(peak_reduction_db(f, z, center, zp, zz, fs, span), axis=-1)


def design_zp(
    center: np.ndarray,
    f_lo: np.ndarray,
    f_hi: np.ndarray,
    zeta_hi: np.ndarray,
    required_db: float,
    depth_db: float | np.ndarray,
    fs: float,
    zp_min: np.ndarray,
    zp_max: np.ndarray,
    candidates: int = 24,
    passes: int = 2,
    zeta_c: np.ndarray | None = None,
    spread: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Narrowest single notches (pole damping ``zp``, depth ``depth_db``, centred at ``center``)
    whose peak reduction is at least ``required_db`` for every mode of the boxes
    (:func:`box_modes`; shape ``(n,)``), searched in ``[zp_min, zp_max]``
    (``passes`` rounds of log-spaced candidates, each inside the last bracket, all
    notches at once: 2 rounds resolve about 1 % of zp over a 100:1 range). Returns
    ``(zp, worst reduction [dB])``; where even ``zp_max`` falls short, ``zp_max`` and its
    (smaller) reduction. With ``spread`` [Hz] (shape ``(n,)``) each notch is a pair: two
    sections of that ``zp`` and depth at ``center -+ spread``; ``depth_db`` may be ``(n,)``."""
    g = (10.0 ** (-np.asarray(depth_db, dtype=float) / 20.0)) * np.ones(np.shape(center))
    fm, z = box_modes(f_lo, f_hi, zeta_hi, zeta_c)  # (n, m)
    z = np.maximum(z, ZETA_FLOOR)
    # the decision "reduction >= required" only needs the grid where |G| is within
    # required_db (+1 dB) of its peak: |N| <= 1, so nothing outside can exceed the bound
    f = resonance_grid(fm, z, required_db + 1.0, fs)  # (n, m, grid)
    limit = 20.0 * np.log10(mode_peak(z)) - required_db  # largest allowed |G N| [dB]
    g_db = 20.0 * np.log10(mode_gain(f, fm[..., None], z[..., None])) - limit[..., None]
    cs = np.asarray(center, dtype=float)[:, None]  # (n, sections)
    if spread is not None:
        cs = cs + np.asarray(spread, dtype=float)[:, None] * np.array([-1.0, 1.0])
    w0 = warp(cs, fs)[:, :, None, None]
    wa = warp(np.minimum(f, 0.4999999 * fs), fs)[:, None]
    x2 = ((w0 * w0 - wa * wa) / (2.0 * w0 * wa)) ** 2  # (n, sections, m, grid)
    g2 = (g * g)[:, None, None, None, None]
    bound = (10.0 ** (g_db / 10.0))[:, None]  # |G|^2 / its limit: |N|^2 must stay below 1/it
    x2c = x2[:, None]

    def meets(zp: np.ndarray) -> np.ndarray:
        """(n, c) candidates -> (n, c) bool: every box mode's |G N| below the limit."""
        zp2 = (zp * zp)[:, :, None, None, None]
        n2 = np.prod((x2c + g2 * zp2) / (x2c + zp2), axis=2)
        return np.max(bound * n2, axis=(-2, -1)) <= 10.0 ** (-DECISION_MARGIN_DB / 10.0)

    # rounds of log-spaced candidates, all notches at once: the first brackets the narrowest
    # zp that meets the requirement, the next ones refine inside the bracket
    lo = np.log(np.asarray(zp_min, dtype=float))[:, None]
    hi = np.log(np.asarray(zp_max, dtype=float))[:, None]
    q = np.linspace(0.0, 1.0, candidates)[None, :]
    ok_any = np.ones(lo.shape[0], dtype=bool)
    for _ in range(passes):
        cand = lo + q * (hi - lo)
        ok = meets(np.exp(cand))
        first = np.argmax(ok, axis=1)
        ok_any = ok.any(axis=1)
        rows = np.arange(ok.shape[0])
        new_hi = np.where(ok_any, cand[rows, first], hi[:, 0])
        new_lo = np.where(ok_any & (first > 0), cand[rows, np.maximum(first - 1, 0)], lo[:, 0])
        lo, hi = new_lo[:, None], new_hi[:, None]
        if not ok_any.any():
            break
    zp = np.where(ok_any, np.exp(hi[:, 0]), np.asarray(zp_max, dtype=float))
    zpb = np.broadcast_to(zp[:, None, None], cs[:, None].shape)  # one cascade per box
    span = float(np.max(-20.0 * np.log10(g))) * cs.shape[1] + 6.0
    worst = np.min(peak_reduction_db(fm, z, cs[:, None], zpb, g[:, None, None] * zpb, fs,
                                     min(span, 80.0)), axis=-1)
    return zp, worst


@dataclass(frozen=True)
class PairDesign:
    """The least-lagging notch pair per box (arrays ``(n,)``): sections of pole damping ``zp``
    and depth ``depth_db`` at ``center -+ spread``; ``lag_deg`` their summed phase lag at the
    crossover (``inf`` where no pair tried meets the requirement), ``worst`` the reduction."""

    spread: np.ndarray
    depth_db: np.ndarray
    zp: np.ndarray
    worst: np.ndarray
    lag_deg: np.ndarray
    factor: np.ndarray  # the spread in units of the half-width plus ``zeta_c f``


def design_pair(
    center: np.ndarray,
    f_lo: np.ndarray,
    f_hi: np.ndarray,
    zeta_hi: np.ndarray,
    required_db: float,
    depth_db: float,
    fs: float,
    zp_single: np.ndarray,
    crossover: float,
    zeta_c: np.ndarray | None = None,
    factors: np.ndarray = PAIR_SPREADS,
) -> PairDesign:
    """Narrowest staggered notch pairs for the boxes of :func:`design_zp`: two sections at
    ``center -+ spread`` make a flat-bottomed stop band, which holds a mode anywhere in a
    frequency interval with less phase lag at the crossover than the single notch that covers
    it (the single notch's V-shaped bottom must be widened until its shoulders clear the
    interval's ends and the mode's own half-power band; even for a known mode a pair of
    sections about ``zeta f`` apart lags about 10 % less than a 30 dB notch). Tried: spreads of
    ``factors`` (default :data:`PAIR_SPREADS`; e.g. the one found before for a box of the same
    shape) times the box's half-width plus ``zeta_c f``, each section ``required_db`` deep (at
    most ``depth_db``; shallower sections lag a little less but leave no margin while the pair
    moves); the least lagging pair that meets the requirement is returned. ``zp_single``: the
    pole damping of the single notch (``depth_db``) that meets it; a section's lag at a
    crossover well below it grows with ``zp - zz``, so only pairs of sections below
    :data:`PAIR_ZP_MAX` of it can lag less, and that bounds the search."""
    center = np.asarray(center, dtype=float)
    n = center.size
    half = 0.5 * (np.asarray(f_hi, dtype=float) - np.asarray(f_lo, dtype=float))
    zc = np.asarray(zeta_hi if zeta_c is None else zeta_c, dtype=float)
    q = np.atleast_1d(np.asarray(factors, dtype=float))
    base = half + np.maximum(zc, ZETA_FLOOR) * center
    spread = np.minimum(base[:, None] * q, 0.5 * center[:, None])  # (n, tries)
    depth = np.full(spread.shape, min(required_db, depth_db))

    def tile(a):
        return np.repeat(np.asarray(a, dtype=float).reshape(n), q.size)

    zp1 = tile(zp_single)
    zp, worst = design_zp(tile(center), tile(f_lo), tile(f_hi), tile(zeta_hi), required_db,
                          depth.ravel(), fs, PAIR_ZP_MIN * zp1, PAIR_ZP_MAX * zp1,
                          candidates=8, passes=3,
                          zeta_c=None if zeta_c is None else tile(zeta_c),
                          spread=spread.ravel())
    zp, worst = zp.reshape(n, -1), worst.reshape(n, -1)
    g = 10.0 ** (-depth / 20.0)
    c = center[:, None]
    lag = (damping_lag_deg(crossover, c - spread, zp, g * zp, fs)
           + damping_lag_deg(crossover, c + spread, zp, g * zp, fs))
    lag = np.where(worst >= required_db - DECISION_MARGIN_DB, lag, np.inf)
    best = np.argmin(lag, axis=1)
    rows = np.arange(n)
    return PairDesign(spread[rows, best], depth[rows, best], zp[rows, best], worst[rows, best],
                      lag[rows, best], q[best])


def guaranteeing_notch(
    f_lo: float,
    f_hi: float,
    zeta: float,
    required_db: float,
    depth_db: float,
    fs: float,
    center: float | None = None,
) -> StaticNotch:
    """The narrowest single notch of depth ``depth_db`` (centred at ``center``, default the
    geometric mean of the range) whose peak reduction is at least ``required_db`` for a mode of
    damping up to ``zeta`` anywhere in ``[f_lo, f_hi]``: the static notch that guarantees what
    an adaptive one does over a drift; with ``f_lo == f_hi`` the oracle notch that knows the
    mode. Raises ValueError when no notch up to twice the centre frequency wide reaches it."""
    fc = float(np.sqrt(f_lo * f_hi)) if center is None else float(center)
    zp_min, _ = pole_zero_damping(fc, 1e-4 * fc, depth_db, fs)
    zp_max, _ = pole_zero_damping(fc, 2.0 * fc, depth_db, fs)
    zp, worst = design_zp(np.array([fc]), np.array([f_lo]), np.array([f_hi]), np.array([zeta]),
                          required_db, depth_db, fs, np.atleast_1d(zp_min),
                          np.atleast_1d(zp_max), passes=3)
    if worst[0] < required_db - DECISION_MARGIN_DB:
        raise ValueError(f"no notch of {depth_db:g} dB up to {2.0 * fc:g} Hz wide reduces a "
                         f"{zeta:g}-damped mode in {f_lo:g}-{f_hi:g} Hz by {required_db:g} dB")
    return StaticNotch(fc, float(bandwidth_from_zp(fc, zp[0], depth_db, fs)), depth_db)


def section_damping(
    center: np.ndarray, bandwidth: np.ndarray, depth_db: np.ndarray, fs: float,
    shape_depth_db: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(center, zp, zz)`` of the sections deeper than 0 dB among the given ones (e.g. the
    sections a NotchBank message lists), ready for :func:`peak_reduction_db`."""
    center = np.atleast_1d(np.asarray(center, dtype=float))
    depth = np.atleast_1d(np.asarray(depth_db, dtype=float))
    on = depth > DEPTH_OFF_DB
    shape = None if shape_depth_db is None else np.atleast_1d(shape_depth_db)[on]
    zp, zz = pole_zero_damping(center[on], np.atleast_1d(bandwidth)[on], depth[on], fs, shape)
    return center[on], zp, zz
