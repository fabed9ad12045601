"""LPV model (2) from local models: the paper's interpolation, the common modal basis (local
models in arbitrary state bases give the same LPV model), predicted modes between operating
points, the file format."""

import json

import numpy as np
import pytest
from sysid_node.core.inputs import InputError
from sysid_node.core.lpv import LpvModel, interpolation_weights, lpv_errors, match_modes
from sysid_node.core.lti import ContinuousSystem
from sysid_node.scenarios.csm_rotor import csm_at

POINTS = np.arange(32.0, 38.01, 1.0)


def scrambled(sys: ContinuousSystem, rng: np.random.Generator) -> ContinuousSystem:
    """The same system in a random state basis."""
    t = rng.standard_normal((sys.order, sys.order)) + 3 * np.eye(sys.order)
    ti = np.linalg.inv(t)
    return ContinuousSystem(ti @ sys.A @ t, ti @ sys.B, sys.C @ t, sys.D)


@pytest.fixture(scope="module")
def lpv():
    return LpvModel.from_systems(POINTS, [csm_at(p) for p in POINTS], scheduling="rotor_speed",
                                 unit="Hz")


def test_paper_interpolation_weights():
    w = interpolation_weights([32.0, 32.25, 33.0, 40.0, 30.0], np.array([32.0, 33.0, 34.0]))
    np.testing.assert_allclose(w, [[1, 0, 0], [0.75, 0.25, 0], [0, 1, 0], [0, 0, 1], [1, 0, 0]])


def test_local_models_are_reproduced(lpv):
    f, z = lpv.modes(POINTS)
    for i, p in enumerate(POINTS):
        pairs = match_modes(list(zip(f[i], z[i], strict=True)), csm_at(p).modes())
        for (fe, ze), (ft, zt) in zip(pairs, csm_at(p).modes(), strict=True):
            assert abs(fe - ft) < 1e-9 * ft and abs(ze - zt) < 1e-9


def test_predicted_modes_between_points_within_one_percent(lpv):
    """1 Hz apart, through the coalescence and the unstable band: frequency within 1 %."""
    theta = np.linspace(32.0, 38.0, 97)
    ef, ez = lpv_errors(lpv, lambda t: csm_at(t).modes(), theta)
    assert ef.max() < 0.01
    assert ez.max() < 0.005  # damping, absolute (0.5 percentage points near the coalescence)


def test_common_basis_makes_the_interpolation_basis_free(lpv):
    """Local models in random state bases give the same LPV matrices (the modal basis is
    unique); interpolating the raw matrices would not even keep the modes."""
    rng = np.random.default_rng(3)
    mixed = [scrambled(csm_at(p), rng) for p in POINTS]
    other = LpvModel.from_systems(POINTS, mixed)
    for name in ("A", "B", "C", "D"):
        np.testing.assert_allclose(getattr(other, name), getattr(lpv, name), atol=1e-6 * max(
            1.0, np.abs(getattr(lpv, name)).max()))
    raw = 0.5 * (mixed[1].A + mixed[2].A)  # raw interpolation at 33.5 Hz
    f_raw = np.sort(np.abs(np.linalg.eigvals(raw).imag))[::2] / (2 * np.pi)
    f_true = np.array([f for f, _ in csm_at(33.5).modes()])
    assert np.max(np.abs(np.sort(f_raw) / np.sort(f_true) - 1)) > 0.01
    ef, _ = lpv_errors(other, lambda t: csm_at(t).modes(), np.array([33.5]))
    assert ef.max() < 0.01


def test_save_and_load(lpv, tmp_path):
    path = tmp_path / "csm.lpv.npz"
    lpv.save(path)
    back = LpvModel.load(path)
    np.testing.assert_array_equal(back.A, lpv.A)
    assert back.scheduling == "rotor_speed" and back.unit == "Hz" and back.n_modes == 3
    with np.load(path) as z:
        meta = json.loads(str(z["meta"]))
    assert meta["format"] == "sysid_lpv" and "beta" in meta["interpolation"]
    np.testing.assert_allclose(back.modes(35.5)[0], lpv.modes(35.5)[0])


def test_bad_files_and_models(tmp_path):
    bad = tmp_path / "bad.npz"
    np.savez(bad, points=np.zeros(1))
    with pytest.raises(InputError, match="cannot load LPV model"):
        LpvModel.load(bad)
    with pytest.raises(InputError, match="cannot load LPV model"):
        LpvModel.load(tmp_path / "missing.npz")
    two_modes = ContinuousSystem(csm_at(32).A[:4, :4], csm_at(32).B[:4], csm_at(32).C[:, :4],
                                 csm_at(32).D)
    with pytest.raises(InputError, match="numbers of"):
        LpvModel.from_systems([32.0, 33.0], [csm_at(32.0), two_modes])
    with pytest.raises(InputError, match="distinct"):
        LpvModel.from_systems([32.0, 32.0], [csm_at(32.0), csm_at(32.0)])
