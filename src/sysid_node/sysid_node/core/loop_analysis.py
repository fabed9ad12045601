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


def crossings(omega: np.ndarray, resp: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Margins of a negative-feedback loop from its frequency response ``resp`` at ``omega``
    (dense, increasing): gain margins [dB] at every phase crossing (-180 deg mod 360; positive
    = the gain may rise, negative = it may fall), and the phase margins [deg, in (-180, 180]]
    at every gain crossing with their frequencies [rad/s], lowest first. Linear interpolation
    in log frequency between the grid points. (python-control's ``stability_margins`` on the
    same data gives the same crossings but spends about a second per loop in its
    stability-margin minimisation.)"""
    lw = np.log(omega)
    mag = np.log(np.maximum(np.abs(resp), 1e-300))
    ph = np.unwrap(np.angle(resp))
    # gain crossings: log|L| changes sign
    i = np.flatnonzero(np.sign(mag[:-1]) * np.sign(mag[1:]) < 0)
    f = mag[i] / (mag[i] - mag[i + 1])
    wgc = np.exp(lw[i] + f * (lw[i + 1] - lw[i]))
    pm = (ph[i] + f * (ph[i + 1] - ph[i])) + np.pi  # PM = 180 deg + phase
    pm = np.degrees((pm + np.pi) % (2 * np.pi) - np.pi)
    # phase crossings: (phase + pi) crosses a multiple of 2 pi
    k = np.floor((ph + np.pi) / (2 * np.pi))
    j = np.flatnonzero(k[:-1] != k[1:])
    level = 2 * np.pi * np.maximum(k[j], k[j + 1]) - np.pi
    g = (level - ph[j]) / (ph[j + 1] - ph[j])
    gm = -(mag[j] + g * (mag[j + 1] - mag[j])) * 20 / np.log(10)
    return gm, pm, wgc


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
    gains, phases, wgc = crossings(omega, resp)
    gmin = float(np.min(np.abs(gains))) if gains.size else float("inf")
    if wgc.size:
        wc, pm_c = float(wgc[0]), float(phases[0])
        pmin = float(np.min(np.abs(phases)))
    else:
        wc, pm_c, pmin = float("nan"), float("inf"), float("inf")
    lag = float("nan")
    if np.isfinite(wc):
        hn = complex(np.asarray(n.frequency_response([wc]).complex).ravel()[0])
        lag = float(-np.degrees(np.angle(hn)))
    above = omega > 1.5 * (wc if np.isfinite(wc) else omega[0])
    peak = float(20 * np.log10(np.max(np.abs(resp[above])))) if above.any() else float("nan")
    return LoopMargins(stable, wc / (2 * np.pi), pm_c, pmin, gmin, lag, peak)
