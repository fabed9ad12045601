"""A wide automatic band splits in two (issue #10): ``core.band.split_frequency``,
``params.window_capped`` and the pipeline's second estimator (``low_band.py``); a configured
band's order makes room for its confirmed modes as the low group's does for its peaks, and its
window spans a full period of its lowest lightly damped one."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import signal
from sysid_node.core.band import BandChoice, split_frequency, structure_band
from sysid_node.core.recursive import RecursiveDSRA
from sysid_node.low_band import LowBand, max_split_hz
from sysid_node.scenarios.draw import drifting_mode
from sysid_node.suite import T0_NS as T0
from sysid_node.suite import run_output_only

from sysid_node import params as P


def _choice(low: float, peaks: tuple[float, ...], fmax: float) -> BandChoice:
    return BandChoice(fmax, max(peaks), 1.0, low, peaks)


def test_a_wide_band_splits_in_its_widest_gap_between_peaks():
    c = _choice(2.5, (3.0, 4.2, 12.0, 80.0, 120.0, 190.0), 300.0)
    assert split_frequency(c) == pytest.approx(math.sqrt(12.0 * 80.0))


def test_neighbouring_coarse_bins_are_not_a_gap():
    # 4 s of a 256 Hz record: 1 Hz bins; 1 -> 2 Hz is a ratio of 2 but no room for a split
    c = _choice(0.75, (1.0, 2.0, 3.0, 5.0, 10.0, 12.0), 102.4)
    assert split_frequency(c) == pytest.approx(math.sqrt(50.0))


def test_a_narrow_band_or_one_without_a_gap_does_not_split():
    assert math.isnan(split_frequency(_choice(2.5, (3.0, 12.0, 30.0), 45.0)))  # 18 x its low
    spread = tuple(3.0 * 1.5 ** k for k in range(12))  # 3 .. 260 Hz, no gap of 2
    assert math.isnan(split_frequency(_choice(2.5, spread, 400.0)))
    # peaks at or below the lowest peak's edge do not count
    assert math.isnan(split_frequency(_choice(2.5, (1.0, 2.0), 300.0)))


def test_the_window_is_capped_when_half_the_lowest_period_needs_more_rows_than_allowed():
    v = P.defaults()
    assert P.window_capped(v, 1, 1, 750.0, 2.0)  # 188 rows > 280 / 4
    assert not P.window_capped(v, 1, 1, 100.0, 2.0)
    assert not P.window_capped(v, 1, 1, 750.0, math.nan)
    assert not P.window_capped({**v, "block_rows": 20}, 1, 1, 750.0, 2.0)  # configured


def _resonance(rng, fs, f, zeta, n):
    """A mode driven by white noise: its exact discrete pole pair (no frequency warping)."""
    w, dt = 2 * np.pi * f, 1.0 / fs
    r = np.exp(-zeta * w * dt)
    a = [1.0, -2 * r * np.cos(w * np.sqrt(1 - zeta**2) * dt), r * r]
    x = signal.lfilter([1.0], a, rng.standard_normal(n + 4000))[4000:]
    return x / x.std()


MODES = ((2.2, 0.005), (2.6, 0.01), (4.1, 0.01), (5.3, 0.02),
         (110.0, 0.01), (135.0, 0.01), (160.0, 0.02), (190.0, 0.01), (240.0, 0.02))
FS = 800.0


@pytest.fixture(scope="module")
def wide_record():
    """Two outputs, output-only: two modes near 3 Hz and two above 100 Hz at 800 Hz (a 2.5 Hz
    period is 320 samples; the main estimator's window is capped at 70 block rows)."""
    rng = np.random.default_rng(21)
    n = int(24 * FS)
    q = np.stack([_resonance(rng, FS, f, z, n) for f, z in MODES], axis=1)
    shapes = rng.uniform(0.3, 1.0, (2, len(MODES))) * rng.choice([-1.0, 1.0], (2, len(MODES)))
    y = q @ shapes.T
    return y + 0.05 * y.std(axis=0) * rng.standard_normal(y.shape)


def test_structure_band_sees_both_groups_and_the_gap(wide_record):
    c = structure_band(wide_record[: int(4 * FS)], None, FS)
    assert 3.3 < split_frequency(c) < 110.0, c


def test_pipeline_identifies_the_low_group_with_its_own_estimator(wide_record):
    logs: list[str] = []
    pl, recs = run_output_only(wide_record, FS, None, 40, logs.append)
    assert any("split" in m for m in logs), logs
    assert pl.low_band is not None and 3.3 < pl.split_hz < 110.0
    assert pl.low_band.rate < FS / 2  # decimated
    _each_mode_right_at_the_end(recs, MODES)


def test_chunking_does_not_change_the_numbers_with_a_split(wide_record):
    y = wide_record[: int(7 * FS)]
    _, a = run_output_only(y, FS, None, 5)
    pl, b = run_output_only(y, FS, None, 37)
    assert pl.low_band is not None
    assert len(a) == len(b) > 0
    for ra, rb in zip(a, b, strict=True):
        assert ra.stamp_ns == rb.stamp_ns
        np.testing.assert_array_equal([m.frequency_hz for m in ra.modes],
                                      [m.frequency_hz for m in rb.modes])


def test_the_low_group_starts_before_the_band_is_chosen(wide_record):
    """While the band's probe runs (EARLY_SPLIT_S) the split is looked for: the low group's
    estimator runs, and its modes are tracked, before the band choice at BAND_PROBE_S (the
    main estimator's 70 block rows at 800 Hz span a quarter of a 2.5 Hz period)."""
    from sysid_node.pipeline import BAND_PROBE_S, EARLY_SPLIT_S

    y = wide_record[: int(0.5 * (EARLY_SPLIT_S[-1] + BAND_PROBE_S) * FS)]  # 3.5 s
    pl, recs = run_output_only(y, FS, None, 40)
    assert math.isnan(pl.band_edge)  # not chosen yet
    assert pl.low_band is not None and 3.3 < pl.split_hz < 110.0
    assert pl.low_band.rate < FS / 2
    last = [m.frequency_hz for m in recs[-1].modes if m.status == "tracked"]
    assert any(abs(f / 2.2 - 1) <= 0.02 for f in last), last


def test_the_split_goes_down_the_gap_to_where_the_low_window_fits():
    c = _choice(2.5, (3.0, 4.2, 12.0, 80.0, 120.0, 190.0), 300.0)
    assert split_frequency(c, max_hz=20.0) == pytest.approx(20.0)
    # never closer than sqrt(SPLIT_GAP) to the peak below the gap
    assert split_frequency(c, max_hz=10.0) == pytest.approx(12.0 * math.sqrt(2.0))
    assert split_frequency(c, max_hz=1e3) == pytest.approx(math.sqrt(12.0 * 80.0))


def test_max_split_is_where_the_low_window_spans_the_lowest_peak():
    v = P.defaults()
    # 5 outputs: 28 block rows; 256 Hz / 7 = 36.6 Hz spans half a period of 0.75 Hz in 25
    top = max_split_hz(v, 5, 0, 256.0, 0.75)
    assert top == pytest.approx(256.0 / 7 / 3)
    rate = 3.0 * top
    assert not P.window_capped(v, 5, 0, rate, 0.75)
    assert math.isinf(max_split_hz({**v, "block_rows": 20}, 5, 0, 256.0, 0.75))


def test_a_configured_band_makes_room_in_its_order_for_its_modes(wide_record):
    """freq_max 8 Hz holds four modes (2.2, 2.6, 4.1, 5.3 Hz); max_modes 4 gives an order of 8:
    the order grows to 2 x max(max_modes, 2 x confirmed modes), logged, from the raw data;
    block rows and memory stay (memory_periods is the automatic band's)."""
    y = wide_record[: int(18 * FS)]
    logs: list[str] = []
    params = {"freq_max": 8.0, "max_modes": 4}
    pl, recs = run_output_only(y, FS, params, 40, logs.append)
    grown = [m for m in logs if "confirmed modes" in m]
    assert grown, logs
    assert pl._band_modes >= 3
    assert pl.estimator.max_order == 2 * 2 * pl._band_modes > 2 * 4
    assert pl.block_rows == P.effective_block_rows(pl.values, 2, 0)
    assert pl.forgetting_factor == pytest.approx(math.exp(-1.0 / pl.identification_rate))
    _, other = run_output_only(y, FS, params, 7)
    assert [r.stamp_ns for r in other] == [r.stamp_ns for r in recs]
    np.testing.assert_allclose([m.frequency_hz for m in other[-1].modes],
                               [m.frequency_hz for m in recs[-1].modes], rtol=1e-9)


def test_an_order_with_room_or_a_configured_one_is_left_as_it_is(wide_record):
    y = wide_record[: int(8 * FS)]
    for params in ({"freq_max": 8.0, "max_modes": 10},
                   {"freq_max": 8.0, "max_modes": 4, "max_order": 8}):
        logs: list[str] = []
        pl, _ = run_output_only(y, FS, params, 40, logs.append)
        assert not any("confirmed modes" in m for m in logs), (params, logs)
        assert pl.estimator.max_order == (params.get("max_order") or 20)


@pytest.mark.parametrize(("damping", "grows"), [(0.02, True), (0.15, False)])
def test_a_configured_band_window_spans_its_lowest_lightly_damped_mode(damping, grows):
    """200 Hz, band 0-60 Hz: a 2.5 Hz mode is 80 samples long, the automatic window 35 rows.
    Lightly damped, it widens the window towards a full period, to the 70 rows of the cost
    budget (one rebuild from the raw data); well damped, like the rigid-body response below it
    (5-30 %), it does not size the window."""
    scn = drifting_mode(np.random.default_rng(4), fs=200.0, duration_s=12.0, frequency_hz=2.5,
                        drift=0.0, damping=damping)
    logs: list[str] = []
    pl, recs = run_output_only(scn.y, scn.fs, {"freq_max": 60.0}, 40, logs.append)
    assert any(abs(m.frequency_hz / 2.5 - 1) < 0.02 for m in recs[-1].modes), recs[-1].modes
    rows = [m for m in logs if "block rows 35 ->" in m]
    if grows:
        assert pl.block_rows == 70 and len(rows) == 1, logs  # l i <= 70 (80 would span it)
    else:
        assert pl.block_rows == 35 and not rows, logs


@pytest.mark.parametrize(("outputs", "rate", "rows"), [(1, 499.0 / 8, 36), (2, 499.0 / 4, 36)])
def test_the_low_group_rate_lets_its_default_rows_span_their_share_of_the_period(outputs, rate,
                                                                                rows):
    """499 Hz split at 11 Hz, lowest peak 1.75 Hz: 35 default rows span half a period at 122.5
    Hz (decimated by 4) and a full one, as one output without input needs
    (``params.window_periods``), at 61.25 Hz (by 8), not 72 rows at 124.75 Hz."""
    low = LowBand(RecursiveDSRA, P.defaults(), outputs, 0, 499.0, 10.97, 1.75)
    assert low.rate == pytest.approx(rate)
    assert low.block_rows == rows
    assert low.block_rows / low.rate >= P.window_periods(outputs, 0) / 1.75


@pytest.mark.slow
def test_one_output_output_only_low_neighbours_are_told_apart():
    """One output, no input, 200 Hz, modes at 2.5 Hz (1 % damped), 3.4 (3 %), 7, 9 and 30 Hz:
    the window spans a full period of the lowest peak (89 block rows; half a period, 45 rows,
    identified none of the four low modes in the last 6 s of 20 s)."""
    rng = np.random.default_rng(7)
    modes = ((2.5, 0.01), (3.4, 0.03), (7.0, 0.01), (9.0, 0.02), (30.0, 0.01))
    fs, n = 200.0, 4000
    q = np.stack([_resonance(rng, fs, f, z, n) for f, z in modes], axis=1)
    y = q @ rng.uniform(0.4, 1.0, len(modes))
    y = (y + 0.05 * y.std() * rng.standard_normal(n))[:, None]
    pl, recs = run_output_only(y, fs, None, 40)
    assert pl.block_rows >= fs / pl.band_low  # a full period
    _each_mode_right_at_the_end(recs, modes)


def _each_mode_right_at_the_end(recs, modes, seconds: float = 6.0, share: float = 0.8) -> None:
    """Each mode (frequency [Hz], damping) tracked within 2 % in ``share`` of the estimates of
    the last ``seconds`` of the record."""
    t = (np.array([r.stamp_ns for r in recs]) - T0) * 1e-9
    last = [r for r, tk in zip(recs, t, strict=True) if tk >= t[-1] - seconds]
    for f, _ in modes:
        right = [any(m.status == "tracked" and abs(m.frequency_hz / f - 1) <= 0.02
                     for m in r.modes) for r in last]
        assert np.mean(right) >= share, (f, np.mean(right))


def test_each_main_realization_gets_the_low_realization_of_its_own_time(wide_record):
    """Fed a 0.1 s piece at once, the low group realizes twice in it (20 Hz) and so does the
    main estimator: each main realization gets the low one made by its time, not the piece's
    latest twice (which counted one low realization as two hits in the tracker)."""
    low = LowBand(RecursiveDSRA, P.defaults(), 2, 0, FS, 30.0, 2.2)
    piece, same, pairs = int(0.1 * FS), 0, 0
    for a in range(0, int(4 * FS), piece):
        end_s = (a + piece) / FS
        low.update(None, wide_record[a : a + piece], True, end_s)
        first, second = low.current(end_s - 0.05, 20.0), low.current(end_s, 20.0)
        if first and second:
            pairs += 1
            same += first is second
    assert pairs > 20
    assert same == 0
