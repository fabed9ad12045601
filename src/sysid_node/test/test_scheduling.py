"""SchedulePredictor: the scheduling signal's value at a stamp and the LPV-predicted modes."""

import math

import numpy as np
from sysid_node.core.lpv import LpvModel
from sysid_node.scenarios.csm_rotor import csm_at
from sysid_node.scheduling import SchedulePredictor, model_error, predictor_from

S = 1_000_000_000


def predictor(max_age_s=1.0):
    pts = np.arange(32.0, 38.01, 1.0)
    return SchedulePredictor(LpvModel.from_systems(pts, [csm_at(p) for p in pts]), max_age_s)


def test_value_held_from_samples_at_or_before_the_stamp_and_stale():
    p = predictor()
    assert math.isnan(p.value_at(5 * S))
    p.push(np.array([10, 11, 12]) * S // 10, [33.0, 34.0, 35.0])
    assert p.value_at(int(1.05 * S)) == 33.0  # never a later sample: live = offline
    assert p.value_at(int(1.1 * S)) == 34.0
    assert p.value_at(int(1.5 * S)) == 35.0  # newest sample held
    assert math.isnan(p.value_at(int(2.3 * S)))  # older than max_age
    assert math.isnan(p.value_at(int(0.5 * S)))  # before the first sample
    p.push(np.array([11, 13, 14]) * S // 10, [40.0, np.nan, 36.0])  # old stamp, NaN: dropped
    assert p.rejected == 2 and p.value_at(int(1.4 * S)) == 36.0


def test_chunking_does_not_change_the_values():
    t = np.arange(0, 200) * S // 100
    v = 33.0 + 0.01 * np.arange(200)
    whole, parts = predictor(), predictor()
    whole.push(t, v)
    for a in range(0, 200, 7):
        parts.push(t[a:a + 7], v[a:a + 7])
    stamps = np.arange(0, 2 * S, S // 37)
    np.testing.assert_allclose([whole.value_at(s) for s in stamps],
                               [parts.value_at(s) for s in stamps])


def test_channel_chosen_by_the_model_scheduling_name():
    pts = np.arange(32.0, 38.01, 1.0)
    lpv = LpvModel.from_systems(pts, [csm_at(p) for p in pts], scheduling="rotor_speed",
                                unit="Hz")
    p = SchedulePredictor(lpv)
    p.push(np.array([S]), np.array([[80.0, 34.0]]), names=("airspeed[m/s]", "rotor_speed[Hz]"))
    assert p.value_at(S) == 34.0


def test_outside_the_model_range_nothing_is_predicted():
    p = predictor()
    p.push(np.array([S, 2 * S]), [36.0, 39.0])
    theta, modes = p.predict(S)
    assert theta == 36.0 and len(modes) == 3 and p.status()["lpv_in_range"] is True
    theta, modes = p.predict(2 * S)
    assert theta == 39.0 and modes == [] and p.status() == {
        "scheduling_value": 39.0, "scheduling_age_s": 0.0, "lpv_in_range": False}
    # without a model: the value only
    q = SchedulePredictor(None)
    q.push(np.array([S]), [34.0])
    assert q.predict(int(1.5 * S)) == (34.0, []) and q.status()["scheduling_age_s"] == 0.5


def test_model_file_errors_are_one_line(tmp_path):
    assert "does not exist" in model_error(str(tmp_path / "none.npz"))
    bad = tmp_path / "bad.npz"
    bad.write_bytes(b"PK\x03\x04 not a zip")
    reason = model_error(str(bad))
    assert reason.startswith("cannot load LPV model") and "\n" not in reason
    other = tmp_path / "other.npz"
    np.savez(other, x=np.zeros(3))
    assert "cannot load LPV model" in model_error(str(other))
    good = tmp_path / "csm.npz"
    predictor().lpv.save(good)
    assert model_error(str(good)) == ""
    assert predictor_from({"scheduling_topic": ""}) is None
    p = predictor_from({"scheduling_topic": "rotor_speed", "lpv_model": str(good),
                        "scheduling_timeout": 0.5})
    assert p.max_age_ns == S // 2 and p.lpv.n_modes == 3


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
