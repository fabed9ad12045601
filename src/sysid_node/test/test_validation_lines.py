"""A periodic disturbance the nominal-order baseline would absorb as an undamped pole pair
(validation.baseline.without_lines): over the record such a pair is a line reproduced from its
initial state in free run, not a structural mode; the baseline is refitted with the line as
harmonic regressors it leaves out, its poles go to the structure and the line stays in its
error for the periodic gate and trial (a drawn case of the hidden-effect suite)."""

from __future__ import annotations

import numpy as np
import pytest
from sysid_node.validation import suite as S
from sysid_node.validation.baseline import line_regressors
from sysid_node.validation.data import ValidationData
from sysid_node.validation.workflow import Options, run_validation


def test_a_strong_rotor_line_is_left_to_the_periodic_trial_not_spent_on_a_pole_pair():
    # periodic_disturbance draw 3 of the suite: sweep input, one mode at 12.2 Hz, harmonic 2 of
    # /rotor_speed (5.70 Hz) at 17.5 x the output noise; before: a 0-damped baseline pole pair
    # at 5.73 Hz, the true mode lost, missing_mode ranked first
    sc = S.draw("periodic_disturbance", 1101003, "sweep")
    out = run_validation(S._data(sc), Options(order=sc.nominal_order, auto=True))
    f_mode = sc.structure.frequencies_hz[0]
    assert any(abs(md.frequency_hz - f_mode) < 0.05 * f_mode for md in out.base.modes())
    assert "lines, not modes" in out.choice.note
    top = out.hyps[0]
    assert top.effect == "periodic_disturbance" and top.significant
    assert top.parameters["source"] == sc.truth["source"]
    assert out.added[:1] == ["periodic_disturbance"]


def test_a_line_at_a_rotor_harmonic_takes_the_rotor_harmonics_out():
    t = np.arange(2000) / 200.0
    rotor = 7.0 + 0.1 * np.sin(0.3 * t)
    data = ValidationData(t, np.zeros((t.size, 1)), np.zeros((t.size, 1)), 200.0,
                          signals={"/rotor_speed": rotor})
    regs = line_regressors([14.1, 33.0], data)
    assert regs[0]["source"] == "/rotor_speed" and 2 in regs[0]["orders"]
    assert regs[1]["source"] is None and regs[1]["frequency_hz"] == pytest.approx(33.0)
