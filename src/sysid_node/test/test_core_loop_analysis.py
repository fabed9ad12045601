"""loop_margins(): python-control margins of controller -> notch -> plant; a notch on a
structural peak restores stability, a wider one costs more phase at the crossover."""

import control as ct
import numpy as np
from scipy import signal
from sysid_node.core.loop_analysis import loop_margins, notch_system

FS = 200.0


def rigid():
    w = 2 * np.pi * 1.5
    return ct.tf([w * w], [1, 1.4 * w, w * w]) * ct.tf([1], [1, 0])


def mode(f, z):
    w = 2 * np.pi * f
    return ct.tf([w * w], [1, 2 * z * w, w * w])


def notch(f, q):
    b, a = signal.iirnotch(f, q, fs=FS)
    return np.concatenate([b, a])[None, :]


def controller():
    c = ct.tf([1, 2 * np.pi * 0.1], [1, 0])  # PI
    g = abs(complex(np.asarray((c * rigid()).frequency_response([np.pi]).complex).ravel()[0]))
    return c * (1 / g)  # crossover at 0.5 Hz


def test_matches_python_control_on_a_plain_loop():
    m = loop_margins(rigid(), controller(), None, FS)
    loop = ct.c2d(controller(), 1 / FS, "tustin") * ct.c2d(rigid(), 1 / FS, "zoh")
    omega = 2 * np.pi * np.geomspace(0.01, 99.0, 6000)
    resp = np.asarray(loop.frequency_response(omega).complex).ravel()
    loop_frd = ct.frd(resp, omega, dt=1 / FS)  # the 'poly' method fails on this loop
    gm, pm, _, wpc, wgc, _ = ct.stability_margins(loop_frd)
    assert m.stable
    assert abs(m.crossover_hz - 0.5) < 0.01 and abs(m.crossover_hz - wgc / (2 * np.pi)) < 0.01
    assert abs(m.phase_margin_deg - pm) < 0.5
    assert abs(m.gain_margin_db - 20 * np.log10(gm)) < 0.2
    assert m.notch_phase_lag_deg == 0.0


def test_notch_restores_stability_and_width_costs_phase():
    c = controller()
    peak = abs(complex(np.asarray((c * mode(2.8, 0.02)).frequency_response(
        [2 * np.pi * 2.8]).complex).ravel()[0]))
    plant = rigid() + (4.0 / peak) * mode(2.8, 0.02)  # +12 dB structural peak
    none = loop_margins(plant, c, None, FS)
    narrow = loop_margins(plant, c, notch(2.8, 8.0), FS)
    wide = loop_margins(plant, c, notch(2.8, 1.5), FS)
    assert none.peak_structural_gain_db > 6.0
    assert narrow.stable and wide.stable
    assert 0 < narrow.notch_phase_lag_deg < wide.notch_phase_lag_deg
    assert wide.phase_margin_deg < narrow.phase_margin_deg
    assert narrow.peak_structural_gain_db < 0.0


def test_notch_system_is_the_cascade():
    sos = np.vstack([notch(2.8, 5.0), notch(5.2, 5.0)])
    f = np.array([1.0, 2.8, 4.0, 5.2])
    _, h = signal.sosfreqz(sos, worN=f, fs=FS)
    n = notch_system(sos, FS)
    hc = np.asarray(n.frequency_response(2 * np.pi * f).complex).ravel()
    np.testing.assert_allclose(hc, h, atol=1e-9)
