"""The scenarios package: simulators against per-sample references, excitations, faults, the
random draws' truth and ranges, and the committed hidden-effect bags against their generator."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from scipy import signal
from sysid_node.core.controller import DiscreteController
from sysid_node.core.lti import discretize, simulate
from sysid_node.scenarios import draw_clean, draw_hidden_effect, draw_modal_scenario, drifting_mode
from sysid_node.scenarios import excitations as X
from sysid_node.scenarios import faults as F
from sysid_node.scenarios.bags import HIDDEN_SCENARIOS, HIDDEN_SEEDS, hidden_effect
from sysid_node.scenarios.closedloop import closed_loop_matrices, simulate_closed_loop
from sysid_node.scenarios.effects import EFFECTS, add_mode, mode_blocks, simulate_cubic_stiffness
from sysid_node.scenarios.structures import (
    ModalStructure,
    combine,
    rigid_body_structure,
    scheduled_mode,
)
from sysid_node.scenarios.timevarying import simulate_piecewise, simulate_scheduled

from sysid_node import bag_io

HIDDEN_BAGS = Path(__file__).resolve().parents[3] / "bags" / "hidden"


def _loop_reference(systems, keys, u, fs):
    """Plain per-sample state recursion (the reference for the block simulators)."""
    x = np.zeros(systems[keys[0]].order)
    y = np.empty((len(u), systems[keys[0]].n_outputs))
    for k, key in enumerate(keys):
        ad, bd, cd, dd = discretize(systems[key], fs)
        y[k] = cd @ x + dd @ u[k]
        x = ad @ x + bd @ u[k]
    return y


def test_modal_structure_sum_of_modes_is_the_system_response():
    rng = np.random.default_rng(0)
    st = combine(ModalStructure([3.0, 7.5], [0.02, 0.01], rng.normal(size=(2, 2)),
                                rng.normal(size=(3, 2))),
                 rigid_body_structure(0.8, 0.1, [1.0, 0.5], [1.0, 0.2, -0.3]))
    assert st.kinds == ("structural", "structural", "rigid_body")
    u = rng.standard_normal((2000, 2))
    y_modes = st.simulate(u, 100.0)
    y_all = simulate(st.system(), u, 100.0)
    assert np.allclose(y_modes, y_all, atol=1e-10 * np.abs(y_all).max())
    assert [round(f, 6) for f, _ in st.system().modes()] == [0.8, 3.0, 7.5]


def test_piecewise_and_scheduled_match_a_per_sample_recursion():
    fs = 50.0
    rng = np.random.default_rng(1)
    u = rng.standard_normal((400, 1))
    v = np.interp(np.arange(400) / fs, [0, 2, 6, 8], [40, 40, 80, 60])
    systems = {k: mode_blocks([(2.0, 0.02), (4.0 + (k / 5 - 60) / 20, 0.02)])
               for k in np.unique(np.round(v * 5).astype(int))}
    keys = np.round(v * 5).astype(int)
    ref = _loop_reference(systems, keys, u, fs)
    y = simulate_scheduled(lambda val: systems[int(round(val * 5))], v, u, fs, resolution=0.2)
    assert np.allclose(y, ref, atol=1e-9 * np.abs(ref).max())
    y2, x_end = simulate_piecewise(lambda k: systems[k], keys, u, fs)
    assert np.allclose(y2, y) and x_end.shape == (4,)


def test_scheduled_mode_follows_the_schedule():
    st = ModalStructure([3.0, 8.0], [0.02, 0.01], [[1.0], [0.5]], [[1.0, 1.0]])
    system_at = scheduled_mode(st, 1, lambda v: 8.0 + 0.1 * (v - 50.0), lambda v: 0.01)
    assert [round(f, 6) for f, _ in system_at(60.0).modes()] == [3.0, 9.0]
    u = np.random.default_rng(11).standard_normal((300, 1))
    y = simulate_scheduled(system_at, np.full(300, 60.0), u, 100.0, resolution=0.5)
    np.testing.assert_allclose(y, simulate(system_at(60.0), u, 100.0), atol=1e-12)


@pytest.mark.parametrize("lag", [0, 2])
def test_closed_loop_matches_a_per_sample_loop(lag):
    """u = r + C xc + D e with e = y delayed ``lag`` samples (0: the controller reads y_k and
    acts from k + 1 on, D = 0)."""
    fs = 100.0
    plant = mode_blocks([(2.0, 0.02), (4.0, 0.05)])
    ctrl = DiscreteController(np.array([[0.9]]), np.array([[1.0]]), np.array([[-0.5]]),
                              np.array([[-1.5 if lag else 0.0]]), fs)
    rng = np.random.default_rng(2)
    r, w, v = (rng.standard_normal((500, 1)) * s for s in (1.0, 0.5, 0.01))
    y, u = simulate_closed_loop(plant, ctrl, r, w=w, v=v, delay=lag)
    ad, bd, cd, dd = discretize(plant, fs)
    x, xc, past = np.zeros(4), np.zeros(1), [np.zeros(1)] * lag
    y_ref, u_ref = np.empty_like(y), np.empty_like(u)
    for k in range(500):
        e = past[-1] if lag else np.zeros(1)
        u_ref[k] = r[k] + ctrl.C @ xc + ctrl.D @ e
        y_ref[k] = cd @ x + dd @ (u_ref[k] + w[k]) + v[k]
        e = e if lag else y_ref[k]
        x, xc = ad @ x + bd @ (u_ref[k] + w[k]), ctrl.A @ xc + ctrl.B @ e
        past = [y_ref[k].copy(), *past[:-1]]
    assert np.allclose(y, y_ref, atol=1e-9) and np.allclose(u, u_ref, atol=1e-9)


def test_a_direct_feedthrough_controller_needs_a_delay():
    ctrl = DiscreteController.static(-1.0, 100.0)
    with pytest.raises(ValueError, match="strictly proper"):
        closed_loop_matrices(mode_blocks([(2.0, 0.02)]), ctrl, delay=0)


def test_cubic_stiffness_converges_and_vanishes_without_the_spring():
    system = mode_blocks([(2.0, 0.02), (4.0, 0.05)], displacement=True)
    u = np.random.default_rng(3).standard_normal((1000, 1))
    lin = simulate(system, u, 50.0)
    scale = np.abs(lin).max()
    assert np.allclose(simulate_cubic_stiffness(system, u, 50.0, 0.0), lin, atol=1e-4 * scale)
    rk4 = simulate_cubic_stiffness(system, u, 50.0, 3e6)
    fine = simulate_cubic_stiffness(system, u, 50.0, 3e6, substeps=16)
    assert np.std(rk4 - lin) > 0.1 * np.std(lin)  # the spring matters
    assert np.std(fine - rk4) < 0.01 * np.std(rk4 - lin)  # 4 substeps: converged


def test_add_mode_gives_the_paper_6_hz_system():
    from sysid_node.scenarios.paper import paper_example_systems

    sys_a, sys_b = paper_example_systems()
    f, z = sys_b.modes()[2]
    assert np.allclose(add_mode(sys_a, f, z).A, sys_b.A)


@pytest.mark.parametrize("kind", [*X.KINDS, "random_multisine"])
def test_excitation_unit_rms_and_in_band(kind):
    fs, n = 200.0, 8000
    u = X.excitation(kind, n, 2, fs, np.random.default_rng(4), (5.0, 40.0))
    assert u.shape == (n, 2) and np.allclose(np.std(u, axis=0), 1.0, rtol=0.05)
    f, p = signal.welch(u[:, 0], fs, nperseg=1024)
    inside = (f >= 4.0) & (f <= 42.0)
    share = p[inside].sum() / p.sum()
    assert share > (0.15 if kind == "white" else 0.9)


def test_multisine_schroeder_crest_factor_and_uncorrelated_inputs():
    u = X.multisine(4000, 2, 100.0, (1.0, 20.0))
    assert np.max(np.abs(u)) < 2.5  # Schroeder phases: crest factor far below sqrt(2 K)
    assert abs(np.corrcoef(u.T)[0, 1]) < 0.05


def test_random_phase_multisine_excites_the_whole_band_at_every_instant():
    """The Schroeder multisine of a record-long period brings its lines in turn (a sweep): in
    the first 2 s of 20 s nothing above 10 Hz of its 1-40 Hz band; the random-phase one has
    every line in every 2 s window (power share above 10 Hz as over the whole record)."""
    fs, n = 200.0, 4000
    band = (1.0, 40.0)

    def upper_share(u):
        f, p = signal.welch(u, fs, nperseg=256)
        return p[f > 10.0].sum() / p.sum()

    schroeder = X.multisine(n, 1, fs, band)[:, 0]
    rand = X.excitation("random_multisine", n, 1, fs, np.random.default_rng(3), band)[:, 0]
    whole = upper_share(rand)
    assert 0.6 < whole < 0.9  # 30 of the 39 Hz
    assert upper_share(schroeder[:400]) < 0.05
    assert all(abs(upper_share(rand[a:a + 400]) - whole) < 0.1 for a in range(0, n, 400))


def test_faults_mark_what_they_touch():
    s = F.Stream.uniform(np.arange(20.0)[:, None] * [1.0, -1.0], 10.0, names=("a", "b"))
    rng = np.random.default_rng(5)
    assert np.isnan(F.nonfinite(s, indices=[3]).values[3]).all()
    assert F.spikes(s, rng, 2).altered.sum() == 2
    assert F.burst(s, 4, 2).values[5, 0] == 5e12
    clipped = F.saturate(s, -10.0, 10.0)
    assert clipped.values.max() == 10.0 and clipped.altered.sum() == 9
    assert (F.stuck(s, 1, 10).values[10:, 1] == -10.0).all()
    assert (F.dead(s, 0, 5).values[5:, 0] == 0.0).all()
    assert len(F.gap(s, 5, 3)) == 17
    dup = F.duplicate(s, [4])
    assert len(dup) == 21 and dup.stamps_ns[4] == dup.stamps_ns[5] and dup.altered[5]
    assert np.diff(F.out_of_order(s, [6]).stamps_ns)[6] < 0
    assert F.future_stamp(s, 7, 10.0).stamps_ns[7] - s.stamps_ns[7] == 10**10
    assert (np.diff(F.stamp_jump(s, 10, -5.0).stamps_ns) < 0).sum() == 1
    assert np.diff(F.rate_change(s, 10, 20.0).stamps_ns)[-1] == 5 * 10**7
    assert F.reorder_channels(s, [1, 0]).names == ("b", "a")
    assert F.rename_channels(s, {"a": "x"}).names == ("x", "b")
    before, after = F.change_channel_count(s, 12, 3)
    assert before.values.shape == (12, 2) and after.values.shape == (8, 3)


@pytest.fixture(scope="module")
def modal_draws():
    return [draw_modal_scenario(np.random.default_rng(seed), duration_s=20.0)
            for seed in range(12)]


def test_modal_draws_within_the_documented_ranges(modal_draws):
    changes = set()
    for s in modal_draws:
        assert 100 <= s.fs <= 1000 and 1 <= s.structure.n_modes <= 8
        assert 1 <= s.y.shape[1] <= 3 and (s.u is None) == s.output_only
        f, z = s.structure.frequencies_hz, s.structure.damping_ratios
        assert f.max() <= 0.4 * s.fs and np.all((z >= 0.002) & (z <= 0.05))
        assert np.all(np.diff(f) / f[1:] > 0.04)
        assert 0.02 <= s.noise_fraction <= 0.10 and np.all(np.isfinite(s.y))
        truth_end = s.modes_at(s.t[-1])
        assert len(truth_end) == s.structure.n_modes
        changes.add(s.change and s.change["kind"])
    assert changes >= {None, "appear", "jump"}
    assert {s.output_only for s in modal_draws} == {True, False}


def test_modal_draw_is_deterministic_per_seed():
    a, b = (draw_modal_scenario(np.random.default_rng(42), duration_s=10.0) for _ in range(2))
    np.testing.assert_allclose(a.y, b.y, rtol=1e-12, atol=1e-12 * np.abs(a.y).max())
    assert a.modes == b.modes


def test_appearing_mode_is_absent_before_its_time():
    rng = np.random.default_rng(7)
    s = draw_modal_scenario(rng, n_modes=2, change="appear", output_only=False, fs=200.0,
                            duration_s=20.0, noise=(0.0, 1e-12))
    tc = s.change["time_s"]
    (name,) = [m.name for m in s.modes if m.t_s[0] > 0]
    assert s.change["mode"] == name and len(s.modes_at(tc - 0.1)) == 1
    assert len(s.modes_at(tc + 0.1)) == 2


def test_drifting_mode_truth_and_components():
    s = drifting_mode(np.random.default_rng(8), duration_s=30.0)
    f, z = s.mode_at(s.t)
    assert 0.01 <= z[0] <= 0.03 and 0.05 <= abs(f[-1] / f[0] - 1) <= 0.2
    assert s.modes[1].kind == "rigid_body" and s.modes[1].frequency_hz[0] < 0.4 * f.min()
    resid = s.y - s.structural - s.rigid
    assert np.std(resid) == pytest.approx(s.noise_fraction * np.std(s.structural + s.rigid),
                                          rel=0.05)


def _at_strength_bound(s) -> bool:
    """The effect's strength sits at the generator's upper bound (draw_effects): a loop at 0.7
    of the largest stable gain, a scheduled mode moving by 30 % of its frequency."""
    if s.effect == "feedback":
        return s.truth["gain_margin"] == pytest.approx(1 / 0.7, rel=1e-6)
    if s.effect == "parameter_varying":
        v = s.signals["/airspeed"][1]
        moved = abs(s.truth["slope_hz_per_unit"]) * (v.max() - v.min()) / s.truth["frequency_hz"]
        return moved == pytest.approx(0.3, rel=0.05)
    return False


@pytest.mark.parametrize("effect", EFFECTS)
def test_hidden_effect_draw_reaches_its_size(effect):
    s = draw_hidden_effect(effect, np.random.default_rng(9), duration_s=20.0, fs=200.0)
    assert s.effect == effect == s.truth["effect"] and np.all(np.isfinite(s.y))
    assert set(s.signals) == {"/airspeed", "/rotor_speed"}
    assert 2.0 <= s.truth["target_size"] <= 20.0
    # reached, or short of it with the strength at its bound (the output noise is y_w + the
    # measurement noise: a loop changes the output by about its own disturbance's response)
    if s.truth["size"] < 0.75 * s.truth["target_size"]:
        assert _at_strength_bound(s), s.truth
    else:
        assert s.truth["size"] == pytest.approx(s.truth["target_size"], rel=0.25)
    # the output noise holds the measurement noise: against it alone the effect is larger
    assert s.truth["size_vs_measurement_noise"] > s.truth["size"]


def test_secant_steps_back_from_a_diverging_strength_towards_the_best_finite_one():
    """A strength past which the simulation diverges (a cubic spring too stiff for its step)
    and a size drawn beyond it: the search steps back towards the best finite strength and
    ends near the divergence, not at the lower bound (1e-3 of the size)."""
    from sysid_node.scenarios.draw_effects import _secant

    def size_of(p: float):
        return (np.inf if p > 2.0 else 3.0 * p), None

    p, size, _ = _secant(size_of, 4.0, 9.0, 4.0e-3, 40.0, steps=4)
    assert np.isfinite(size) and size > 0.5 * 9.0 and p <= 2.0


def test_effect_size_is_against_the_output_noise_disturbance_response_included():
    """Ljung's v (y = G u + v): the disturbance's response y_w plus the measurement noise; a
    change as large as v itself has size 1 (against the measurement noise alone, ~3)."""
    from sysid_node.scenarios.draw_effects import _draw_base

    rng = np.random.default_rng(12)
    b = _draw_base(rng, 300.0, 2, 2, "coloured", 30.0, (0.02, 0.05), (0.005, 0.05),
                   "acceleration", 0.1)
    v = b.y_w + b.noise_std * rng.standard_normal(b.y_w.shape)
    assert b.size(v) == pytest.approx(1.0, rel=0.05)
    assert b.size(b.y_w) < 1.0
    assert b.size_vs_measurement_noise(b.noise_std * rng.standard_normal(b.y_w.shape)) == (
        pytest.approx(1.0, rel=0.05))


def test_clean_draw_has_no_effect():
    s = draw_clean(np.random.default_rng(10), duration_s=10.0)
    assert s.effect is None and s.nominal_order == 2 * s.structure.n_modes


@pytest.mark.parametrize("name", HIDDEN_SCENARIOS)
def test_committed_hidden_bag_is_what_the_generator_makes(name):
    rec = hidden_effect(name, seed=HIDDEN_SEEDS[name])
    sig = bag_io.read_signals(HIDDEN_BAGS / name)
    for topic, values in (("/vibration", rec.y), ("/excitation", rec.u)):
        np.testing.assert_allclose(sig[topic].values, values, rtol=1e-9,
                                   atol=1e-9 * np.abs(values).max())
