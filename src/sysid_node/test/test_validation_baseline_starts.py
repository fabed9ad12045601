"""The baseline's refit from several starts (issue #11 item 1: a free-run error near the best
linear model's): on suite draws whose input is a sweep (a Schroeder multisine is one), the
split interleaves short blocks and the held-out ranking of the unrefined realizations picks a
start whose output-error refinement stops far above the true linear system's error."""

from __future__ import annotations

import numpy as np
import pytest
from sysid_node.validation import suite as S
from sysid_node.validation.workflow import Options, baseline_assessment

#: The baseline may exceed the true system's free-run error by this factor: over the suite's
#: 40 clean draws and 90 clean twins at main 2488c83 the ratio's median is 1.01 and its 90th
#: percentile 1.14 to 1.23 (short records of lightly damped close modes: estimation variance).
NEAR_TRUE = 1.25


def _true_free_run_nrmse(sc, rows: np.ndarray) -> float:
    """Free-run NRMSE of the generator's own linear structure simulated on the measured input:
    what is left is the response to the unmeasured disturbance and the output noise."""
    y = sc.y[rows]
    e = y - sc.structure.simulate(sc.u, sc.fs)[rows]
    return float(np.linalg.norm(e) / np.linalg.norm(y - y.mean(axis=0)))


@pytest.mark.parametrize("seed, kind", [(1199006, "multisine"), (1199027, "sweep")])
def test_the_baseline_of_a_swept_clean_draw_is_near_the_true_linear_system(seed, kind):
    sc = S.draw(None, seed, kind)
    split, fm, choice, a = baseline_assessment(S._data(sc), Options(order=sc.nominal_order))
    assert split.mode == "interleaved" and a.primary == "free_run"
    floor = _true_free_run_nrmse(sc, split.val)
    assert a.primary_nrmse <= NEAR_TRUE * floor, (a.primary_nrmse, floor, choice.note)



def test_a_mode_the_realization_split_into_real_poles_is_in_the_baseline():
    """Clean sweep 1199047: every start's realization of order 6 has two complex pairs and two
    real poles where the true 1.65 Hz mode is; the poles' refinement moves complex pairs only,
    so no refit reached that mode (and the unseen clean record added missing_mode). A pair
    started at the estimation error's power peak in place of the real poles reaches it."""
    sc = S.draw(None, 1199047, "sweep")
    split, fm, choice, a = baseline_assessment(S._data(sc), Options(order=sc.nominal_order))
    got = np.array([md.frequency_hz for md in fm.modes()])
    for f, _ in sc.structure.modes():  # within the missing-mode gate's NEAR_MODE (5 %)
        assert np.min(np.abs(got - f)) <= 0.05 * f, (f, got, choice.note)


def test_the_baseline_is_a_converged_minimum_of_its_refinement():
    """Clean sweep 1199027: the chosen refit's output-error refinement stopped after its
    evaluations with a mode's damping twice the true one; refined once more, its estimation
    free-run error is clearly lower (the starts' bar). The baseline is the minimum reached."""
    from sysid_node.validation import models as M
    from sysid_node.validation.baseline import _clearly_lower

    sc = S.draw(None, 1199027, "sweep")
    data = S._data(sc)
    split, fm, choice, a = baseline_assessment(data, Options(order=sc.nominal_order))
    again = M.FittedModel(fm.spec, fm.order, model=fm.model, n_outputs=fm.n_outputs)
    M.fit_simulation(again, data, None, split)
    assert not _clearly_lower(fm, again, data, split), choice.note
