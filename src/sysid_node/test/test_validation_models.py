"""Free run, output-error fit, pole refinement, cubic spring, split and baseline choice of
sysid_node.validation against systems with known answers."""

from __future__ import annotations

import numpy as np
import pytest
from sysid_node.core.lti import simulate_discrete
from sysid_node.validation import simulation as S
from sysid_node.validation.augment import ModelSpec
from sysid_node.validation.baseline import select_baseline
from sysid_node.validation.data import ValidationData, ValidationError, load_arrays
from sysid_node.validation.residuals import compare_errors
from sysid_node.validation.split import make_split


def _block(r: float, w: float) -> np.ndarray:
    return r * np.array([[np.cos(w), np.sin(w)], [-np.sin(w), np.cos(w)]])


def _two_modes() -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    a = np.zeros((4, 4))
    a[:2, :2], a[2:, 2:] = _block(0.98, 0.2), _block(0.95, 0.7)
    rng = np.random.default_rng(1)
    return a, rng.standard_normal((4, 1)), rng.standard_normal((1, 4)), np.array([[0.3]])


def test_markov_free_run_matches_the_state_recursion_and_oe_recovers_b_d_x0():
    a, b, c, d = _two_modes()
    a[0, 2] = 0.3  # not block-diagonal: no eigenvector basis is used
    rng = np.random.default_rng(2)
    u = rng.standard_normal((3000, 1))
    x0 = rng.standard_normal(4)
    y, _ = simulate_discrete(a, b, c, d, u, x0)
    dyn = S.LinearDynamics.build(a, c, u.shape[0])
    assert np.allclose(S.simulate_linear(dyn, b, d, u, x0), y, atol=1e-9 * np.abs(y).max())
    yn = y + 0.01 * np.std(y) * rng.standard_normal(y.shape)
    oe = S.fit_output_error(dyn, yn, u, np.arange(2000))
    assert np.allclose(oe.B, b, rtol=0.02, atol=0.02 * np.abs(b).max())
    assert np.allclose(oe.D, d, atol=0.01)


def test_output_error_refinement_moves_the_poles_to_the_truth():
    a, b, c, d = _two_modes()
    rng = np.random.default_rng(3)
    u = rng.standard_normal((3000, 1))
    y, _ = simulate_discrete(a, b, c, d, u)
    y = y + 0.01 * np.std(y) * rng.standard_normal(y.shape)
    a0 = np.zeros((4, 4))
    a0[:2, :2], a0[2:, 2:] = _block(0.97, 0.21), _block(0.96, 0.68)  # off by a bandwidth
    a1, *_ = S.refine_poles(a0, c, y, np.arange(2000), lambda _: (u, u), np.zeros(0))
    got = np.sort_complex(np.linalg.eigvals(a1))
    want = np.sort_complex(np.linalg.eigvals(a))
    assert np.allclose(got, want, atol=2e-3)


def test_cubic_free_run_picard_equals_the_recursion():
    a, b, c, d = _two_modes()
    rng = np.random.default_rng(4)
    u = rng.standard_normal((2000, 1))
    y, _ = simulate_discrete(a, b, c, d, u)
    cz = c[0] / np.std(y)
    bq = -0.05 * b  # a mild hardening spring acting where the input acts
    b_all, d_all = np.column_stack([b, bq]), np.column_stack([d, -0.05 * d])
    dyn = S.LinearDynamics.build(a, np.vstack([c, cz]), u.shape[0])
    y_p, z_p = S.simulate_cubic(dyn, b_all, d_all, u)
    y_r, z_r = S._cubic_recursion(a, b_all, np.vstack([c, cz]), d_all, u, None, 1.0)
    assert np.all(np.isfinite(y_p))
    assert np.allclose(y_p, y_r, atol=1e-6 * np.abs(y_r).max())
    assert not np.allclose(y_p, y, atol=1e-3 * np.abs(y).max())  # the spring does something


def test_double_integral_of_an_acceleration_is_the_displacement():
    fs, f = 200.0, 3.0
    t = np.arange(4000) / fs
    disp = np.sin(2 * np.pi * f * t)
    acc = -((2 * np.pi * f) ** 2) * disp
    z = S.integrate(acc, fs, 2, 1.0)
    assert np.allclose(z[200:-200], disp[200:-200], atol=0.02)


def _data(u: np.ndarray, y: np.ndarray, fs: float) -> ValidationData:
    return ValidationData(np.arange(y.shape[0]) / fs, y, u, fs, ["y0"], ["u0"], {})


def test_split_is_interleaved_for_a_sweep_and_chronological_for_white_noise():
    from scipy import signal as sg

    fs, n = 200.0, 6000
    t = np.arange(n) / fs
    sweep = sg.chirp(t, 0.5, t[-1], 80.0)[:, None]
    white = np.random.default_rng(5).standard_normal((n, 1))
    y = np.zeros((n, 1)) + np.random.default_rng(6).standard_normal((n, 1))
    s = make_split(_data(sweep, y, fs), 0.6, 200)
    assert s.mode == "interleaved" and "sweep" in s.reason
    assert s.n_est + s.n_val == n and len(s.val_segments) > 2
    assert make_split(_data(white, y, fs), 0.6, 200).mode == "chronological"
    with pytest.raises(ValidationError, match="too short"):
        make_split(_data(white[:300], y[:300], fs), 0.6, 200)


def test_baseline_picks_the_true_order_and_a_stable_free_run():
    a, b, c, d = _two_modes()
    rng = np.random.default_rng(7)
    u = rng.standard_normal((4000, 1))
    w = 0.05 * rng.standard_normal((4000, 1))  # unmeasured disturbance
    y, _ = simulate_discrete(a, b, c, d, u + w)
    y = y + 0.02 * np.std(y) * rng.standard_normal(y.shape)
    data = _data(u, y, 100.0)
    split = make_split(data, 0.6, 200)
    fm, choice = select_baseline(data, split, ModelSpec())
    assert choice.order == 4 and choice.criterion == "free_run"
    assert fm.free_run_radius < 1 and fm.predictor_radius < 1
    ys = fm.simulate(data)[split.val]
    nrmse = np.linalg.norm(y[split.val] - ys) / np.linalg.norm(y[split.val])
    assert nrmse < 0.1


def test_error_comparison_sees_a_real_drop_and_not_a_coin_flip():
    rng = np.random.default_rng(8)
    e0 = rng.standard_normal((2000, 1))
    assert compare_errors(e0, 0.5 * e0 + 0.1 * rng.standard_normal((2000, 1))).p_value < 1e-3
    same = compare_errors(rng.standard_normal((2000, 1)), rng.standard_normal((2000, 1)))
    assert same.p_value > 1e-3 and abs(same.drop) < 0.1


def test_plain_arrays_csv_with_quoted_header_npy_and_bad_columns(tmp_path):
    csv = tmp_path / "rec.csv"
    rows = "\n".join(f"{0.1 * k:.3f},{0.2 * k + 1:.3f}," for k in range(100))
    csv.write_text('"V1","V2"\n' + rows + "\n")
    d = load_arrays(str(csv), 50.0, outputs="V2", inputs="V1", rows="10:90", remove_mean=True)
    assert d.n == 80 and d.input_names == ["V1"] and d.output_names == ["V2"]
    assert abs(float(d.y.mean())) < 1e-12 and d.fs == 50.0
    npy = tmp_path / "rec.npy"
    np.save(npy, np.random.default_rng(9).standard_normal((50, 3)))
    d = load_arrays(str(npy), 10.0, outputs="0,1")
    assert d.n_outputs == 2 and d.n_inputs == 0
    with pytest.raises(ValidationError, match="no column 'V3'"):
        load_arrays(str(csv), 50.0, outputs="V3")
    with pytest.raises(ValidationError, match="--rate"):
        load_arrays(str(csv), 0.0)
    with pytest.raises(ValidationError, match="not found"):
        load_arrays(str(tmp_path / "none.csv"), 1.0)


def test_cubic_trial_keeps_the_structure_when_the_force_realization_loses_a_mode():
    """A drawn cubic-stiffness record (suite seed 1104013 as drawn before round 32, sized against
    the measurement noise: modes 3.4, 46.9, 78.5 Hz, coloured input) where the realization with
    the measured spring force as an input trades the 3.4 Hz mode for the force's spectrum: the
    refinement also starts from the linear prior's poles, keeps all three modes and lowers the
    free-run error significantly."""
    from sysid_node.validation import suite as S
    from sysid_node.validation.workflow import Options, run_validation

    sc = S.draw("nonlinear_stiffness", 1104013, "coloured", size_against="measurement_noise")
    out = run_validation(S._data(sc), Options(order=sc.nominal_order))
    h = next(h for h in out.hyps if h.effect == "nonlinear_stiffness")
    assert h.significant and h.score > 0.1, h.evidence
    freqs = sorted(md.frequency_hz for md in h.trial.modes())
    assert len(freqs) == 3 and abs(freqs[0] / 3.3657 - 1) < 0.05


def test_cubic_trial_tries_every_coordinate_of_the_gates_channel():
    """A drawn cubic-stiffness record (suite seed 1104006: acceleration sensor, modes 10.8,
    15.4, 24.0 Hz, multisine at 868 Hz) whose gate correlates the error best with the cube of
    the output's single integral (a velocity) while the spring acts on the displacement (its
    double integral): the trial tries the channel's three coordinates, the displacement lowers
    the free-run error by over a fifth, significantly (only the velocity: 23 %, p=4e-2)."""
    from sysid_node.validation import suite as S
    from sysid_node.validation.workflow import Options, run_validation

    sc = S.draw("nonlinear_stiffness", 1104006, "multisine")
    out = run_validation(S._data(sc), Options(order=sc.nominal_order))
    h = next(h for h in out.hyps if h.effect == "nonlinear_stiffness")
    assert h.significant and h.score > 0.2, h.evidence
    assert h.parameters["integrals"] == 2
    assert out.hyps[0] is h


def test_the_best_of_several_trials_pays_for_the_choice():
    """The cubic trial fits every coordinate of the gate's channel (and the follow-ups they ask
    for) and keeps the one that lowers the validation error most (suite seed 1104006): chosen on
    the data that test it, its drop's p-value is that comparison's times the number of
    candidates fitted (Bonferroni)."""
    from sysid_node.validation import suite as S
    from sysid_node.validation.assess import compare_primary, primary_error
    from sysid_node.validation.workflow import Options, run_validation

    sc = S.draw("nonlinear_stiffness", 1104006, "multisine")
    out = run_validation(S._data(sc), Options(order=sc.nominal_order))
    h = next(h for h in out.hyps if h.effect == "nonlinear_stiffness")
    k = int(h.trial_note.split("the best of ")[1].split()[0])  # with follow-up fits, if any
    assert k >= 1 + len(h.alternatives) >= 3, (k, h.alternatives)
    e1 = primary_error(h.trial, out.data, out.split, out.before.primary)
    own = compare_primary(out.before, e1).p_value
    assert h.drop_p == pytest.approx(min(1.0, k * own), rel=1e-6), (h.drop_p, own)
    assert h.significant  # k x 1e-4 is still under the 1e-2 asked


def test_the_largest_drop_significant_on_its_own_is_kept():
    """Suite record 1104004 (white input, a cubic spring on the displacement): the spring on
    the second integral of the output lowers the validation error by 62 %, on the output
    itself by 61 %. The second's error has the shorter correlation time and its drop is
    significant on the ranks of its batches; keeping the largest drop whatever its p-value
    left the record unexplained (main: 62 %, p = 0.09 after Bonferroni over 4 trials)."""
    from sysid_node.validation import suite as S
    from sysid_node.validation.workflow import Options, run_validation

    sc = S.draw("nonlinear_stiffness", 1104004, "white")
    out = run_validation(S._data(sc), Options(order=sc.nominal_order, auto=True))
    h = out.hyps[0]
    assert h.effect == "nonlinear_stiffness" and h.significant, h.evidence
    assert h.score > 0.5 and out.error_drop > 0.5, (h.score, out.error_drop)


def test_best_trial_keeps_a_significant_drop_over_a_larger_insignificant_one():
    from types import SimpleNamespace

    from sysid_node.validation.diagnose import _best_trial

    def trial(drop, p):
        return ("fm", SimpleNamespace(drop=drop, p_value=p), {}, None)

    big, sig, small = trial(0.62, 0.02), trial(0.61, 1e-8), trial(0.03, 1e-9)
    assert _best_trial([big, sig, small], 0.01 / 3) is sig
    assert _best_trial([big, small], 0.01 / 2) is big  # under MIN_DROP: not a choice
    assert _best_trial([sig, trial(0.7, 1e-5)], 0.01 / 2)[1].drop == 0.7


def test_missing_mode_trial_starts_from_the_model_plus_a_mode_at_the_evidence():
    """A drawn record (suite seed 1100008: modes 5.8 and 17.1 Hz plus a hidden 8.1 Hz mode,
    618 Hz, white input) whose nominal-order model took the stronger hidden mode in place of
    5.8 Hz: the order n + 2 realization alone finds no new mode; started from the model's
    poles plus a pair at the residual's peak, the refinement lands on 5.8 Hz and the error
    falls by half."""
    from sysid_node.validation import suite as S
    from sysid_node.validation.workflow import Options, run_validation

    sc = S.draw("missing_mode", 1100008, "white")
    out = run_validation(S._data(sc), Options(order=sc.nominal_order))
    h = next(h for h in out.hyps if h.effect == "missing_mode")
    assert h.significant and h.score > 0.3, h.evidence
    assert abs(h.parameters["frequency_hz"] / 5.8177 - 1) < 0.02


def test_cubic_trial_also_fits_the_force_where_the_input_acts():
    """Suite record 1104009 (acceleration sensor, modes 12.2, 17.2, 37.6 Hz, coloured input,
    the validation part's output 1.2 x the estimation part's RMS): at every coordinate the
    estimation error prefers the force as a free input (its own b_q, d_q), which spends its
    parameters on the estimation part's noise (at the displacement it lowers the validation
    error by 7 %).
    The trial also fits the force acting where the input acts (Duffing, one stiffness): the
    displacement's drop then exceeds half the 67 % the effect adds to the error (its ceiling),
    and the follow-up fits are counted in the Bonferroni factor."""
    from sysid_node.validation import suite as S
    from sysid_node.validation.workflow import Options, run_validation

    sc = S.draw("nonlinear_stiffness", 1104009, "coloured")
    out = run_validation(S._data(sc), Options(order=sc.nominal_order))
    h = next(h for h in out.hyps if h.effect == "nonlinear_stiffness")
    assert out.hyps[0] is h and h.significant, h.evidence
    assert h.score > 0.5 * 0.67, h.evidence
    assert h.parameters["integrals"] == 2 and h.parameters.get("force") == "input", h.parameters
    k = int(h.trial_note.split("the best of ")[1].split()[0])
    assert k > 1 + len(h.alternatives), h.trial_note  # the follow-up fits are counted
