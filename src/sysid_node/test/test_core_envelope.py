"""Sec. IV envelope expansion on the rotor-speed cobra stick model: the range is covered without
ever closing an unstable loop, every step passed the check first, and the LPV model built from
the identified local models predicts the modes between the operating points within 1 %; the
``envelope`` tool's files and errors."""

import json

import numpy as np
import pytest
from sysid_node.core.envelope import EnvelopeSettings, expand_envelope
from sysid_node.core.lpv import LpvModel, lpv_errors
from sysid_node.scenarios.csm_rotor import closed_loop_experiment, csm_at
from sysid_node.tools import envelope as tool


@pytest.fixture(scope="module")
def run():
    settings = EnvelopeSettings(32.0, 38.0, 1.0, order=6, control_band_hz=(30.0, 40.0))

    def experiment(theta, controller, rng):
        return closed_loop_experiment(csm_at(theta), controller, 40.0, rng)

    return expand_envelope(experiment, settings, np.random.default_rng(0))


@pytest.mark.slow
def test_range_covered_without_an_unstable_loop(run):
    assert run.completed and run.stop_reason == ""
    assert run.points[0].theta == 32.0 and run.points[-1].theta == 38.0
    assert not run.points[0].closed_loop and all(p.closed_loop for p in run.points[1:])
    # the open loop is unstable inside the range: the closed loops were not
    assert any(min(z for _, z in csm_at(p.theta).modes()) < 0 for p in run.points)
    assert run.unstable_closures() == 0
    assert all(p.record.true_spectral_radius < 1.0 for p in run.points)
    for p in run.points[1:]:  # the controller in the loop passed the check on the prediction
        assert p.check_before.ok and p.check_before.stable
    for theta, reason in run.rejected_steps:
        assert reason and 32.0 < theta <= 38.0


@pytest.mark.slow
def test_lpv_model_predicts_between_points(run):
    lpv = run.lpv
    assert lpv is not None and lpv.n_modes == 3
    np.testing.assert_allclose(lpv.points, [p.theta for p in run.points])
    grid = np.linspace(32.0, 38.0, 49)
    ef, _ = lpv_errors(lpv, lambda t: csm_at(t).modes(), grid)
    assert ef.max() < 0.01


def test_tool_writes_the_lpv_model_and_json(tmp_path, capsys):
    out, js = tmp_path / "csm.lpv.npz", tmp_path / "run.json"
    status = tool.main(["--start", "32", "--stop", "33", "--duration", "20", "--quiet",
                        "--output", str(out), "--json", str(js)])
    text = capsys.readouterr().out
    assert status == 0, text
    assert "Table 2 analogue" in text and "0 unstable closed loop" in text
    lpv = LpvModel.load(out)
    assert lpv.scheduling == "rotor_speed" and list(lpv.points) == [32.0, 33.0]
    summary = json.loads(js.read_text())
    assert summary["completed"] and summary["unstable_closures"] == 0


@pytest.mark.parametrize("args, reason", [
    (["--step", "0.1", "--min-step", "0.5"], "min-step"),
    (["--output", "/nonexistent/dir/x.npz"], "does not exist"),
    (["--control-band", "40", "30"], "control-band"),
])
def test_tool_refuses_bad_arguments(args, reason, capsys):
    assert tool.main(args) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("envelope: error:") and reason in err[0]
