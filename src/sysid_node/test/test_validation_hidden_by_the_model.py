"""Effects the baseline hides from the gates (drawn cases of the hidden-effect suite, issue #11):
a sensor offset carried by a slow pole pair's initial state, a delay the Schroeder multisine
shows through one mode's transient, a delay whose baseline horizon lost a mode, and a missing
mode whose interleaved validation blocks are shorter than its period."""

from __future__ import annotations

import numpy as np
import pytest
from sysid_node.validation import baseline as B
from sysid_node.validation import diagnose as D
from sysid_node.validation import gates as G
from sysid_node.validation import suite as S
from sysid_node.validation.assess import assess
from sysid_node.validation.augment import ModelSpec
from sysid_node.validation.baseline import select_baseline
from sysid_node.validation.split import make_split
from sysid_node.validation.workflow import Options, run_validation


def _context(effect: str, seed: int, kind: str):
    """The suite case's baseline and its gate context (no trials: cheap)."""
    sc = S.draw(effect, seed, kind)
    data = S._data(sc)
    split = make_split(data, 0.6, 2 * 10 * (1 + data.n_inputs + data.n_outputs) + 50)
    base, _ = select_baseline(data, split, ModelSpec(), sc.nominal_order, None, "free_run")
    a = assess(base, data, split, primary="free_run")
    return sc, G.Context(data, split, base, a, dict(data.signals))


def test_an_offset_carried_by_a_slow_pole_pairs_initial_state_fires_the_bias_gate():
    """Draw 10 (multisine, 367 Hz): the baseline spends its second pole pair on the offset
    (0.02 Hz, 96 % damped, its initial state holding the offset over the record) and loses the
    3.2 Hz mode; its error has no mean, the error of its input-driven part has."""
    sc, ctx = _context("sensor_bias", 1105010, "multisine")
    assert min(md.frequency_hz for md in ctx.current.modes()) < 0.5  # the slow pair
    x0r = G.initial_response(ctx.current, ctx.data)
    assert x0r is not None and np.std(x0r[ctx.split.val]) > 0.3 * np.std(ctx.data.y)
    h = G.sensor_bias(ctx)
    assert h.p_value < G.P_GATE and "without the initial-state response" in h.evidence


def test_the_bias_gate_is_quiet_on_a_clean_record_with_an_initial_state():
    _, ctx = _context(None, 1199003, "sweep")
    assert G.initial_response(ctx.current, ctx.data) is not None
    assert G.sensor_bias(ctx).p_value > G.P_GATE


def test_a_delay_seen_through_one_modes_transient_fires_the_scan_gate():
    """Draw 2 (Schroeder multisine, 304 Hz, 2 samples): the multisine crosses the 3.25 Hz mode
    in its first tenth of a second; the delayed scan fit lowers the estimation error by 43 %
    within the mode's transient, which the batch means alone never found significant."""
    sc, ctx = _context("input_delay", 1103002, "multisine")
    h = G.input_delay(ctx)
    assert h.p_value < G.P_GATE and "an input delayed 2 samples" in h.evidence


def test_the_delay_trial_realizes_the_delayed_input_as_the_baseline_would(monkeypatch):
    """Draw 9 (coloured, 119 Hz, 2 samples; modes 1.14, 1.47, 9.8 Hz), full-rate candidates
    only (a realization at fs / 4 spans the close pair from the start): the baseline's horizon
    (10 block rows, chosen for the undelayed input) realizes one of the close pair only, and so
    does the delay's re-fit with it; the horizon chosen for the delayed input finds both."""
    monkeypatch.setattr(B, "decimation_factors", lambda: [])
    sc, ctx = _context("input_delay", 1103009, "coloured")
    spec = ctx.current.spec
    alt = D._delayed_realization(ctx, spec, 2.0)
    assert alt is not None and alt.block_rows != spec.block_rows
    fm, _ = D._delay_refit(ctx, spec, "input_delay", {"samples": 2.0})
    freqs = sorted(md.frequency_hz for md in fm.modes())
    assert len(freqs) == 3 and freqs[0] == pytest.approx(1.143, rel=0.02)


def test_a_mode_longer_than_the_interleaved_blocks_is_found_on_the_whole_record():
    """Draw 14 as drawn before round 32 (Schroeder multisine, 538 Hz, 4.4 x the measurement
    noise; modes at 2.75 (the missing one), 3.59 and 4.09 Hz): the validation blocks last
    0.3 s, one period of the lost mode; the coherence of the whole record's free-run error
    finds it, and the mode's trial beats the cubic spring's. (Before the baseline's refit was
    refined again, the baseline also had a 72 %-damped pair for the 3.59 Hz mode and the
    addition lowered the error by 81 %; now both structural modes are in it: 35 %.)"""
    sc = S.draw("missing_mode", 1100014, "multisine", size_against="measurement_noise")
    out = run_validation(S._data(sc), Options(order=sc.nominal_order, auto=True))
    assert out.split.mode == "interleaved"
    top = out.hyps[0]
    assert top.effect == "missing_mode" and top.significant, top.evidence
    assert "of the whole record" in top.evidence
    assert out.added[:1] == ["missing_mode"] and out.error_drop > 0.0
    got = np.array([md.frequency_hz for md in out.current.modes()])
    for f in [*(f for f, _ in sc.structure.modes()), sc.truth["frequency_hz"]]:
        assert np.min(np.abs(got - f)) <= 0.05 * f, (f, got)  # the gate's NEAR_MODE



@pytest.mark.slow
def test_a_failing_model_tries_the_mode_where_its_free_run_error_peaks():
    """Draw 14 as the suite draws it now (sizes against the output noise: 4.4 x): the baseline
    (4.09 Hz, free-run fit 36 %, a failure) lacks the modes at 2.75 and 3.59 Hz, where the
    multisine has little power; the whole record's coherence does not fire (p=0.15). A failing
    model's search tries a mode where its free-run error peaks away from its modes (before:
    the gate gave no frequency, no trial, nothing ranked first; ceiling 35 %)."""
    sc = S.draw("missing_mode", 1100014, "multisine")
    out = run_validation(S._data(sc), Options(order=sc.nominal_order, auto=True))
    top = out.hyps[0]
    assert top.effect == "missing_mode" and top.significant, top.evidence
    assert out.added[:1] == ["missing_mode"] and out.error_drop > 0.3

def test_error_fell_at_uses_the_trial_error_it_is_given():
    """The confirmation's trial error is handed down, not simulated again: the frequency is
    where the given error fell (here: the model's own error with its 18-22 Hz band removed)."""
    _, ctx = _context("missing_mode", 1100002, "multisine")
    e0 = ctx.assessment.primary_error
    f, res = D.error_fell_at(ctx, ctx.current, e0 - 0.99 * _band(e0, ctx.data.fs, 20.0))
    assert 18.0 - res <= f <= 22.0 + res  # within the band taken out (18-22 Hz)


def _band(e: np.ndarray, fs: float, f0: float) -> np.ndarray:
    from scipy import signal

    sos = signal.butter(2, [0.9 * f0, 1.1 * f0], "bandpass", fs=fs, output="sos")
    return signal.sosfiltfilt(sos, e, axis=0)
