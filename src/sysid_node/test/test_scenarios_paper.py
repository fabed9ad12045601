"""The paper's systems (scenarios.paper) and the vectorised simulator (core.lti,
scenarios.timevarying) against independent references."""

import numpy as np
import pytest
from scipy import signal
from sysid_node.core.lti import discretize, simulate
from sysid_node.scenarios.excitations import white
from sysid_node.scenarios.noise import add_output_noise
from sysid_node.scenarios.paper import (
    COBRA_ROTOR_MODE_TABLE2,
    cobra_stick_at,
    cobra_stick_model,
    paper_example_systems,
    paper_example_truth,
)
from sysid_node.scenarios.timevarying import simulate_switching


def test_paper_example_modes_are_2_4_6_hz():
    before, after = paper_example_systems()
    assert [round(f, 2) for f, _ in before.modes()] == [2.0, 4.0]
    assert [round(f, 2) for f, _ in after.modes()] == [2.0, 4.0, 6.0]
    assert np.isclose(after.modes()[2][1], 3.76 / (2 * np.sqrt(1420)))


def test_cobra_stick_model_frequencies():
    csm = cobra_stick_model()
    assert (csm.n_inputs, csm.n_outputs, csm.order) == (2, 2, 6)
    f = [f for f, _ in csm.modes()]
    assert np.allclose(f, [np.sqrt(w2) / (2 * np.pi) for w2 in (2.1e4, 4e4, 5.3e4)])
    assert np.round(f, 2).tolist() == [23.06, 31.83, 36.64]


def test_simulate_matches_scipy_dlsim_with_initial_state():
    csm = cobra_stick_model()
    rng = np.random.default_rng(1)
    u = white(3000, 2, rng)
    x0 = rng.standard_normal(6)
    ad, bd, cd, dd = discretize(csm, 256.0)
    _, y_ref, _ = signal.dlsim((ad, bd, cd, dd, 1 / 256.0), u, x0=x0)
    y = simulate(csm, u, 256.0, x0=x0)
    assert np.max(np.abs(y - y_ref)) <= 1e-9 * np.max(np.abs(y_ref))


def test_switching_carries_state_and_new_mode_starts_at_rest():
    before, after = paper_example_systems()
    rng = np.random.default_rng(2)
    u = white(400, 1, rng)
    y = simulate_switching([(0.0, before), (2.0, after)], u, 100.0)
    y_before = simulate(before, u, 100.0)
    assert np.allclose(y[:200], y_before[:200])
    # from the switch on: the old modes continue, the 6 Hz mode starts from zero state
    ad, bd, cd, dd = discretize(after, 100.0)
    _, _, x = signal.dlsim(discretize(before, 100.0) + (1 / 100.0,), u[:201])
    x0 = np.concatenate([x[200], [0.0, 0.0]])
    _, y_ref, _ = signal.dlsim((ad, bd, cd, dd, 1 / 100.0), u[200:], x0=x0)
    assert np.allclose(y[200:], y_ref, atol=1e-10)


def test_output_noise_fraction():
    rng = np.random.default_rng(3)
    y = np.column_stack([np.sin(np.arange(100000) * 0.1), 50 * np.cos(np.arange(100000) * 0.3)])
    n = add_output_noise(y, 0.05, rng) - y
    assert np.allclose(n.std(axis=0) / y.std(axis=0), 0.05, rtol=0.02)


def test_cobra_rotor_mode_follows_table_2():
    assert np.allclose(cobra_stick_at(32.0).A, cobra_stick_model().A)
    for speed, f, z in COBRA_ROTOR_MODE_TABLE2:
        modes = cobra_stick_at(speed).modes()
        assert min(abs(m[0] - f) for m in modes) < 1e-9 * f
        (zeta,) = [m[1] for m in modes if abs(m[0] - f) < 1e-6]
        assert zeta == pytest.approx(z, abs=1e-12)
    # the 23 and 36.6 Hz modes stay where they are
    f38 = [m[0] for m in cobra_stick_at(38.0).modes()]
    assert np.round(f38, 2).tolist() == [23.06, 36.64, 37.99]


def test_paper_truth_has_the_6_hz_mode_from_20_s():
    truth = paper_example_truth()
    assert [m.name for m in truth] == ["mode_1", "mode_2", "mode_3"]
    f, _ = truth[2].at([19.9, 20.0, 39.0, 40.1])
    assert np.isnan(f[0]) and np.isnan(f[3]) and np.allclose(f[1:3], 6.0, atol=0.01)
