"""The periodic trial (validation.diagnose.confirm) on drawn cases of the hidden-effect suite
whose baseline spent states on the disturbance: a rotor harmonic the baseline imitates with a
lightly damped pole pair leaves no line in its error (the gate's harmonics miss it; the trial
with it too is the gate's alternative), and the baseline's horizon, chosen for the output with
the lines, can realize an unstable pole once they are taken out (the trial also re-fits with
the realization the baseline's selection picks for the output without them)."""

from __future__ import annotations

import pytest
from sysid_node.validation import suite as S
from sysid_node.validation.workflow import Options, run_validation

#: the trials' drops must reach most of what the effect adds to the baseline's error (the
#: cases' ceilings, suite.ceiling: 0.90 and 0.87)
MIN_DROP = 0.6


def _validated(seed: int):
    kind = S.KINDS[(seed % 1000) % 4]
    sc = S.draw("periodic_disturbance", seed, kind)
    return sc, run_validation(S._data(sc), Options(order=sc.nominal_order, auto=True))


@pytest.mark.slow
def test_a_rotor_harmonic_the_baseline_imitates_with_a_pole_pair_is_tried_too():
    # draw 11 (sweep): harmonics 1 and 3 of /rotor_speed (4.09 Hz); the baseline's pole pair
    # at 4.16 Hz (0.4 % damped) holds harmonic 1, the gate finds 2 and 3 in its error; before:
    # the trial without harmonic 1 lowered the error by 11 % (p=0.53), nothing ranked first
    sc, out = _validated(1101011)
    top = out.hyps[0]
    assert top.effect == "periodic_disturbance" and top.significant
    assert top.parameters["source"] == sc.truth["source"]
    assert set(sc.truth["harmonics"]) <= set(top.parameters["harmonics"])
    assert out.added[:1] == ["periodic_disturbance"]
    assert out.error_drop > MIN_DROP


@pytest.mark.slow
def test_a_trial_unstable_at_the_baselines_horizon_is_realized_at_the_selections():
    # draw 12 (white): harmonic 1 of /rotor_speed (23.1 Hz) held by a baseline pole pair at
    # 23.4 Hz; with the line out, the baseline's 20 block rows realize an unstable real pole
    # (before: "trial re-fit is unstable", nothing ranked first)
    sc, out = _validated(1101012)
    top = out.hyps[0]
    assert top.effect == "periodic_disturbance" and top.significant
    assert out.added[:1] == ["periodic_disturbance"]
    assert out.error_drop > MIN_DROP


@pytest.mark.slow
def test_a_failing_model_holding_a_rotor_harmonic_in_its_poles_tries_that_harmonic():
    # unseen draw 19 (sweep): harmonic 2 of /rotor_speed (66.1 Hz) held by two baseline pole
    # pairs at 65.1 and 66.1 Hz, no rotor line left in the error; the baseline fails (free-run
    # NRMSE 98 %), every effect is tried; before: the periodic trial took /airspeed (the
    # gate's best, p=0.36), missing_mode ranked first (drop 23 %)
    sc, out = _validated(1101019)
    top = out.hyps[0]
    assert top.effect == "periodic_disturbance" and top.significant
    assert top.parameters["source"] == sc.truth["source"]
    # the evidence names the trial the parameters are, after the gate's own (other) choice
    won = top.evidence.split("lowers the error most")[0].rsplit(";", 1)[-1]
    assert f"source={sc.truth['source']}" in won and "parameters are this trial's" in top.evidence
    assert out.added[:1] == ["periodic_disturbance"]
    assert out.error_drop > MIN_DROP
