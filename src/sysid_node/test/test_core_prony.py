"""Prony's method (classical and modified) on free decays, and the Table 1 finding on the
V-22-like wing: one mode per sine dwell with Prony, several modes per sweep with DSRA."""

import numpy as np
import pytest
from sysid_node.core import identify
from sysid_node.core.inputs import InputError
from sysid_node.core.prony import decay_start, prony
from sysid_node.scenarios.v22_wing import sine_dwell_test, sine_sweep_test

FS = 100.0
MODES = [(2.8, 0.03), (5.18, 0.0458)]


def decay(n=1000, channels=((1.0, 0.3), (0.5, -0.4))):
    t = np.arange(n) / FS
    out = []
    for amps in channels:
        out.append(sum(a * np.exp(-z * 2 * np.pi * f * t)
                       * np.cos(2 * np.pi * f * np.sqrt(1 - z * z) * t + 0.3 + k)
                       for k, ((f, z), a) in enumerate(zip(MODES, amps, strict=True))))
    return np.column_stack(out)


@pytest.mark.parametrize("modified", [False, True])
def test_exact_without_noise(modified):
    res = prony(decay(), FS, 4, modified=modified)
    est = [(m.frequency_hz, m.damping_ratio) for m in res.modes]
    np.testing.assert_allclose(est, MODES, rtol=1e-6)
    assert res.converged and np.all(res.residual_rms < 1e-8)


def test_modified_prony_removes_the_classical_bias():
    rng = np.random.default_rng(0)
    y = decay()
    err = {False: [], True: []}
    for _ in range(12):
        yn = y + 0.05 * y.std(axis=0) * rng.standard_normal(y.shape)
        for modified in err:
            m = min(prony(yn, FS, 4, modified=modified, band=(1, 10)).modes,
                    key=lambda x: abs(x.frequency_hz - 2.8))
            err[modified].append((m.frequency_hz / 2.8 - 1, m.damping_ratio - 0.03))
    classic, modified = np.abs(np.mean(err[False], axis=0)), np.abs(np.mean(err[True], axis=0))
    assert modified[0] < 0.01 and modified[1] < 0.005
    assert modified[1] < classic[1] and modified[0] < classic[0]


def test_bad_input():
    with pytest.raises(InputError, match="order"):
        prony(decay(30), FS, 12)
    y = decay()
    y[3, 0] = np.nan
    with pytest.raises(InputError, match="NaN"):
        prony(y, FS, 4)
    with pytest.raises(InputError, match="zero variance"):
        prony(np.zeros((200, 1)), FS, 4)


def test_decay_start():
    u = np.zeros(100)
    u[:60] = np.sin(np.arange(60))
    assert decay_start(u) == 60  # the first sample after the dwell
    assert decay_start(np.zeros(5)) == 0


def test_one_mode_per_dwell_several_per_sweep():
    """The finding of Table 1: a sine dwell gives Prony (and DSRA) the dwelled mode; one sweep
    gives DSRA both structural modes; Prony has no free decay of each mode in a sweep."""
    rng = np.random.default_rng(5)
    t = sine_dwell_test(150.0, rng, turbulence=0.1)
    f_swb, z_swb = t.truth["SWB"]
    pr = prony(t.y[t.decay_start + 10 :, :2], t.fs, 6, band=(0.75 * f_swb, 1.25 * f_swb))
    assert len(pr.modes) == 1
    assert abs(pr.modes[0].frequency_hz / f_swb - 1) < 0.02
    assert abs(pr.modes[0].damping_ratio - z_swb) < 0.01
    sw = sine_sweep_test(150.0, rng, turbulence=0.1)
    model = identify(sw.y, sw.u, fs=sw.fs, order=6, block_rows=20, band=(0.5, 8.0))
    for name in ("SWB", "SWT"):
        f, z = sw.truth[name]
        m = min(model.modes, key=lambda x: abs(x.frequency_hz - f))
        # (the paper: 2.83 Hz / 2.86 % from the sweep against 2.87 Hz / 1.93 % from dwells)
        assert abs(m.frequency_hz / f - 1) < 0.02 and abs(m.damping_ratio - z) < 0.015
