"""The sensor_bias trial (validation.diagnose.confirm) on a drawn case of the hidden-effect suite
whose baseline spent states on the bias: an offset and drift the baseline's realization holds
with a slow, heavily damped pole pair in place of a structural mode. The trial re-fits with
the realization the baseline's selection picks for the output without the bias too (as the
periodic trial does for lines)."""

from __future__ import annotations

import pytest
from sysid_node.validation import suite as S
from sysid_node.validation.workflow import Options, run_validation

#: the trial's drop must reach most of what the bias adds to the baseline's error (the
#: case's ceiling, suite.ceiling: 0.52)
MIN_DROP = 0.4


@pytest.mark.slow
def test_a_bias_the_baseline_holds_with_a_pole_pair_is_tried_at_the_selections_horizon():
    # draw 12 (white): offset 0.81 and drift 0.22/s on modes at 14.5 and 26.3 Hz; the baseline
    # (dominant modes of order 8, 10 block rows) has a 0.05 Hz pair (96 % damped) and no
    # 14.5 Hz mode. Before: the bias trial at the baseline's horizon lowered the error by
    # -13 %, missing_mode ranked first (46 %)
    sc = S.draw("sensor_bias", 1105012, "white")
    out = run_validation(S._data(sc), Options(order=sc.nominal_order, auto=True))
    top = out.hyps[0]
    assert top.effect == "sensor_bias" and top.significant
    assert out.added[:1] == ["sensor_bias"]
    assert out.error_drop > MIN_DROP


@pytest.mark.slow
def test_the_bias_trial_refits_the_selections_best_ranked_realizations():
    # unseen draw 26 (multisine, 20 s at 149 Hz): offset -2.0 and drift 0.14/s on modes at
    # 2.28, 2.74 and 8.19 Hz; the baseline lacks the 2.28 Hz mode. The selection's first
    # realization of the output without the bias is unstable once re-fitted, its second holds
    # all three modes (the baseline refits its baseline.STARTS best too). Before: the trial
    # at the baseline's horizon lowered the error by 9 % (p=0.1), nothing was added
    sc = S.draw("sensor_bias", 1105026, "multisine")
    out = run_validation(S._data(sc), Options(order=sc.nominal_order, auto=True))
    top = out.hyps[0]
    assert top.effect == "sensor_bias" and top.significant, top.evidence
    assert out.added[:1] == ["sensor_bias"]
    assert out.error_drop > S.ceiling("sensor_bias", 1105026, "multisine") / 2
