"""Spurious-mode test 5 (``core/spurious.py``): a pole pair in a peak of the recent input's
spectrum is the input's own, not a mode; on the pipeline, a swept input no longer leaves tracked
"modes" that follow the sweep."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import signal
from sysid_node.core import spurious
from sysid_node.core.spurious import input_concentration, input_own


def _window_cov(u: np.ndarray, n: int, memory_windows: float = 2.0) -> np.ndarray:
    """Exponentially weighted covariance of the n-sample windows of u (as the estimator's)."""
    rows = np.lib.stride_tricks.sliding_window_view(u, n)
    lam = 1.0 - 1.0 / (memory_windows * n)
    w = lam ** np.arange(rows.shape[0] - 1, -1, -1.0)
    return (rows * w[:, None]).T @ rows


FS, N = 400.0, 80  # 2i = 80 window samples: 5 Hz Bartlett bins


def test_white_input_has_no_peak_and_unit_concentration():
    rng = np.random.default_rng(0)
    cov = _window_cov(rng.standard_normal(4000), N)
    f = np.linspace(2.0, 190.0, 60)
    q = input_concentration(cov, 1, f, FS)
    assert 0.4 < np.median(q) < 1.6
    assert not input_own(cov, 1, f, FS).any()


def test_sweep_frequency_is_the_inputs_own_and_a_mode_behind_it_is_not():
    t = np.arange(int(6 * FS)) / FS
    u = signal.chirp(t, 5.0, t[-1], 65.0)  # 10 Hz/s; now at 65 Hz
    cov = _window_cov(u, N)
    own = input_own(cov, 1, np.array([64.0, 40.0, 20.0]), FS)
    assert own.tolist() == [True, False, False]


def test_red_input_low_end_and_band_pass_input_are_not_peaks():
    """A red input's spectrum falls from DC (no peak at a low mode), a band-pass one is flat."""
    rng = np.random.default_rng(1)
    red = signal.lfilter([1.0], [1.0, -0.995], rng.standard_normal(6000))
    sos = signal.butter(4, [10.0 / 200, 120.0 / 200], btype="bandpass", output="sos")
    band = signal.sosfilt(sos, rng.standard_normal(6000))
    f = np.array([3.0, 6.0, 12.0, 40.0, 90.0])
    assert input_concentration(_window_cov(red, N), 1, f[:1], FS)[0] > spurious.INPUT_OWN_LEVEL
    assert not input_own(_window_cov(red, N), 1, f, FS).any()
    assert not input_own(_window_cov(band, N), 1, f, FS).any()


def test_several_inputs_any_one_narrow_band():
    rng = np.random.default_rng(2)
    t = np.arange(int(4 * FS)) / FS
    u = np.column_stack([rng.standard_normal(t.size), np.sin(2 * np.pi * 30.0 * t)])
    rows = np.lib.stride_tricks.sliding_window_view(u, N, axis=0)  # (k, 2, N)
    rows = rows.transpose(0, 2, 1).reshape(rows.shape[0], -1)  # sample-major, 2 inputs
    cov = rows.T @ rows
    assert input_own(cov, 2, np.array([30.0, 70.0]), FS).tolist() == [True, False]


@pytest.mark.slow
def test_swept_input_leaves_fewer_false_tracked_modes(monkeypatch):
    """Drawn records with a whole-record Schroeder multisine (a linear sweep through the band),
    defaults: fewer false tracked modes per estimate with test 5 than without it and never more
    at any estimate. 20 s records: at 12 s these 16 seeds had no false track with or without
    test 5 (round 29), nothing left for it to remove; at 20 s 0.023 vs 0.041 (8 seeds with a
    false track without it). The cost, not asserted: a mode is acquired only once the sweep has
    passed it (settled share 0.78 vs 0.79)."""
    from sysid_node.scenarios import draw_modal_scenario
    from sysid_node.suite import run_pipeline, score

    def run(seed):
        scn = draw_modal_scenario(np.random.default_rng(seed), duration_s=20.0,
                                  output_only=False, excitation_kind="multisine", change=None)
        return score(scn, run_pipeline(scn), seed)

    seeds = range(700, 716)
    with_test = [run(s) for s in seeds]
    monkeypatch.setattr(spurious, "INPUT_OWN_LEVEL", np.inf)
    without = [run(s) for s in seeds]
    false_with = np.mean([r.false_mean for r in with_test])
    false_without = np.mean([r.false_mean for r in without])
    assert false_with <= 0.9 * false_without, (false_with, false_without)
    assert max(r.false_max for r in with_test) <= max(r.false_max for r in without)
