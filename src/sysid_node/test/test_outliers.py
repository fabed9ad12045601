"""Finite outliers do not poison the estimator (#13 item 1, estimator part): a 1 s burst of
outputs x 1e12 and single spikes of 1e3 to 1e6 sigma in an output or in the excitation are
rejected by the innovation gate of RecursiveDSRA, counted, kept out of the change detection,
and reported as ``health = 1`` (degraded) with a reason while they happen; the modes stay right.
Through the same Pipeline the node and ``offline`` use, on the paper's Sec. II example."""

from __future__ import annotations

import numpy as np
import pytest
from sysid_node.core.recursive import GATE_WILD_FACTOR
from sysid_node.pipeline import Pipeline
from sysid_node.scenarios.paper import paper_example_data

T0 = 1_700_000_000 * 10**9
FS = 100.0
SETTINGS = {"freq_max": 10.0, "max_modes": 5}  # the paper's band and mode count


def _run(y, u, settings=SETTINGS):
    stamps = T0 + np.round(np.arange(len(y)) / FS * 1e9).astype(np.int64)
    pl = Pipeline(settings)
    recs = []
    for a in range(0, len(y), 10):
        pl.push_output(stamps[a : a + 10], y[a : a + 10])
        pl.push_input(stamps[a : a + 10], u[a : a + 10])
        recs += pl.step()
    return pl, recs + pl.step(flush=True)


def _t(r) -> float:
    return (r.stamp_ns - T0) * 1e-9


def _right(r) -> bool:
    tracked = [m.frequency_hz for m in r.modes if m.status == "tracked"]
    return all(any(abs(f / g - 1) <= 0.02 for f in tracked) for g in (2.0, 4.0))


@pytest.fixture(scope="module")
def clean():
    _, u, y = paper_example_data(duration_s=18.0, fs=FS, seed=4, switch_time_s=100.0)
    return u, y


@pytest.fixture(scope="module")
def clean_changes(clean):
    """Changes the detection reports on the record without outliers."""
    u, y = clean
    pl, recs = _run(y, u)
    assert pl.estimator.status().outliers_rejected == 0
    assert all(r.health == 0 for r in recs if _t(r) >= 4.0)
    return pl.estimator.change_count


CASES = {
    "burst_1s_x1e12": lambda u, y: (u, _burst(y)),
    "output_spike_1e3": lambda u, y: (u, _spike(y, 1e3)),
    "output_spike_1e6": lambda u, y: (u, _spike(y, 1e6)),
    "input_spike_1e3": lambda u, y: (_spike(u, 1e3), y),
    "input_spike_1e6": lambda u, y: (_spike(u, 1e6), y),
}


def _burst(x):
    x = x.copy()
    x[int(10 * FS) : int(11 * FS)] *= 1e12
    return x


def _spike(x, sigmas):
    x = x.copy()
    x[int(10 * FS)] += sigmas * np.std(x)
    return x


@pytest.mark.parametrize("case", sorted(CASES))
def test_outliers_are_rejected_counted_and_reported(clean, clean_changes, case):
    u, y = CASES[case](*clean)
    pl, recs = _run(y, u)
    status = pl.estimator.status()
    assert status.outliers_rejected >= 1
    # a spike is not a change of the structure: no more changes than without it
    assert pl.estimator.change_count == clean_changes
    assert pl.estimator.level_restarts == 0
    # degraded, with the reason, while it happens (within 1 s of the first bad sample)
    during = [r for r in recs if 10.0 <= _t(r) <= 11.0]
    assert during and all(r.health == 1 and "outliers" in r.health_reason for r in during)
    # and not before; ok again once the reference window has passed
    assert all(r.health == 0 for r in recs if 4.0 <= _t(r) < 10.0)
    assert all(r.health == 0 for r in recs if _t(r) >= 15.0)
    # the modes stay right through and after it
    after = [r for r in recs if _t(r) >= 6.0]
    assert np.mean([_right(r) for r in after]) >= 0.95, case


def test_a_lasting_new_signal_level_restarts_the_estimator(clean):
    """Outputs x 1e6 from 8 s on for good (a gain change, not an outlier): after the reference
    window of rejected samples the estimator restarts on the new level and finds the modes."""
    u, y = clean
    y = y.copy()
    y[int(8 * FS) :] *= 1e6
    pl, recs = _run(y, u)
    assert pl.estimator.level_restarts == 1
    assert _right(recs[-1])



def test_a_wild_gate_prediction_is_not_used(clean):
    """A realization from few samples per dimension can give the gate's predictor wild
    coefficients; its predictions must not replace a rejected sample (the next predictions
    would build on it and overflow): the gate predicts 0 there instead."""
    u, y = clean
    pl, _ = _run(y[:900], u[:900])
    est = pl.estimator
    est.flush()
    hist = np.hstack([u[900:1000], y[900:1000]]) / np.r_[est._su, est._sy]  # scaled [u, y]
    sane = est._gate_prediction(hist, est.block_rows)
    assert np.all(np.abs(sane) < 10.0) and np.any(sane != 0.0)
    est._theta1 = est._theta1 * 1e6
    level = max(np.abs(hist[:, est.n_inputs:]).max(), 1.0)
    wild = est._gate_prediction(hist, est.block_rows, level)
    assert np.all(np.abs(wild) <= GATE_WILD_FACTOR * level)
    with np.errstate(over="raise", invalid="raise"):
        est.update(u[900:1200], _spike(y, 1e6)[900:1200])  # the spike at 10 s
        est.flush()
    assert est.status().outliers_rejected >= 1
