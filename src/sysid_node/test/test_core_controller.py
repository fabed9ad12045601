"""Known controller, LQG design with python-control and the checks before closing a loop; the
rotor-speed cobra stick model and its closed-loop experiment."""

import numpy as np
import pytest
from sysid_node.core.controller import (
    DiscreteController,
    check_closed_loop,
    closed_loop,
    closed_loop_poles,
    design_lqg,
    plant_ss,
)
from sysid_node.core.inputs import InputError
from sysid_node.core.lti import discretize
from sysid_node.scenarios.closedloop import closed_loop_matrices
from sysid_node.scenarios.csm_rotor import (
    CSM_FS,
    closed_loop_experiment,
    csm_at,
)


def plant(theta):
    return plant_ss(*discretize(csm_at(theta), CSM_FS), CSM_FS)


def test_csm_is_unstable_only_near_36_hz():
    damping = {th: min(z for _, z in csm_at(th).modes()) for th in np.arange(32, 38.01, 0.25)}
    unstable = [th for th, z in damping.items() if z < 0]
    assert unstable and 35.5 <= min(unstable) and max(unstable) <= 37.5
    assert abs(min(f for f, _ in csm_at(33.0).modes() if f > 30) - 33.0) < 0.1


def test_lqg_design_is_strictly_proper_and_checked():
    g = plant(35.0)
    k = design_lqg(g, (30.0, 40.0), control_weight=1.0)
    assert not k.D.any() and k.order == 6 and k.fs == CSM_FS
    own = check_closed_loop(g, k, 0.0005, 3.0, 20.0)
    assert own.ok and own.stable and own.gain_margin_db > 3 and own.phase_margin_deg > 20
    # the same controller stabilises the open-loop unstable plant 1 Hz further
    assert min(z for _, z in csm_at(36.0).modes()) < 0
    assert check_closed_loop(plant(36.0), k).stable
    # the sign flipped: unstable, and said so
    bad = DiscreteController(k.A, k.B, -k.C, k.D, k.fs)
    chk = check_closed_loop(plant(36.0), bad)
    assert not chk.ok and "unstable" in chk.reason
    with pytest.raises(InputError, match="no mode"):
        design_lqg(g, (100.0, 120.0))


def test_simulator_loop_equals_the_designed_loop():
    """The experiment's simulator closes exactly the loop that python-control's
    feedback(G, K, +1) describes."""
    k = design_lqg(plant(35.0), (30.0, 40.0), control_weight=1.0)
    p1 = np.sort_complex(closed_loop_poles(plant(36.0), k))
    a = closed_loop_matrices(csm_at(36.0), k, delay=0)[0]
    p2 = np.linalg.eigvals(a)
    p2 = np.sort_complex(p2[np.abs(p2) > 1e-9])
    np.testing.assert_allclose(p1, p2, atol=1e-10)
    rec = closed_loop_experiment(csm_at(36.0), k, 2.0, np.random.default_rng(0),
                                 disturbance_std=0.0, noise_fraction=0.0)
    cl = closed_loop(plant(36.0), k)  # r -> [y; u]
    _, yu = __import__("control").forced_response(cl, U=rec.r.T)
    np.testing.assert_allclose(yu.T, np.hstack([rec.y, rec.u]), atol=1e-9 * np.abs(yu).max())


def test_controller_file_round_trip(tmp_path):
    k = design_lqg(plant(33.0), (30.0, 40.0))
    k.save(tmp_path / "k.npz")
    back = DiscreteController.load(tmp_path / "k.npz")
    np.testing.assert_array_equal(back.A, k.A)
    assert back.fs == k.fs and back.n_sensors == 2 and back.n_actuators == 2
    with pytest.raises(InputError, match="cannot load controller"):
        DiscreteController.load(tmp_path / "none.npz")
