"""The hidden-effect suite's ceiling (validation.suite.ceiling): each case's clean twin is the
same draw without the effect, and the baseline's error on the two tells how much of the drawn
effect the linear model already absorbs."""

import numpy as np
import pytest
from sysid_node.validation import suite as S

pytestmark = pytest.mark.filterwarnings("ignore::RuntimeWarning")


def test_twin_is_the_same_draw_without_the_effect():
    sc, clean = S.draw_twin("missing_mode", 1100000, "white")
    assert clean.effect is None and sc.effect == "missing_mode"
    assert sc.fs == clean.fs and sc.y.shape == clean.y.shape
    np.testing.assert_allclose(sc.u, clean.u)
    np.testing.assert_allclose(sc.structure.frequencies_hz, clean.structure.frequencies_hz)
    # what differs is the effect plus a new measurement-noise draw of one size (against that
    # noise: the effect's size is against the output noise, which also holds y_w)
    noise = np.sqrt(np.mean(clean.y.var(axis=0))) * clean.noise_fraction
    diff = np.sqrt(np.mean((sc.y - clean.y) ** 2)) / noise
    size = sc.truth["size_vs_measurement_noise"]
    assert size > 1.5 * sc.truth["size"]
    assert diff == pytest.approx(np.hypot(size, np.sqrt(2)), rel=0.15)


def test_ceiling_separates_a_visible_effect_from_an_absorbed_one():
    """Two moving-mode draws of similar size (5.0 and 3.5 x the output noise against the true
    linear system, both at the generator's bound on the move): in the first the baseline's
    free-run error is 4 x its twin's; in the second the linear fit absorbs the move and the
    errors are equal."""
    visible = S.ceiling("parameter_varying", 1102004, "white")
    absorbed = S.ceiling("parameter_varying", 1102006, "multisine")
    assert visible > 0.5
    assert abs(absorbed) < S.DETECTABLE



def test_ceiling_scales_both_errors_by_the_records_spread():
    """A moved mode can change the output's spread (1102002, multisine: the mode at 38 Hz
    moves +-30 % with /airspeed, the record's validation output spread is 0.73 of its twin's):
    scaled by each record's own spread the twin's error looked 31 % lower; on the record's
    scale the two baselines' errors differ by 6 %, nothing a re-fit can find."""
    assert abs(S.ceiling("parameter_varying", 1102002, "multisine")) < S.DETECTABLE

def test_a_loops_ceiling_is_what_the_true_loop_explains_of_the_input():
    """Feedback has no twin: its ceiling is the true loop's drop of the input's held-out
    one-step error (feedback's score). Under a multisine reference (1106002) the reference is
    predictable from its own past and the loop is the input's whole unpredictable part; under
    a white one (1106004, at the gain bound: the loop is half the input's RMS) the input's own
    past predicts the loop's part about as well as the true loop: nothing for the score to
    find."""
    assert S.ceiling("feedback", 1106002, "multisine") > 0.5
    assert abs(S.ceiling("feedback", 1106004, "white")) < S.DETECTABLE
