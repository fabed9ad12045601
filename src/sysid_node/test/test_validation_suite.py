"""The randomized, seeded hidden-effect suite of validate (issue #11; sysid_node.validation.suite),
as a test: the first 6 draws of every effect (all four input kinds) and all 40 clean ones (1-3
modes, 100-1000 Hz, white / coloured / multisine / sweep input, effect size 2-20 x the output noise:
the disturbance's response plus the measurement noise), each validated with the nominal order and
--auto on two worker processes. ``benchmarks/validate_suite.py`` runs the issue's 15 draws per
effect and prints the figures (confusion matrix, drops, clean false alarms, time per case,
``--failures`` per case).

Asserted: clean records get nothing added (>= 95 %), every gate's false-alarm rate on them,
and the per-effect levels reached so far. The issue's target (the right effect first in >= 90 %
of every effect's cases, a median drop >= 60 %) is not reached for every effect yet: the
xfail test below says which and by how much.
"""

from __future__ import annotations

import numpy as np
import pytest
from sysid_node.validation import suite as S

#: Cases ranked right in the test's subset when it was measured (round 6: the drop's rank test
#: and the scheduling windows in periods; round 11: parameter_varying's affine structure and
#: input_delay's scan route; round 15: feedback scored on the input's held-out prediction, a
#: line whose periodic trial fails tried as a missing mode; round h11: a trial's drop also tested
#: conditionally on the two predictions; round 23: the whole record's coherence for a missing
#: mode on an interleaved split, the delay scan's conditional test, every coordinate of the
#: nonlinear gate's channel tried; round 25: parameter_varying's decay rate no longer follows
#: the signal, 1102004 found; round 32: effect sizes against the output noise y_w + measurement
#: noise, not the measurement noise alone, ~2.6x larger effects: parameter_varying 4 -> 5,
#: nonlinear_stiffness 2 -> 4, feedback 3 -> 4 (every loop at its gain bound), periodic 6 -> 5
#: (1101003 strong line taken for a missing mode; round 32 hp: a baseline pole pair whose decay
#: the record does not resolve is taken out as a line, 1101003 found again: 5 -> 6); 6 per
#: effect), as a count;
#: the floor is one case below (another CPU's rounding may move one case, a regression beyond
#: that fails).
#: The benchmark's 15 per effect (same seeds first) gave missing_mode 14 (12 in round 22, 11
#: before a new mode where the trial lowered the error was accepted), periodic_disturbance 15,
#: parameter_varying 9 (8 before round 25), input_delay 14 (12 in round 22, 10 before the
#: delay scan realized the dynamics as the model does), nonlinear_stiffness 9 (7 before its
#: trial tried every coordinate of the gate's channel), sensor_bias 15 (14 before its gate
#: also tested the model's input-driven part), feedback 8 (7 in round 26, 5 in round 23; round
#: 29: the score's own past has the most lags, 1106014 found; round 30: 9, least squares with a
#: rank threshold, 1106005's loop fit converges: subset 2 -> 3). Round 32 (sizes against the
#: output noise; benchmarks/validate_suite.py --failures --ceiling): missing_mode 14,
#: periodic_disturbance 9, parameter_varying 11, input_delay 13, nonlinear_stiffness 10,
#: sensor_bias 14, feedback 10; periodic_disturbance 13 after the baseline leaves lines out, 15
#: after round 33 (the periodic trial also takes the rotor harmonics the model's poles hold and
#: is re-fitted at the horizon selected for the output without the lines); round 34:
#: missing_mode 15 (a failing model's search tries where its free-run error peaks),
#: sensor_bias 15 (the bias trial also at the horizon selected for the output without it);
#: round 35: nonlinear_stiffness 12 (the drop's batch test on log loss ratios, a spring near
#: its gate tried when nothing is significant: subset 4 -> 6), feedback 11 (a loop ranked on
#: the larger of its input's and its output's drops).
RIGHT_FIRST_MEASURED = {
    "missing_mode": 6,
    "periodic_disturbance": 6,
    "parameter_varying": 5,
    "input_delay": 5,
    "nonlinear_stiffness": 6,
    "sensor_bias": 6,
    "feedback": 4,
}
#: Median drop of the validation error reached in the subset (round 32: measured 81 %, 78 %
#: and 51 %), with room for one case falling to no drop (then 66 %, 66 %, 24 %). (The other
#: effects' medians sit between right and unexplained cases: one case moves them far, so they
#: are guarded by their counts above.)
MEDIAN_DROP_FLOOR = {"periodic_disturbance": 0.6, "sensor_bias": 0.6, "nonlinear_stiffness": 0.2}
GATE_FALSE_ALARM_MAX = 0.2  # before the trial; the trial's held-out test keeps additions out


@pytest.fixture(scope="session")
def suite_results():
    return S.run_suite(S.cases(S.TEST_CASES_PER_EFFECT, S.TEST_CLEAN_CASES), workers=2)


@pytest.fixture(scope="session")
def suite_summary(suite_results):
    sm = S.summary(suite_results)
    print("\n" + S.confusion_table(suite_results))
    for eff, row in sm["effects"].items():
        print(f"{eff:22s} right first {100 * row['right_first']:5.1f} %, "
              f"median drop {100 * row['median_drop']:5.1f} %")
    print(f"clean: nothing added in {100 * sm['clean_nothing_added']:.1f} %; gate false "
          "alarms: " + ", ".join(f"{g} {100 * r:.0f} %" for g, r in sm["gate_false_alarm"].items()))
    return sm


@pytest.mark.slow
def test_suite_runs_every_case(suite_results, suite_summary):
    assert len(suite_results) == 7 * S.TEST_CASES_PER_EFFECT + S.TEST_CLEAN_CASES
    assert not suite_summary["errors"]
    kinds = {r.kind for r in suite_results}
    assert kinds == set(S.KINDS)
    assert min(r.fs for r in suite_results) >= 100 and max(r.fs for r in suite_results) <= 1000


@pytest.mark.slow
def test_clean_records_get_nothing_added(suite_summary):
    assert suite_summary["clean_nothing_added"] >= 0.95


@pytest.mark.slow
def test_gate_false_alarm_rates_on_clean_records(suite_summary):
    for gate, rate in suite_summary["gate_false_alarm"].items():
        assert rate <= GATE_FALSE_ALARM_MAX, gate


@pytest.mark.slow
@pytest.mark.parametrize("effect", [e for e, v in RIGHT_FIRST_MEASURED.items() if v > 1])
def test_effect_ranked_first_at_least_as_often_as_before(suite_summary, effect):
    row = suite_summary["effects"][effect]
    assert round(row["right_first"] * row["cases"]) >= RIGHT_FIRST_MEASURED[effect] - 1


@pytest.mark.slow
@pytest.mark.parametrize("effect", list(MEDIAN_DROP_FLOOR))
def test_error_falls_after_adding_the_effect(suite_summary, effect):
    assert suite_summary["effects"][effect]["median_drop"] >= MEDIAN_DROP_FLOOR[effect]


@pytest.mark.slow
@pytest.mark.xfail(
    reason="issue #11 target not reached for every effect yet (see the note)", strict=True
)
def test_issue_target_right_first_90_percent_and_median_drop_60_percent(suite_summary):
    short = {e: r["right_first"] for e, r in suite_summary["effects"].items()
             if r["right_first"] < 0.9}
    assert not short, f"below 90 %: {short}"
    assert suite_summary["median_drop"] >= 0.6


def test_input_noise_measures_the_input_with_seeded_white_noise():
    sc = S.draw(None, S.cases(0, 1)[0][1], "coloured")
    exact, noisy, again = S._data(sc), S._data(sc, 0.02, 7), S._data(sc, 0.02, 7)
    np.testing.assert_allclose(exact.u, sc.u)
    np.testing.assert_allclose(noisy.y, sc.y)
    np.testing.assert_allclose(noisy.u, again.u)
    share = np.sqrt(np.mean((noisy.u - sc.u) ** 2) / np.mean(sc.u**2))
    assert 0.015 < share < 0.025
    assert not np.allclose(S._data(sc, 0.02, 8).u, noisy.u)
