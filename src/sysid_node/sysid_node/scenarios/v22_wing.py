"""V-22-like wing for Table 1 / Fig. 3 of the paper: sine-dwell and sine-sweep flight tests.

Modes (Table 1): the symmetric wing beam (SWB) at 150, 200 and 250 kn with the frequencies and
damping ratios the paper reports (2.89 Hz 2.10 %, 2.86 Hz 3.2 %, 2.82 Hz 3.6 %; linear in
airspeed between), the symmetric wing torsion (SWT, 5.18 Hz, 4.58 %) and the 1 Hz rigid-body
mode of the repository's wing scenario; flaperon input gains and the three vertical
accelerometers (wing tips left and right, fuselage) of the ``wing_bending_drift`` bag.

An experiment is a flaperon command (the measured input) plus unmeasured turbulence (white,
through gust input gains) and sensor noise:

* :func:`sine_dwell_test`: the industry practice: dwell at the target mode's frequency (known
  to ``tuning_error`` from a previous test), stop, record the free decay;
* :func:`sine_sweep_test`: one linear sweep through the band, then a free decay.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..core.lti import simulate
from .excitations import sine_dwell, sweep
from .structures import modal_system

#: Table 1: airspeed [kn] -> SWB (frequency [Hz], damping ratio).
SWB_TABLE1 = {150.0: (2.89, 0.0210), 200.0: (2.86, 0.032), 250.0: (2.82, 0.036)}
SWT = (5.18, 0.0458)
RIGID = (1.0, 0.05)
#: flaperon command -> rigid body, SWB, SWT; unmeasured gust -> the same modes
FLAPERON_GAINS = np.array([0.4, 1.0, 0.8])
GUST_GAINS = np.array([1.0, 0.6, 0.3])
#: wing tip left, wing tip right, fuselage (vertical accelerations) x (rigid, SWB, SWT)
SHAPES = 0.05 * np.array([[1.0, 1.0, 0.6], [1.0, 1.0, -0.6], [1.0, -0.25, 0.05]])
WING_FS = 100.0


def swb_at(airspeed_kn: float) -> tuple[float, float]:
    """SWB frequency [Hz] and damping ratio at ``airspeed_kn`` (Table 1, linear between)."""
    kn = sorted(SWB_TABLE1)
    f = np.interp(airspeed_kn, kn, [SWB_TABLE1[k][0] for k in kn])
    z = np.interp(airspeed_kn, kn, [SWB_TABLE1[k][1] for k in kn])
    return float(f), float(z)


def wing_modes(airspeed_kn: float) -> dict[str, tuple[float, float]]:
    """True (frequency [Hz], damping ratio) per mode name."""
    return {"rigid": RIGID, "SWB": swb_at(airspeed_kn), "SWT": SWT}


def wing_at(airspeed_kn: float):
    """The wing as a continuous system: inputs [flaperon, gust], 3 accelerometer outputs."""
    m = wing_modes(airspeed_kn)
    names = ("rigid", "SWB", "SWT")
    gains = np.column_stack([FLAPERON_GAINS, GUST_GAINS])
    return modal_system([m[k][0] for k in names], [m[k][1] for k in names], gains, SHAPES)


@dataclass
class WingTest:
    """One flight-test record: flaperon command u (N, 1), accelerations y (N, 3), the sample
    where the excitation stops (the free decay starts) and the truth."""

    u: np.ndarray
    y: np.ndarray
    fs: float
    decay_start: int
    truth: dict[str, tuple[float, float]]


def _record(airspeed_kn: float, u: np.ndarray, rng: np.random.Generator, fs: float,
            turbulence: float, noise: float, decay_start: int) -> WingTest:
    gust = turbulence * rng.standard_normal(u.shape[0])
    y = simulate(wing_at(airspeed_kn), np.column_stack([u[:, 0], gust]), fs)
    y = y + noise * np.std(y, axis=0) * rng.standard_normal(y.shape)
    return WingTest(u, y, fs, decay_start, wing_modes(airspeed_kn))


def sine_dwell_test(airspeed_kn: float, rng: np.random.Generator, mode: str = "SWB",
                    dwell_s: float = 8.0, decay_s: float = 12.0, tuning_error: float = 0.005,
                    turbulence: float = 0.05, noise: float = 0.05,
                    fs: float = WING_FS) -> WingTest:
    """Dwell at the target mode's frequency times (1 + tuning_error N(0, 1)), then stop."""
    f = wing_modes(airspeed_kn)[mode][0] * (1.0 + tuning_error * rng.standard_normal())
    n_dwell, n = int(round(dwell_s * fs)), int(round((dwell_s + decay_s) * fs))
    u = np.zeros((n, 1))
    u[:n_dwell] = sine_dwell(n_dwell, fs, f)
    return _record(airspeed_kn, u, rng, fs, turbulence, noise, n_dwell)


def sine_sweep_test(airspeed_kn: float, rng: np.random.Generator, f0: float = 0.5,
                    f1: float = 8.0, sweep_s: float = 60.0, decay_s: float = 10.0,
                    turbulence: float = 0.05, noise: float = 0.05,
                    fs: float = WING_FS) -> WingTest:
    """One linear sweep f0 -> f1 [Hz], then a free decay."""
    n_sweep, n = int(round(sweep_s * fs)), int(round((sweep_s + decay_s) * fs))
    u = np.zeros((n, 1))
    u[:n_sweep] = sweep(n_sweep, fs, f0, f1)
    return _record(airspeed_kn, u, rng, fs, turbulence, noise, n_sweep)
