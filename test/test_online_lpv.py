"""Online LPV model (#16 item 3), pipeline + notch policy: the CSM (Sec. IV) is identified while
its test input runs at 33 Hz rotor speed, then the input stops (the identification is starved)
while the rotor speed ramps to 35 Hz over 10 s and the moving mode follows it
(``scenarios.csm_rotor.starved_run``). The bag (vibration, excitation, rotor_speed) goes through
the offline tool, i.e. the node's own pipeline; each estimate carries the LPV model's predicted
modes at its stamp. The notch bank is driven by those estimates (delivered 0.1 s after their
data) and, at every block, the true moving mode's resonance times the bank gives the peak
reduction the loop sees: with the model the bank follows the prediction (PREDICTED) and keeps
the required 15 dB throughout the starved part; without it (the same estimates without
predicted modes, as from a node without ``lpv_model``) it holds, then takes the preset
fallback notch (a static notch over the rotor-speed range), which does not.

The LPV model is built from the CSM's local models at 1 Hz steps of rotor speed (the envelope
tool's identified model is checked against the truth in test_core_envelope.py).
"""

import math

import numpy as np
import pytest
from notch_filter_node.adaptive import AdaptiveNotchFilter
from notch_filter_node.policy import (
    BANK_FALLBACK,
    BANK_HOLDING,
    BANK_PREDICTED,
    EstimateInput,
    ModeInput,
    PolicyConfig,
)
from sysid_node.core.lpv import LpvModel
from sysid_node.scenarios.csm_rotor import csm_at, starved_run
from sysid_node.tools import offline

from sysid_node import bag_io

pytestmark = pytest.mark.slow

REQUIRED = 15.0  # [dB] the policy's default peak_reduction
T0 = 1000.0  # [s] stamp of the first sample
DELIVERY = 0.1  # [s] estimate delivered this long after its data
BLOCK = 16  # samples per filter block


@pytest.fixture(scope="module")
def starved(tmp_path_factory):
    """The run, and the offline tool's records over its bag with the scheduling topic."""
    tmp = tmp_path_factory.mktemp("online_lpv")
    run = starved_run(np.random.default_rng(3))
    pts = np.arange(32.0, 38.01, 1.0)
    lpv = tmp / "csm.lpv.npz"
    LpvModel.from_systems(pts, [csm_at(p) for p in pts], scheduling="rotor_speed",
                          unit="Hz").save(lpv)
    bag = tmp / "starved"
    bag_io.write_signals(bag, {
        "/vibration": (T0 + run.t, run.y, ("y0", "y1")),
        "/excitation": (T0 + run.t, run.u, ("u0", "u1")),
        "/rotor_speed": (T0 + run.schedule_t, run.rotor_speed[:, None], ("rotor_speed[Hz]",)),
    })
    values = {"scheduling_topic": "rotor_speed", "lpv_model": str(lpv)}
    records, pipeline, _ = offline.run(bag, values)
    return run, records, pipeline


def _modes(ms) -> list[ModeInput]:
    return [ModeInput(m.id, m.status, m.frequency_hz, m.frequency_std_hz, m.damping_ratio,
                      m.damping_std, m.amplitude) for m in ms]


def bank_run(run, records, with_model: bool):
    """(t, true moving mode's peak reduction [dB], bank state, the bank's phase lag at the
    crossover [deg] as /diagnostics publishes it) at every filter block."""
    from notch_filter_node import resonance as R

    cfg = PolicyConfig(peak_reduction=REQUIRED, fallback_center=35.0, fallback_bandwidth=6.0)
    flt = AdaptiveNotchFilter(cfg, run.fs, 2)
    ests = []
    for r in records:
        t = r.stamp_ns * 1e-9 - T0
        ests.append((t + DELIVERY, EstimateInput(
            t, r.converged, _modes(r.modes), r.health, r.health_reason, t + DELIVERY,
            _modes(r.predicted_modes) if with_model else ())))
    rows, k = [], 0
    for a in range(0, run.t.size - BLOCK + 1, BLOCK):
        t_last = (a + BLOCK - 1) / run.fs
        while k < len(ests) and ests[k][0] <= t_last:
            flt.set_estimate(ests[k][1])
            k += 1
        flt.process(np.zeros((BLOCK, 2)), t_last)
        p = flt.bank.params
        c, zp, zz = R.section_damping(p.center, p.bandwidth, p.depth_db, run.fs,
                                      p.shape_depth_db)
        theta = float(np.interp(t_last, run.t, run.theta))
        f, z = min(csm_at(theta).modes(), key=lambda m: abs(m[0] - theta))
        pr = R.peak_reduction_db(np.array([f]), np.array([z]), c, zp, zz, run.fs)[0]
        rows.append((t_last, pr, flt.status().bank_state, flt.phase_lag()))
    return np.array(rows)


def test_estimates_carry_the_scheduling_value_and_the_prediction(starved):
    """Each record: the newest rotor-speed sample at or before its stamp, and the LPV model's
    modes there (the moving one within 0.5 % of the truth all along)."""
    run, records, pipeline = starved
    stamps = np.array([r.stamp_ns * 1e-9 - T0 for r in records])
    theta = np.array([r.scheduling_value for r in records])
    k = np.searchsorted(run.schedule_t, stamps + 1e-9, side="right") - 1
    ok = k >= 0
    np.testing.assert_allclose(theta[ok], run.rotor_speed[k[ok]], rtol=0, atol=1e-9)
    assert np.all(np.isnan(theta[~ok]))
    err = []
    for r, t in zip(records, stamps, strict=True):
        if not math.isfinite(r.scheduling_value):
            continue
        assert [m.id for m in r.predicted_modes] == [1, 2, 3]
        f_true = run.moving_mode_hz(t)[0]
        err.append(min(abs(m.frequency_hz - f_true) for m in r.predicted_modes) / f_true)
    print(f"\npredicted moving mode: max error {100 * max(err):.2f} % over {len(err)} "
          "estimates")
    assert max(err) < 0.005
    st = pipeline.scheduling_status()
    assert st["lpv_in_range"] and 0 <= st["scheduling_age_s"] <= 0.1 + 1e-9


def test_starved_identification_notch_follows_the_lpv_prediction(starved):
    run, records, _ = starved
    starve = run.starve_time_s
    out = {}
    for with_model in (True, False):
        rows = bank_run(run, records, with_model)
        t, pr, state, lag = rows.T
        s = t >= starve
        out[with_model] = (pr[s], state[s])
        print(f"\n{'LPV model' if with_model else 'no model (preset fallback)'}: starved "
              f"{starve:g}-{t[-1]:.0f} s, true moving mode {run.moving_mode_hz(starve)[0]:.2f}"
              f" -> {run.moving_mode_hz(t[-1])[0]:.2f} Hz: peak reduction min "
              f"{pr[s].min():.1f} dB, median {np.median(pr[s]):.1f} dB, >= {REQUIRED:g} dB in "
              f"{np.mean(pr[s] >= REQUIRED):.1%} of blocks; bank PREDICTED "
              f"{np.mean(state[s] == BANK_PREDICTED):.0%}, HOLDING "
              f"{np.mean(state[s] == BANK_HOLDING):.0%}, FALLBACK "
              f"{np.mean(state[s] == BANK_FALLBACK):.0%}; phase lag at the crossover median "
              f"{np.median(lag[s]):.2f} deg; identified part (5 s - starve) min "
              f"{pr[(t >= 5.0) & ~s].min():.1f} dB")
    pr, state = out[True]
    assert pr.min() >= REQUIRED  # throughout the starved part
    assert np.mean(state == BANK_PREDICTED) >= 0.8
    pr0, state0 = out[False]
    assert not np.any(state0 == BANK_PREDICTED)
    assert pr0.min() < REQUIRED  # the preset does not keep the moving mode down
