"""Automatic band (issue #10 item 3): ``core/band.py`` and the pipeline with ``freq_max: 0``."""

from __future__ import annotations

import functools

import numpy as np
import pytest
from scipy import signal
from sysid_node.core.band import MAX_EDGE_FRACTION, structure_band
from sysid_node.decimation import auto_factor
from sysid_node.scenarios import draw_modal_scenario
from sysid_node.suite import T0_NS as T0
from sysid_node.suite import run_output_only


def _resonance(rng, fs, f, zeta, n, level=1.0):
    """Response of a lightly damped mode to white noise (bilinear SDOF), RMS ``level``."""
    w = 2 * np.pi * f
    b, a = signal.bilinear([w * w], [1.0, 2 * zeta * w, w * w], fs)
    x = signal.lfilter(b, a, rng.standard_normal(n + 2000))[2000:]
    return level * x / x.std()


def test_modes_in_white_noise_give_a_band_above_them():
    rng = np.random.default_rng(1)
    fs, n = 1000.0, 4000
    y = _resonance(rng, fs, 12.0, 0.01, n) + _resonance(rng, fs, 31.0, 0.02, n, 0.5)
    y = y + 0.05 * y.std() * rng.standard_normal(n)
    ch = structure_band(y[:, None], None, fs)
    assert ch.found
    # the roll-off of a mode far above the noise can lift the edge (the safe side)
    assert 31.0 <= ch.top_hz
    assert 31.0 < ch.fmax_hz < 0.5 * MAX_EDGE_FRACTION * fs  # narrowed


def test_structure_below_freq_min_is_not_looked_at():
    """``fmin_hz`` (the user's freq_min): the band's top and lowest peak are those of the
    structure above it; with none above, the full band (was: the top of the structure below,
    a band under freq_min, which the estimator refused: every step failed)."""
    rng = np.random.default_rng(4)
    fs, n = 1000.0, 4000
    y = _resonance(rng, fs, 12.0, 0.01, n) + _resonance(rng, fs, 31.0, 0.02, n, 0.5)
    y = (y + 0.05 * y.std() * rng.standard_normal(n))[:, None]
    both = structure_band(y, None, fs)
    above = structure_band(y, None, fs, fmin_hz=20.0)
    assert both.low_hz < 12.0 and 20.0 <= above.low_hz < 31.0
    assert above.fmax_hz == pytest.approx(both.fmax_hz)
    low = _resonance(rng, fs, 12.0, 0.01, n)[:, None] + 0.05 * rng.standard_normal((n, 1))
    assert structure_band(low, None, fs).fmax_hz < 100.0
    none_above = structure_band(low, None, fs, fmin_hz=100.0)
    assert not none_above.found and none_above.fmax_hz == pytest.approx(MAX_EDGE_FRACTION * fs)


def test_white_noise_has_no_structure_and_keeps_the_full_band():
    rng = np.random.default_rng(2)
    for fs in (100.0, 1000.0):
        ch = structure_band(rng.standard_normal((4000, 3)), None, fs)
        assert not ch.found
        assert ch.fmax_hz == pytest.approx(MAX_EDGE_FRACTION * fs)


def test_too_little_data_keeps_the_full_band():
    ch = structure_band(np.ones((40, 1)), None, 200.0)
    assert not ch.found and ch.fmax_hz == pytest.approx(80.0)


def test_multisine_input_lines_widen_the_band():
    """A measured input's lines count: the response is excited (and identified) there."""
    rng = np.random.default_rng(3)
    fs, n = 500.0, 4000
    t = np.arange(n) / fs
    u = sum(np.sin(2 * np.pi * f * t + rng.uniform(0, 6)) for f in (3.0, 7.0, 60.0))
    y = _resonance(rng, fs, 5.0, 0.01, n) + 0.02 * rng.standard_normal(n)
    assert structure_band(y[:, None], None, fs).fmax_hz < 40.0
    assert structure_band(y[:, None], u[:, None], fs).fmax_hz > 60.0


def test_broadband_input_does_not_hold_the_band_open():
    """A band-limited broadband input (2-150 Hz noise at 500 Hz) stands far above its own 5 %
    quantile (its stop bands) over its whole pass band, but has no lines: the band follows the
    response's structure (a 5 Hz mode), as without the input."""
    rng = np.random.default_rng(4)
    fs, n = 500.0, 4000
    sos = signal.butter(4, [2.0, 150.0], "bandpass", fs=fs, output="sos")
    u = signal.sosfilt(sos, rng.standard_normal(n))
    y = _resonance(rng, fs, 5.0, 0.01, n) + 0.02 * rng.standard_normal(n)
    alone = structure_band(y[:, None], None, fs).fmax_hz
    assert alone < 40.0
    assert structure_band(y[:, None], u[:, None], fs).fmax_hz == pytest.approx(alone)


@functools.cache
def _drawn_choices() -> list:
    """(seed, scenario, band choice from its first 4 s as the pipeline makes it) for the
    randomized suite's records, seeds 1000-1099 (shared by the tests below)."""
    out = []
    for seed in range(1000, 1100):
        scn = draw_modal_scenario(np.random.default_rng(seed), duration_s=6.0, change=None)
        n = int(max(4.0 * scn.fs, 512))
        out.append((seed, scn, structure_band(scn.y[:n], None if scn.u is None else scn.u[:n],
                                              scn.fs)))
    return out


def test_drawn_scenarios_keep_their_true_modes():
    """The randomized suite's records (100-1000 Hz, 1-8 modes anywhere below 0.4 fs, 1-3
    outputs, with and without an input): the band chosen from the first 4 s (as the pipeline
    does) holds every true mode; some draws are narrowed. Known loss (1 of the 1500 draws
    tried, seed 1024): 8 modes seen in acceleration under ambient excitation, the spectrum
    above the noise almost everywhere, the weak top mode at 80 Hz (210 Hz) below the test's
    ratio and the band ends at 57 Hz."""
    lost, narrowed = [], 0
    for seed, scn, ch in _drawn_choices():
        top = max(f for f, _ in scn.modes_at(0.0))
        if top > ch.fmax_hz:
            lost.append((seed, scn.fs, top, ch.fmax_hz))
        narrowed += ch.fmax_hz < 0.5 * MAX_EDGE_FRACTION * scn.fs
    assert len(lost) <= 1, lost
    assert narrowed >= 5


def _run(y, fs, params=None, block=50):
    logs: list[str] = []
    pl, recs = run_output_only(y, fs, params, block, logs.append)
    return pl, recs, logs


def test_pipeline_chooses_the_band_decimates_and_keeps_every_record():
    """freq_max 0: the band comes from the data, the estimator is rebuilt decimated to match
    (a record every publication period throughout), and a 8 Hz mode at 1 kHz is
    tracked."""
    rng = np.random.default_rng(4)
    fs, n = 1000.0, 20000
    y = _resonance(rng, fs, 8.0, 0.01, n) + 0.05 * rng.standard_normal(n)
    pl, recs, logs = _run(y[:, None], fs)
    assert any("automatic band" in m for m in logs)
    assert 8.0 < pl.band_edge < 100.0
    assert pl.decimator.factor == auto_factor(fs, pl.band_edge) > 1
    assert recs[-1].band_max_hz == pytest.approx(pl.band_edge)
    assert recs[-1].sample_rate == pytest.approx(fs / pl.decimator.factor)
    t = (np.array([r.stamp_ns for r in recs]) - T0) * 1e-9
    assert t[0] < 0.1 + 1e-6  # estimates from the start, across the rebuild
    assert np.allclose(np.diff(t), 0.1, atol=0.01)
    tracked = [m.frequency_hz for m in recs[-1].modes if m.status == "tracked"]
    assert any(abs(f / 8.0 - 1) < 0.01 for f in tracked), tracked


def test_pipeline_widens_the_band_when_a_mode_appears_above_it():
    rng = np.random.default_rng(5)
    fs, n = 400.0, 16000
    y = _resonance(rng, fs, 5.0, 0.01, n) + 0.05 * rng.standard_normal(n)
    late = _resonance(rng, fs, 60.0, 0.01, n)
    late[: n // 2] = 0.0
    pl, recs, logs = _run((y + late)[:, None], fs)
    first = recs[len(recs) // 4].band_max_hz
    assert first < 30.0
    assert any("widened" in m for m in logs), logs
    assert recs[-1].band_max_hz > 60.0
    tracked = [m.frequency_hz for m in recs[-1].modes if m.status == "tracked"]
    assert any(abs(f / 5.0 - 1) < 0.03 for f in tracked), tracked  # the track was kept


def test_configured_band_is_untouched():
    rng = np.random.default_rng(6)
    fs, n = 200.0, 2000
    y = _resonance(rng, fs, 5.0, 0.01, n) + 0.05 * rng.standard_normal(n)
    pl, recs, logs = _run(y[:, None], fs, {"freq_max": 50.0})
    assert not any("automatic band" in m for m in logs)
    assert recs[-1].band_max_hz == pytest.approx(50.0)


def test_lowest_peak_is_the_lowest_mode_not_a_drift():
    """The lowest output bin rising from below is about the lowest mode (its lower edge at most
    two and a half bins below it, never above);
    a slow drift's rising spectrum below it is no peak, and an input's lines do not count."""
    rng = np.random.default_rng(5)
    fs, n = 877.0, 4000
    t = np.arange(n) / fs
    y = _resonance(rng, fs, 9.5, 0.01, n) + _resonance(rng, fs, 150.0, 0.02, n, 0.5)
    drift = 2.0 * np.cumsum(rng.standard_normal(n)) / np.sqrt(n)  # a random walk offset
    y = y + drift + 0.02 * rng.standard_normal(n)
    u = np.sin(2 * np.pi * 1.3 * t)
    ch = structure_band(y[:, None], u[:, None], fs)
    assert 9.5 - 2.5 * ch.resolution_hz <= ch.low_hz <= 9.5
    white = structure_band(rng.standard_normal((n, 2)), None, fs)
    assert np.isnan(white.low_hz)


def test_lowest_mode_in_the_first_coarse_bins_is_found_on_a_finer_grid():
    """A 2.2 Hz mode at 433 Hz sits in the first 1.7 Hz Welch bin of 4 s of data, which has no
    bins below it for the rising test; the fine spectrum (3 segments) finds it, also under a
    displacement sensor's quasi-static plateau and a drift. Without the fine look the lowest
    rise is the next mode's (40 Hz) and the Hankel window spans a few ms of a 450 ms period."""
    rng = np.random.default_rng(11)
    fs, n = 433.0, int(4 * 433)
    y = _resonance(rng, fs, 2.2, 0.01, n) + _resonance(rng, fs, 40.0, 0.02, n, 0.5)
    y = y + 0.5 * np.cumsum(rng.standard_normal(n)) / np.sqrt(n) + 0.03 * rng.standard_normal(n)
    ch = structure_band(y[:, None], None, fs)
    assert 1.0 <= ch.low_hz <= 2.2, ch


def test_drawn_scenarios_find_their_lowest_mode():
    """The randomized suite's records (first 4 s, as the pipeline): the lowest output rise is at
    or below the lowest true mode (+2 %) in all but a few draws (measured: 2 of these 100,
    5 of 300 with seeds up to 1299, 32 of 300 before the fine look)."""
    missed = []
    for seed, scn, ch in _drawn_choices():
        f0 = float(np.min(scn.structure.frequencies_hz))
        if not ch.low_hz <= 1.02 * f0:
            missed.append((seed, round(f0, 2), round(ch.low_hz, 2)))
    assert len(missed) <= 3, missed
