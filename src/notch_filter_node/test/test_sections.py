"""Notch sections and the retune-tolerant bank, measured from scipy.signal responses."""

import numpy as np
import pytest
from scipy import signal

from notch_filter_node import sections as S

CASES = [(3.0, 0.3, 30.0, 200.0), (40.0, 5.0, 20.0, 200.0), (6.0, 1.0, 10.0, 100.0)]


@pytest.mark.parametrize(("f0", "bw", "depth", "fs"), CASES)
def test_closed_form_equals_scipy_bilinear_with_prewarp(f0, bw, depth, fs):
    zp, zz = S.pole_zero_damping(f0, bw, depth, fs)
    w = 2 * np.pi * S.warp(f0, fs)
    b, a = signal.bilinear([1, 2 * zz * w, w * w], [1, 2 * zp * w, w * w], fs=fs)
    sos = S.notch_sos(f0, bw, depth, fs)[0]
    np.testing.assert_allclose(sos[:3], b, atol=1e-13)
    np.testing.assert_allclose(sos[3:], a, atol=1e-13)


@pytest.mark.parametrize(("f0", "bw", "depth", "fs"), CASES)
def test_centre_depth_bandwidth_measured_from_response(f0, bw, depth, fs):
    sos = S.notch_sos(f0, bw, depth, fs)
    f = np.linspace(max(f0 - 3 * bw, 0.01), f0 + 3 * bw, 200_001)
    db = 20 * np.log10(np.abs(S.response(sos, f, fs)))
    assert f[np.argmin(db)] == pytest.approx(f0, abs=2 * (f[1] - f[0]))
    assert -db.min() == pytest.approx(depth, abs=0.01)
    below = f[db < -10 * np.log10(2)]
    assert below.max() - below.min() == pytest.approx(bw, rel=0.01)
    # unit gain far away (DC and Nyquist)
    far = np.abs(S.response(sos, [0.0, fs / 2 * 0.999], fs))
    np.testing.assert_allclose(far, 1.0, atol=2e-3)


def test_shaped_section_fades_with_fixed_poles():
    fs = 200.0
    sos_full = S.notch_sos(3.0, 0.3, 30.0, fs)
    sos_half = S.notch_sos(3.0, 0.3, 15.0, fs, shape_depth_db=30.0)
    sos_off = S.notch_sos(3.0, 0.3, 0.0, fs, shape_depth_db=30.0)
    np.testing.assert_allclose(sos_half[0, 3:], sos_full[0, 3:])
    assert -20 * np.log10(abs(S.response(sos_half, 3.0, fs)[0])) == pytest.approx(15.0, abs=1e-6)
    np.testing.assert_allclose(np.abs(S.response(sos_off, [0.5, 3.0, 10.0], fs)), 1.0, atol=1e-12)


def test_covering_notch_keeps_attenuation_over_range():
    fs = 200.0
    n = S.covering_notch(2.6, 3.0, 30.0, 20.0, fs)
    assert n.center == pytest.approx(np.sqrt(2.6 * 3.0))
    sos = S.notch_sos(n.center, n.bandwidth, n.depth_db, fs)
    f = np.linspace(2.6, 3.0, 2001)
    att = -20 * np.log10(np.abs(S.response(sos, f, fs)))
    assert att.min() == pytest.approx(20.0, abs=0.01)  # narrowest: attained at an edge
    assert att.max() == pytest.approx(30.0, abs=0.01)
    with pytest.raises(ValueError, match="must exceed"):
        S.covering_zp(3.0, 0.1, 20.0, 20.0, fs)


def test_phase_lags_per_section_match_cascade():
    fs = 200.0
    sos = S.notch_sos([3.0, 6.0], [0.5, 1.0], [30.0, 20.0], fs)
    lags = S.section_phase_lags_deg(sos, 0.5, fs)
    assert (lags > 0).all()
    assert lags.sum() == pytest.approx(S.phase_lag_deg(sos, 0.5, fs), rel=1e-9)


def test_fixed_bank_equals_sosfilt_and_is_block_size_independent():
    fs, rng = 200.0, np.random.default_rng(0)
    x = rng.normal(size=(1000, 3))
    p = S.SectionParams(np.array([3.0, 7.0]), np.array([0.4, 1.0]), np.array([30.0, 20.0]),
                        np.array([30.0, 20.0]))
    sos = S.notch_sos(p.center, p.bandwidth, p.depth_db, fs)
    ref, _ = signal.sosfilt(sos, x, axis=0, zi=signal.sosfilt_zi(sos)[:, :, None] * x[0])
    for block in (1, 7, 1000):
        bank = S.NotchBank(fs, 3, 2)
        bank.params = p.copy()
        y = np.concatenate([bank.process(x[a : a + block], p) for a in range(0, 1000, block)])
        np.testing.assert_allclose(y, ref, atol=1e-10)


def test_nan_input_gives_nan_output_and_clean_memory():
    fs = 200.0
    t = np.arange(800) / fs
    x = np.sin(2 * np.pi * 1.0 * t)[:, None].repeat(2, axis=1)
    x_bad = x.copy()
    x_bad[100, 0] = np.nan
    p = S.SectionParams(np.array([3.0]), np.array([0.4]), np.array([30.0]), np.array([30.0]))
    bank = S.NotchBank(fs, 2, 1)
    bank.params = p.copy()
    y = bank.process(x_bad, p)
    assert np.isnan(y[100, 0]) and np.isfinite(np.delete(y[:, 0], 100)).all()
    # the hole only disturbs the filtered sine by about one sample's change
    assert np.max(np.abs(y[400:, 0] - y[400:, 1])) < 1e-3
    with pytest.raises(ValueError, match="expected"):
        bank.process(np.zeros((4, 3)), p)


def test_single_sample_cascade_equals_section_by_section_while_moving():
    """The vectorised one-sample path (used for one message per sample) gives the same output
    as running the sections one after the other, while centres, widths and depths move."""
    fs, rng = 200.0, np.random.default_rng(3)
    x = rng.normal(size=(400, 2))
    fast, ref = S.NotchBank(fs, 2, 3), S.NotchBank(fs, 2, 3)

    def sequential(idx, sos, u):
        y = u
        for r, k in enumerate(idx):
            y = ref._run(k, sos[r], y)
        return y

    ref._cascade_one = sequential
    out_fast, out_ref = [], []
    for i in range(400):
        s = i / 400
        p = S.SectionParams(np.array([3.0 + s, 6.0 - s, 9.0]), np.array([0.5, 1.0 + s, 0.8]),
                            np.array([30.0 * min(1.0, 4 * s), 20.0, 15.0 * (1 - s)]),
                            np.array([30.0, 20.0, 15.0]))
        out_fast.append(fast.process(x[i : i + 1], p))
        out_ref.append(ref.process(x[i : i + 1], p))
    np.testing.assert_allclose(np.concatenate(out_fast), np.concatenate(out_ref), atol=1e-12)
