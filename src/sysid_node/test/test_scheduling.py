"""SchedulePredictor: the scheduling signal's value at a stamp and the LPV-predicted modes."""

import math

import numpy as np
from sysid_node.core.lpv import LpvModel
from sysid_node.scenarios.csm_rotor import csm_at
from sysid_node.scheduling import SchedulePredictor

S = 1_000_000_000


def predictor(max_age_s=1.0):
    pts = np.arange(32.0, 38.01, 1.0)
    return SchedulePredictor(LpvModel.from_systems(pts, [csm_at(p) for p in pts]), max_age_s)


def test_value_interpolated_held_and_stale():
    p = predictor()
    assert math.isnan(p.value_at(5 * S))
    p.push(np.array([10, 11, 12]) * S // 10, [33.0, 34.0, 35.0])
    assert p.value_at(int(1.05 * S)) == 33.5  # between two samples
    assert p.value_at(int(1.5 * S)) == 35.0  # newest sample held
    assert math.isnan(p.value_at(int(2.3 * S)))  # older than max_age
    assert math.isnan(p.value_at(int(0.5 * S)))  # before the first sample
    p.push(np.array([11, 13, 14]) * S // 10, [40.0, np.nan, 36.0])  # old stamp, NaN: dropped
    assert p.rejected == 2 and p.value_at(int(1.4 * S)) == 36.0


def test_predicted_modes_follow_the_lpv_model():
    p = predictor()
    t = np.arange(0, 100) * S // 50
    theta = 33.0 + 0.02 * np.arange(100)  # 33 -> 35 Hz in 2 s
    p.push(t, theta)
    value, modes = p.predict(int(t[-1]))
    assert abs(value - theta[-1]) < 1e-12
    f, z = p.lpv.modes(value)
    assert [m.id for m in modes] == [1, 2, 3]
    np.testing.assert_allclose([m.frequency_hz for m in modes], f[0])
    np.testing.assert_allclose([m.damping_ratio for m in modes], z[0])
    assert all(m.status == "tracked" and m.shape.shape == (2,) for m in modes)
    # noise-free straight-line schedule and no identified stds: no uncertainty to report
    assert all(math.isnan(m.frequency_std_hz) for m in modes)
    noisy = predictor()
    noisy.push(t, theta + 0.05 * np.random.default_rng(0).standard_normal(100))
    _, modes = noisy.predict(int(t[-1]))
    moving = min(modes, key=lambda m: abs(m.frequency_hz - 35.0))
    assert 0.02 < moving.frequency_std_hz < 0.1  # d f / d theta ~ 1 times the 0.05 Hz scatter
    assert predictor().predict(5 * S) == (math.nan, [])
