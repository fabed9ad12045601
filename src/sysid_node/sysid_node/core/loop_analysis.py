"""Stability margins of a flight-control loop with a notch bank in its feedback path (Sec. III:
"notch filters must be designed wider than required ... phase lag increases with notch width
... degradation in overall performance and possibly instability"), with python-control.

The loop (negative feedback, broken at the plant input) is L = C N G: plant G (rigid-body
dynamics plus the structural modes the sensor sees), notch cascade N (second-order sections
``[b0 b1 b2 1 a1 a2]`` at ``fs``, the layout of ``notch_filter_node.sections``) and controller
C, all discrete at ``fs`` (continuous parts by zero-order hold). :func:`loop_margins` returns
the margins python-control finds on a dense frequency grid: the phase margin at the
flight-control crossover (the lowest gain crossover), the smallest distance to instability
over every crossing (a structural peak above 0 dB makes more of them), the gain margin, closed-
loop stability, and the notch's phase lag at the crossover (its phase cost).
"""

from __future__ import annotations

from dataclasses import dataclass

import control as ct
import numpy as np


@dataclass(frozen=True)
class LoopMargins:
    """Margins of L = C N G (negative feedback)."""

    stable: bool  # closed loop (all poles inside the unit circle)
    crossover_hz: float  # lowest gain crossover (the flight-control crossover) [Hz]
    phase_margin_deg: float  # at crossover_hz [deg]
    min_phase_margin_deg: float  # smallest |PM| over every gain crossover [deg]
    gain_margin_db: float  # smallest |GM| over every phase crossover [dB]
    notch_phase_lag_deg: float  # phase lag of N at crossover_hz [deg]
    peak_structural_gain_db: float  # largest |L| above 1.5 x crossover [dB]


def notch_system(sos: np.ndarray | None, fs: float) -> ct.TransferFunction:
    """The cascade of second-order sections as a discrete python-control system (1 if none)."""
    dt = 1.0 / fs
    out = ct.tf([1.0], [1.0], dt)
    if sos is None:
        return out
    for row in np.atleast_2d(np.asarray(sos, dtype=float)):
        out = out * ct.tf(row[:3], row[3:], dt)
    return out


def _discrete(sys: ct.LTI, fs: float, method: str) -> ct.LTI:
    if sys.isdtime(strict=True):
        if abs(sys.dt - 1.0 / fs) > 1e-12 * (1.0 / fs):
            raise ValueError(f"discrete system at dt={sys.dt}, the loop runs at 1/{fs}")
        return sys
    return ct.c2d(sys, 1.0 / fs, method=method)


def loop_margins(
    plant: ct.LTI,
    controller: ct.LTI,
    notch_sos: np.ndarray | None,
    fs: float,
    f_min_hz: float = 0.01,
    n_freq: int = 6000,
) -> LoopMargins:
    """Margins of the loop controller -> notch bank -> plant (SISO, negative feedback).

    ``plant`` and ``controller`` are python-control systems, continuous (discretised at ``fs``,
    plant by zero-order hold, controller by Tustin) or discrete at ``fs``; ``notch_sos`` the
    bank's sections (None: no notch)."""
    g = _discrete(plant, fs, "zoh")
    c = _discrete(controller, fs, "tustin")
    n = notch_system(notch_sos, fs)
    loop = c * n * g
    poles = ct.poles(ct.feedback(ct.ss(loop), 1))
    stable = bool(np.max(np.abs(poles), initial=0.0) < 1.0)
    omega = 2 * np.pi * np.geomspace(f_min_hz, 0.499 * fs, n_freq)
    resp = np.asarray(loop.frequency_response(omega).complex).ravel()
    gm, pm, _, wpc, wgc, _ = ct.stability_margins(ct.frd(resp, omega, dt=1.0 / fs),
                                                  returnall=True)
    gm, pm = np.asarray(gm, float), np.asarray(pm, float)
    wpc, wgc = np.asarray(wpc, float), np.asarray(wgc, float)
    ok = np.isfinite(gm) & (gm > 0)
    gmin = float(np.min(np.abs(20 * np.log10(gm[ok])))) if ok.any() else float("inf")
    wrap = np.abs((pm + 180.0) % 360.0 - 180.0)
    if wgc.size:
        k = int(np.argmin(wgc))
        wc = float(wgc[k])
        pm_c = float(pm[k])
        pmin = float(np.min(wrap))
    else:
        wc, pm_c, pmin = float("nan"), float("inf"), float("inf")
    lag = float("nan")
    if np.isfinite(wc):
        hn = complex(np.asarray(n.frequency_response([wc]).complex).ravel()[0])
        lag = float(-np.degrees(np.angle(hn)))
    above = omega > 1.5 * (wc if np.isfinite(wc) else omega[0])
    peak = float(20 * np.log10(np.max(np.abs(resp[above])))) if above.any() else float("nan")
    return LoopMargins(stable, wc / (2 * np.pi), pm_c, pmin, gmin, lag, peak)
