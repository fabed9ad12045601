"""A residual peak taken for a line whose periodic trial fails is tried as a missing mode
(validation.diagnose._line_as_mode): a lightly damped mode an octave below the model's, crossed
once by a sweep, rings at one frequency and over the interleaved validation blocks looks like a
line (a drawn case of the hidden-effect suite)."""

from __future__ import annotations

import pytest
from sysid_node.validation import suite as S
from sysid_node.validation.workflow import Options, run_validation


def test_a_ringing_mode_taken_for_a_line_is_found_as_a_mode():
    seed = 1100003  # missing_mode draw 3 of the suite: sweep input, 0.85 Hz, 0.75 % damping
    sc = S.draw("missing_mode", seed, "sweep")
    out = run_validation(S._data(sc), Options(order=sc.nominal_order, auto=True))
    pd = next(h for h in out.hyps if h.effect == "periodic_disturbance")
    assert "a line at" in pd.evidence and not pd.significant  # the line's own trial fails
    top = out.hyps[0]
    assert top.effect == "missing_mode" and top.significant
    assert top.evidence.startswith("the line's periodic trial failed, tried as a mode")
    assert top.parameters["frequency_hz"] == pytest.approx(sc.truth["frequency_hz"], rel=0.02)
    assert out.added[:1] == ["missing_mode"]
