"""The default order selection (validate without --order) and an input delay: a linear model
buys a delay's phase lag with extra states, so the held-out error falls with the order; the
order kept is the one that predicts as well with the input delayed (baseline._delay_parsimony),
and the delay is left to the diagnosis."""

from __future__ import annotations

from sysid_node.validation import suite as S
from sysid_node.validation.workflow import Options, baseline_assessment, run_validation


def test_the_default_order_leaves_a_delay_to_the_diagnosis():
    """Draw 12 of the suite's input_delay cases: one mode, white input, a 2-sample delay. The
    default selection chose order 4 on 2d57369 (the two extra states reproduce the delay, so
    the model passed and the delay went unseen); now the structure's order 2, and the
    diagnosis finds and adds the delay."""
    sc = S.draw("input_delay", 1103012, "white")
    assert sc.nominal_order == 2 and sc.truth["samples"] == 2
    data = S._data(sc)
    _, base, choice, _ = baseline_assessment(data, Options())
    assert base.order == sc.nominal_order
    assert "stand in for a delay" in choice.note
    out = run_validation(data, Options(auto=True))
    assert out.hyps[0].effect == "input_delay" and out.hyps[0].significant
    assert out.added[:1] == ["input_delay"]
