"""The affine parameter_varying structure (validation.lpv_affine) and its gate: the scan against
the plain recursion, slopes recovered on drawn records of the hidden-effect suite, and the
placebo that keeps a signal moving like time from being credited."""

from __future__ import annotations

import numpy as np
import pytest
from sysid_node.validation import gates as G
from sysid_node.validation import suite as S
from sysid_node.validation.data import ValidationData
from sysid_node.validation.gates import Context
from sysid_node.validation.lpv_affine import tv_scan
from sysid_node.validation.workflow import Options, run_validation


def _recursion(log_lam: np.ndarray, v: np.ndarray, z0: complex) -> np.ndarray:
    out = np.empty(v.size, complex)
    z, lam = z0, np.exp(log_lam)
    for t in range(v.size):
        out[t] = z
        z = lam[t] * z + v[t]
    return out


@pytest.mark.parametrize("zeta, samples_per_cycle", [(0.002, 50.0), (0.05, 3.0), (0.4, 2.2)])
def test_scan_is_the_recursion(zeta, samples_per_cycle):
    """Chunks are cut by the decay: the heavily damped case crosses many chunk boundaries."""
    rng = np.random.default_rng(1)
    n = 6000
    w = 2 * np.pi / samples_per_cycle
    log_lam = -zeta * w + 1j * w * (1 + 0.1 * np.sin(np.arange(n) / 400))
    v = rng.standard_normal(n)
    ref = _recursion(log_lam, v, 0.3 - 0.2j)
    z = tv_scan(log_lam, v, 0.3 - 0.2j)
    assert np.max(np.abs(z - ref)) <= 1e-9 * np.max(np.abs(ref))


def _case(seed: int):
    kind = S.KINDS[(seed % 1000) % 4]
    sc = S.draw("parameter_varying", seed, kind)
    return sc, S._data(sc)


@pytest.mark.parametrize("seed", [1102007, 1102008, 1102013])  # sweep, white, coloured input
def test_added_schedule_recovers_the_slope(seed):
    sc, data = _case(seed)
    out = run_validation(
        data, Options(order=sc.nominal_order, add=[("parameter_varying", {"signal": "/airspeed"})])
    )
    am = out.current.affine
    assert am is not None
    f_true = sc.truth["frequency_hz"]
    k = int(np.argmin(np.abs(am.frequencies_hz() - f_true)))
    slope = am.frequency_slopes_hz()[k]
    assert slope == pytest.approx(sc.truth["slope_hz_per_unit"], rel=0.1)
    assert out.error_drop >= 0.4


def test_a_signal_that_moves_like_time_is_not_credited():
    """The same record with the candidate signals replaced by ramps in time: the schedule still
    lowers the error (the mode does move over the record), but time itself does as well, so
    the gate gives the signal nothing."""
    sc, data = _case(1102008)
    data.signals = {"/airspeed": 50.0 + 2.0 * data.t, "/rotor_speed": 10.0 - 0.1 * data.t}
    out = run_validation(data, Options(order=sc.nominal_order))
    ctx = Context(data, out.split, out.base, out.before, dict(data.signals))
    trials = G.schedule_trials(ctx)
    assert {name for name, _ in trials} == {"/airspeed", "/rotor_speed"}
    assert {decay for _, decay in trials} == set(G.DECAY_FORMS)
    for p, _ in trials.values():
        assert p == 1.0
    pv = next(h for h in out.hyps if h.effect == "parameter_varying")
    assert not pv.significant


def test_the_true_signal_is_credited():
    sc, data = _case(1102008)
    out = run_validation(data, Options(order=sc.nominal_order, auto=True))
    pv = next(h for h in out.hyps if h.effect == "parameter_varying")
    assert pv.significant and pv.parameters["signal"] == "/airspeed"
    assert out.added[:1] == ["parameter_varying"]


def test_the_decay_rate_does_not_follow_the_signal_by_default():
    """1102001 (coloured input, a 0.9 Hz mode at 104 Hz): with a free damping slope the fit
    bent the decay by 13 % per standard deviation of the signal to follow the disturbance's
    response on the estimation part and the held-out error fell by 48 %; with the decay rate
    kept (q1 = 0) it falls by 75 % (the clean twin's ceiling is 73 %)."""
    sc, data = _case(1102001)
    out = run_validation(
        data, Options(order=sc.nominal_order, add=[("parameter_varying", {"signal": "/airspeed"})])
    )
    am = out.current.affine
    assert am is not None and np.all(am.q1 == 0.0)
    assert out.error_drop >= 0.65


def _flutter_like(seed: int) -> tuple[ValidationData, np.ndarray]:
    """One 5 Hz mode at 200 Hz, white force in, whose damping falls from 4 % to 0.5 % and whose
    frequency falls 6 % as the airspeed rises (a mode approaching flutter); 3 % output noise."""
    rng = np.random.default_rng(seed)
    fs, n = 200.0, 16000
    t = np.arange(n) / fs
    speed = 60 + 8 * np.sin(2 * np.pi * t / 23) + 5 * np.sin(2 * np.pi * t / 9.0 + 1.0)
    x = (speed - speed.min()) / np.ptp(speed)
    f = 5.0 * (1 - 0.06 * x)
    zeta = 0.04 - 0.035 * x
    w = 2 * np.pi * f / fs
    u = rng.standard_normal(n)
    z = tv_scan(-zeta * w + 1j * w * np.sqrt(1 - zeta**2), u, 0j)
    y = np.imag(z)[:, None]
    y = y + 0.03 * np.std(y) * rng.standard_normal(y.shape)
    data = ValidationData(t, y, u[:, None], fs, ["y0"], ["u0"], {"/airspeed": speed})
    return data, zeta


@pytest.mark.parametrize("seed", [3, 4])
def test_a_damping_that_moves_with_the_signal_is_tried_and_kept(seed):
    """The trial also fits the decay rates moving with the signal (``decay=moving``) and keeps
    that when it lowers the validation error most: on a flutter-like record the damping
    changes eight-fold with airspeed and the constant-decay structure cannot follow it.
    (Seed 4: the shape refinement once stopped at its first step, its trust region started at
    the constant refit's hair-off-zero values.)"""
    data, _ = _flutter_like(seed)
    out = run_validation(data, Options(order=2, auto=True))
    pv = next(h for h in out.hyps if h.effect == "parameter_varying")
    assert pv.significant and pv.parameters.get("decay") == "moving"
    assert out.current.affine is not None and np.any(out.current.affine.q1 != 0.0)
    assert "the best of" in pv.trial_note
    # the report gives the damping's slope too: 4 % -> 0.5 % over the airspeed's range
    speed = data.signals["/airspeed"]
    true_slope = -0.035 / np.ptp(speed)
    assert pv.parameters["damping_slope_per_unit"] == pytest.approx(true_slope, rel=0.3)
    assert 0.005 < pv.parameters["mode_damping_ratio"] < 0.04


def test_decay_parameter_is_checked():
    from sysid_node.validation.augment import ModelSpec
    from sysid_node.validation.data import ValidationError

    spec = ModelSpec(order=2)
    assert spec.with_effect("parameter_varying", {"signal": "a", "decay": "moving"}).lpv_decay
    assert not spec.with_effect("parameter_varying", {"signal": "a"}).lpv_decay
    with pytest.raises(ValidationError, match="decay"):
        spec.with_effect("parameter_varying", {"signal": "a", "decay": "sideways"})


def test_a_schedule_both_decay_forms_see_is_found():
    """Unseen case 1102033 (coloured input, 14.3 Hz mode moving with airspeed, ceiling far above
    the detectable 10 %): both decay forms' trials lower the held-out error at p = 0.003 each,
    Bonferroni over the four trials (two signals x two forms) asked 0.0025 and nothing was
    found; Simes' test of the family fires (the two forms are fits of one structure)."""
    sc, data = _case(1102033)
    out = run_validation(data, Options(order=sc.nominal_order, auto=True))
    top = out.hyps[0]
    assert top.significant and top.effect == "parameter_varying"
    assert top.parameters["signal"] == "/airspeed"
    assert out.error_drop >= 0.5
