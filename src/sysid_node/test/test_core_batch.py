"""Batch DSRA (Appendix A) on the cobra stick model and on MIMO data, against the direct
eigen-analysis of the true system; model methods; order selection; stabilization; validation."""

import numpy as np
import pytest
from sysid_node.core import IdentifiedModel, InputError, identify, stabilization_diagram
from sysid_node.core.lti import ContinuousSystem, simulate
from sysid_node.scenarios.excitations import white
from sysid_node.scenarios.noise import add_output_noise
from sysid_node.scenarios.paper import cobra_stick_model

FS = 256.0
WIDE_DAMPING = (-0.01, 0.5)  # the 31.8 Hz mode of the CSM is undamped (zeta = 0)


def _match(modes, system):
    """Identified (f, zeta) nearest to each true mode of ``system`` (direct eigen-analysis)."""
    out = []
    for f_true, _ in system.modes():
        md = min(modes, key=lambda m: abs(m.frequency_hz - f_true))
        out.append((md.frequency_hz, md.damping_ratio))
    return np.array(out)


def _check_cobra(modes, system, f_tol, damping_pp=None):
    true = np.array(system.modes())
    est = _match(modes, system)
    assert np.all(np.abs(est[:, 0] / true[:, 0] - 1) <= f_tol), est
    if damping_pp is not None:  # the 23 and 36.6 Hz modes, in percentage points
        assert np.all(np.abs(est[[0, 2], 1] - true[[0, 2], 1]) * 100 <= damping_pp), est


def test_cobra_input_output_batch(cobra_data):
    system, u, y = cobra_data
    model = identify(y, u, fs=FS, order=6, block_rows=20, damping_bounds=WIDE_DAMPING)
    assert len(model.modes) == 3
    _check_cobra(model.modes, system, 0.005, damping_pp=0.15)
    # delta-method standard deviations are finite, positive and cover the error
    for md, (f_true, _) in zip(model.modes, system.modes(), strict=True):
        assert 0 < md.frequency_std_hz < 0.05
        assert abs(md.frequency_hz - f_true) <= 5 * md.frequency_std_hz + 1e-3
        assert md.shape.shape == (2,) and md.amplitude > 0


def test_cobra_output_only_batch(cobra_data):
    system, _, y = cobra_data
    model = identify(y, None, fs=FS, order=6, block_rows=20, damping_bounds=WIDE_DAMPING)
    assert model.n_inputs == 0 and model.B.shape == (6, 0)
    _check_cobra(model.modes, system, 0.01)


@pytest.mark.parametrize("method", ["aic", "bic"])
def test_information_criteria_pick_true_order(cobra_data, method):
    _, u, y = cobra_data
    assert identify(y, u, fs=FS, block_rows=20, order_method=method).order == 6


def test_gap_and_mdl_orders_are_valid(cobra_data):
    _, u, y = cobra_data
    for method in ("gap", "mdl"):
        n = identify(y[:4000], u[:4000], fs=FS, block_rows=10, order_method=method).order
        assert 1 <= n <= 18
    with pytest.raises(ValueError):
        identify(y, u, fs=FS, block_rows=10, order_method="xyz")


def test_model_predict_simulate_continuous_and_storage(cobra_data, tmp_path):
    system, u, y = cobra_data
    model = identify(y, u, fs=FS, order=6, block_rows=20, damping_bounds=WIDE_DAMPING)
    n = 5000
    y_clean = simulate(system, u[:n], FS)
    resid = y[:n] - model.predict(y[:n], u[:n])
    noise_std = 0.05 * y.std(axis=0)
    # one-step prediction error close to the measurement noise (after the filter transient)
    assert np.all(resid[500:].std(axis=0) < 2.0 * noise_std)
    free = model.simulate(u[:n])
    fit = 1 - np.linalg.norm(free[500:] - y_clean[500:]) / np.linalg.norm(y_clean[500:])
    assert fit > 0.8
    cont = model.to_continuous()
    assert isinstance(cont, ContinuousSystem)
    assert np.allclose(
        sorted(f for f, _ in cont.modes())[:3], [m.frequency_hz for m in model.modes], rtol=1e-6
    )
    path = tmp_path / "model.npz"
    model.save(path)
    again = IdentifiedModel.load(path)
    assert np.allclose(again.A, model.A) and again.fs == FS and again.order == 6
    assert [m.frequency_hz for m in again.modes] == [m.frequency_hz for m in model.modes]
    assert np.allclose(again.modes[0].shape, model.modes[0].shape)


def test_mimo_two_inputs_six_outputs():
    csm = cobra_stick_model()
    rng = np.random.default_rng(11)
    c6 = rng.standard_normal((6, 6)) * 300.0
    system = ContinuousSystem(csm.A, csm.B, c6, np.zeros((6, 2)))
    u = white(int(30 * FS), 2, rng)
    y = add_output_noise(simulate(system, u, FS), 0.05, rng)
    model = identify(y, u, fs=FS, order=6, block_rows=10, damping_bounds=WIDE_DAMPING)
    assert (model.n_inputs, model.n_outputs) == (2, 6)
    _check_cobra(model.modes, system, 0.005, damping_pp=0.15)
    assert all(md.shape.shape == (6,) for md in model.modes)


def test_stabilization_diagram_marks_true_modes_stable(cobra_data):
    system, u, y = cobra_data
    diag = stabilization_diagram(
        y[:8000],
        u[:8000],
        fs=FS,
        orders=range(4, 21, 2),
        block_rows=20,
        damping_bounds=WIDE_DAMPING,
    )
    arr = diag.as_arrays()
    for f_true, _ in system.modes():
        near = np.abs(arr["frequency_hz"] / f_true - 1) < 0.005
        assert np.sum(near & arr["stable"]) >= 4


@pytest.mark.parametrize(
    ("y", "u", "match"),
    [
        (np.zeros((500, 1)) + 1.0, None, "zero variance"),
        (np.ones((500, 2, 2)), None, "shape"),
        (np.r_[np.random.default_rng(0).standard_normal((499, 1)), [[np.nan]]], None, "NaN"),
        (np.random.default_rng(0).standard_normal((500, 1)), np.ones((400, 1)), "samples"),
        (np.random.default_rng(0).standard_normal((30, 1)), None, "at least"),
    ],
)
def test_bad_inputs_raise_one_line_errors(y, u, match):
    with pytest.raises(InputError, match=match) as err:
        identify(y, u, fs=100.0, block_rows=10)
    assert "\n" not in str(err.value)
    assert isinstance(err.value, ValueError)


def test_bad_rate_and_order_raise():
    y = np.random.default_rng(0).standard_normal((2000, 1))
    with pytest.raises(InputError):
        identify(y, fs=0.0)
    with pytest.raises(InputError):
        identify(y, fs=100.0, block_rows=10, order=50)
