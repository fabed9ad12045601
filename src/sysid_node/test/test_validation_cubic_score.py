"""The nonlinear_stiffness gate's score test (gates.cubic_score) on drawn suite records."""

import numpy as np
import pytest
from sysid_node.validation import gates as G
from sysid_node.validation import suite as S
from sysid_node.validation.workflow import Options, baseline_assessment


def _context(effect, seed, kind):
    sc = S.draw(effect, seed, kind)
    data = S._data(sc)
    split, base, _, a = baseline_assessment(data, Options(order=sc.nominal_order))
    return G.Context(data, split, base, a, dict(data.signals))


def test_partial_t_ignores_a_regressor_the_null_directions_explain():
    """A regressor that is mostly a null direction (the linear model's own misfit) has no
    t of its own once that direction is projected out; its own part still has."""
    rng = np.random.default_rng(0)
    n = 4000
    null = rng.standard_normal((n, 2))
    x = null[:, 0] + 0.1 * rng.standard_normal(n)
    e = 0.5 * null[:, 0] + rng.standard_normal(n)
    assert abs(G._partial_t(e, x, null)) < 3.0
    assert abs(G._partial_t(e, x, np.zeros((n, 0)))) > 10.0
    e1 = e + 2.0 * (x - null[:, 0])
    assert abs(G._partial_t(e1, x, null)) > 10.0


def test_cubic_gate_fires_on_an_interleaved_split():
    """Suite record 1104014 (cubic spring, modes 2.4, 43.4, 50.5 Hz, multisine at 473 Hz,
    interleaved split): the one-step residual shows nothing (correlation p=0.23 over 3
    coordinates, gate p=0.70 before the score test) while the trial on the displacement lowers
    the free-run error by 22 %; the score test of the force's response on the free-run error
    fires (p about 1e-5 before Bonferroni)."""
    ctx = _context("nonlinear_stiffness", 1104014, "multisine")
    assert ctx.split.mode == "interleaved"
    h = G.nonlinear_stiffness(ctx)
    assert h.p_value < G.P_GATE, h.evidence
    assert h.parameters["channel"] == 0 and "score test" in h.evidence


@pytest.mark.parametrize("seed,kind", [(1199005, "coloured"), (1199013, "coloured")])
def test_cubic_score_is_calm_on_a_lightly_damped_clean_record(seed, kind):
    """Clean suite records with one lightly damped mode far below the sample rate (2.5 Hz at
    407 Hz, 1.5 Hz at 253 Hz, 12 cycles of validation): without the model's own parameter
    directions projected out the score test gave p=1e-11 and 3e-6 (the initial state's and
    the poles' misfit ring at the mode, as the force's response does)."""
    ctx = _context(None, seed, kind)
    score = G.cubic_score(ctx)
    assert score is not None and score[0] * 3 > G.P_GATE, score


def test_cubic_gate_is_calm_on_a_clean_white_record():
    """Clean suite record 1199016 (white input, chronological split): the prewhitened
    free-run error correlated with the measured output's cube (p=2e-7, gate 1e-6); the score
    test, which takes the free-run error's part on a linear free run, finds nothing (p=0.15)."""
    h = G.nonlinear_stiffness(_context(None, 1199016, "white"))
    assert h.p_value > G.P_GATE, h.evidence
