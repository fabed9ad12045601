"""Peak reduction of a resonance by notch sections and the width rule, checked against scipy's
frequency response on fine grids, on random modes, notches and sample rates."""

import numpy as np
import pytest
from scipy import signal

from notch_filter_node import resonance as R
from notch_filter_node import sections as S


def brute(f_mode, zeta, sos, fs):
    """Peak reduction [dB] from scipy.signal.sosfreqz on a grid of 400 001 points."""
    f = np.linspace(1e-3 * f_mode, 0.499 * fs, 400_001)
    g = 1.0 / np.abs(1.0 - (f / f_mode) ** 2 + 2j * zeta * f / f_mode)
    _, h = signal.sosfreqz(sos, worN=f, fs=fs)
    return 20 * np.log10(g.max() / np.max(g * np.abs(h)))


def random_cases(n, seed):
    rng = np.random.default_rng(seed)
    for _ in range(n):
        fs = float(rng.choice([100.0, 200.0, 500.0, 1000.0]))
        f_mode = float(rng.uniform(0.01, 0.3) * fs)
        zeta = float(10 ** rng.uniform(-2.5, -0.8))
        k = int(rng.integers(1, 4))
        centre = f_mode * (1 + rng.uniform(-0.15, 0.15, k))
        bw = f_mode * 10 ** rng.uniform(-2, -0.3, k)
        depth = rng.uniform(10, 40, k)
        yield fs, f_mode, zeta, centre, bw, depth


@pytest.mark.parametrize("case", list(random_cases(12, seed=3)))
def test_peak_reduction_matches_scipy_response(case):
    fs, f_mode, zeta, centre, bw, depth = case
    zp, zz = S.pole_zero_damping(centre, bw, depth, fs)
    got = float(R.peak_reduction_db(np.array(f_mode), np.array(zeta), centre, zp, zz, fs))
    assert got == pytest.approx(brute(f_mode, zeta, S.notch_sos(centre, bw, depth, fs), fs),
                                abs=0.02)


def test_the_issues_example():
    """A 2.5 % mode at 3.4 Hz: a 30 dB notch needs about 0.85 Hz for 15 dB, 1.5 Hz for 19 dB."""
    fs = 200.0
    n = R.guaranteeing_notch(3.4, 3.4, 0.025, 15.0, 30.0, fs)
    assert n.bandwidth == pytest.approx(0.85, abs=0.02)
    assert brute(3.4, 0.025, S.notch_sos(3.4, 1.5, 30.0, fs), fs) == pytest.approx(19.1, abs=0.1)


@pytest.mark.parametrize("seed", [1, 2, 3, 4])
def test_box_samples_find_the_worst_mode(seed):
    """A box is checked at its largest damping (the reduction only falls as damping grows) and
    at 5 frequencies: its edges, centre and quarter points. On random notches and boxes the
    worst of those 5 is the worst of a fine grid (a mode wider than the notch can gain a
    little off centre, so the worst is at the centre or at an edge)."""
    rng = np.random.default_rng(seed)
    fs = 200.0
    f0 = rng.uniform(2, 30)
    zp, zz = S.pole_zero_damping(f0, f0 * rng.uniform(0.05, 0.5), rng.uniform(15, 40), fs)
    zetas = np.linspace(0.003, 0.12, 25)
    pr = R.peak_reduction_db(np.full(25, f0), zetas, np.array([f0]), np.array([zp]),
                             np.array([zz]), fs)
    assert np.all(np.diff(pr) <= 0.01)  # along damping
    for half in f0 * np.array([0.002, 0.02, 0.1]):
        centre = f0 * (1 + rng.uniform(-0.05, 0.05))
        zeta = rng.uniform(0.005, 0.08)
        fine = R.peak_reduction_db(np.linspace(centre - half, centre + half, 81),
                                   np.full(81, zeta), np.array([f0]), np.array([zp]),
                                   np.array([zz]), fs)
        box = R.worst_peak_reduction_db(np.array(centre - half), np.array(centre + half),
                                        np.array(zeta), np.array([f0]), np.array([zp]),
                                        np.array([zz]), fs)
        assert float(box) == pytest.approx(fine.min(), abs=0.05)


@pytest.mark.parametrize("case", list(random_cases(8, seed=5)))
def test_box_grid_limited_to_the_summed_depths_loses_nothing(case):
    """The box check's grid only spans the mode's response down to the cascade's summed depths
    (+ 6 dB): no cascade lowers the peak further, so the result is the full 80 dB grid's."""
    fs, f_mode, zeta, centre, bw, depth = case
    zp, zz = S.pole_zero_damping(centre, bw, depth, fs)
    lo, hi = np.array(0.98 * f_mode), np.array(1.02 * f_mode)
    f, z = R.box_modes(lo, hi, np.array(zeta))
    full = R.peak_reduction_db(f, z, centre, zp, zz, fs, 80.0).min()
    got = R.worst_peak_reduction_db(lo, hi, np.array(zeta), centre, zp, zz, fs)
    assert float(got) == pytest.approx(float(full), abs=0.02)


@pytest.mark.parametrize("case", list(random_cases(6, seed=11)))
def test_design_is_the_narrowest_that_meets_the_requirement(case):
    fs, f_mode, zeta, *_ = case
    zeta = min(zeta, 0.05)  # a peak high enough above the static gain for 12 dB
    half = f_mode * 0.01
    tc = f_mode * 1.002
    zp_min, _ = S.pole_zero_damping(tc, 1e-3 * f_mode, 30.0, fs)
    zp_max, _ = S.pole_zero_damping(tc, 1.0 * f_mode, 30.0, fs)
    zp, worst = R.design_zp(np.array([tc]), np.array([f_mode - half]),
                            np.array([f_mode + half]), np.array([zeta]), 12.0, 30.0, fs,
                            np.atleast_1d(zp_min), np.atleast_1d(zp_max))
    bw = S.bandwidth_from_zp(tc, zp[0], 30.0, fs)
    modes = np.linspace(f_mode - half, f_mode + half, 7)
    at = [brute(f, zeta, S.notch_sos(tc, bw, 30.0, fs), fs) for f in modes]
    narrower = [brute(f, zeta, S.notch_sos(tc, 0.95 * bw, 30.0, fs), fs) for f in modes]
    assert min(at) >= 12.0 and worst[0] == pytest.approx(min(at), abs=0.05)
    assert min(narrower) < 12.0


def test_model_peak_reduction_is_what_a_broadband_excited_signal_shows():
    """The mode x bank figure is the one a signal shows: a lightly damped mode excited by white
    noise (1000 s at 100 Hz), through a fixed notch; the ratio of the resonance peaks of the
    averaged spectra (0.012 Hz resolution, smoothed over 5 bins: the largest of many noisy bins
    is biased up) before and after matches the model within 1 dB."""
    fs, f_mode, zeta = 100.0, 3.4, 0.025
    w = 2 * np.pi * f_mode
    b, a = signal.bilinear([w * w], [1.0, 2 * zeta * w, w * w], fs=fs)
    x = signal.lfilter(b, a, np.random.default_rng(4).normal(size=100_000))
    smooth = np.ones(5) / 5
    for bw in (0.5, 0.85, 1.5):
        sos = S.notch_sos(3.4, bw, 30.0, fs)
        y = signal.sosfilt(sos, x)
        f, px = signal.welch(x, fs=fs, nperseg=8192)
        _, py = signal.welch(y, fs=fs, nperseg=8192)
        band = (f > 2.0) & (f < 5.0)
        px, py = np.convolve(px, smooth, "same"), np.convolve(py, smooth, "same")
        measured = 10 * np.log10(px[band].max() / py[band].max())
        zp, zz = S.pole_zero_damping(3.4, bw, 30.0, fs)
        model = float(R.peak_reduction_db(np.array(f_mode), np.array(zeta), np.array([3.4]),
                                          zp[None], zz[None], fs))
        print(f"bandwidth {bw} Hz: signal {measured:.2f} dB, model {model:.2f} dB")
        assert measured == pytest.approx(model, abs=1.0), (bw, measured, model)


def test_unreachable_requirement_is_reported():
    with pytest.raises(ValueError, match="no notch of 20 dB"):
        R.guaranteeing_notch(3.0, 5.0, 0.03, 15.0, 20.0, 100.0)


def test_closed_form_phase_lag_equals_freqz():
    fs = 200.0
    centre, bw, depth = np.array([2.0, 4.0, 30.0]), np.array([0.5, 1.5, 8.0]), np.array([30.0,
                                                                                     20, 10])
    zp, zz = S.pole_zero_damping(centre, bw, depth, fs)
    got = S.damping_lag_deg(0.7, centre, zp, zz, fs)
    want = S.section_phase_lags_deg(S.notch_sos(centre, bw, depth, fs), 0.7, fs)
    np.testing.assert_allclose(got, want, atol=1e-9)


@pytest.mark.parametrize("kf,kz", [(3.0, 2.0), (2.0, 3.0), (1.0, 0.0), (2.5, 2.5)])
def test_region_confidence_is_the_gaussian_mass_it_covers(kf, kz):
    """Monte Carlo: standardized errors inside the designed region or below it in damping."""
    rng = np.random.default_rng(7)
    u, v = rng.standard_normal((2, 400_000))
    inside = np.abs(u) <= kf
    if kz > 0:
        inside &= (v <= 0) | ((u / kf) ** 2 + (v / kz) ** 2 <= 1.0)
    else:
        inside &= v <= 0
    assert R.region_confidence(kf, kz) == pytest.approx(inside.mean(), abs=2e-3)


def _single_and_pair(fs, f_mode, zeta, half, required=15.0, depth=30.0, crossover=None):
    c = np.array([f_mode])
    lo, hi, z = c - half, c + half, np.array([zeta])
    zp_min, _ = S.pole_zero_damping(c, 1e-3 * f_mode, depth, fs)
    zp_max, _ = S.pole_zero_damping(c, 1.0 * f_mode, depth, fs)
    zp, _ = R.design_zp(c, lo, hi, z, required, depth, fs, zp_min, zp_max, passes=3)
    xo = 0.2 * f_mode if crossover is None else crossover
    pair = R.design_pair(c, lo, hi, z, required, depth, fs, zp, xo)
    g = 10.0 ** (-depth / 20.0)
    return float(S.damping_lag_deg(xo, c, zp, g * zp, fs)[0]), pair


@pytest.mark.parametrize("case", list(random_cases(5, seed=23)))
def test_pair_meets_the_requirement_over_the_interval_and_is_the_narrowest(case):
    """A pair (two sections at centre -+ spread): every mode of the interval is reduced by the
    requirement (scipy's response), and sections 5 % narrower (same spread) miss it."""
    fs, f_mode, zeta, *_ = case
    zeta = min(zeta, 0.05)
    half = f_mode * 0.02
    _, pair = _single_and_pair(fs, f_mode, zeta, half)
    assert np.isfinite(pair.lag_deg[0]) and pair.depth_db[0] == 15.0
    centres = f_mode + np.array([-1.0, 1.0]) * pair.spread[0]
    modes = np.linspace(f_mode - half, f_mode + half, 9)

    def worst(scale):
        zp = scale * pair.zp[0]
        sos = S.sos_from_damping(centres, np.full(2, zp), np.full(2, zp * 10 ** (-15 / 20)), fs)
        return min(brute(f, zeta, sos, fs) for f in modes)

    assert worst(1.0) >= 15.0 and pair.worst[0] == pytest.approx(worst(1.0), abs=0.1)
    assert worst(0.95) < 15.0


@pytest.mark.parametrize(("f_mode", "zeta"), [(2.4, 0.022), (10.0, 0.01), (40.0, 0.03)])
def test_pair_lags_less_than_the_single_notch(f_mode, zeta):
    """For the same guarantee a pair lags less at the crossover than one notch: a little for a
    known mode, much for an uncertain one (interval +- 2 half-power half-widths)."""
    fs = 400.0
    known, pair = _single_and_pair(fs, f_mode, zeta, 0.0)
    assert pair.lag_deg[0] < 0.95 * known
    wide, pair = _single_and_pair(fs, f_mode, zeta, 2.0 * zeta * f_mode)
    assert pair.lag_deg[0] < 0.75 * wide
