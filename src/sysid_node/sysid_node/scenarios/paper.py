"""The seed paper's systems and data sets (Mehra & Prasanth, J. Aircraft 41(4) 2004).

* Sec. II: the abruptly changing system (1) with modes at 2 and 4 Hz for t <= 20 s and
  2, 4 and 6 Hz after (:func:`paper_example_systems`, :func:`paper_example_data`,
  :func:`paper_example_truth`).
* Sec. IV: the cobra stick model (CSM) identified open loop at 32 Hz rotor speed, printed in
  modal form (3) with 2 inputs and 2 outputs (:func:`cobra_stick_model`,
  :func:`cobra_example_data`), and its rotor-speed dependence (Table 2: the 32 Hz mode follows
  the rotor speed up to 38 Hz, :func:`cobra_stick_at`, an LPV structure for
  :func:`~sysid_node.scenarios.timevarying.simulate_scheduled`).
"""

from __future__ import annotations

import numpy as np

from ..core.lti import ContinuousSystem, simulate
from .excitations import white
from .noise import add_output_noise
from .timevarying import simulate_switching
from .truth import TrueMode

#: Time [s] at which the 6 Hz mode of the Sec. II example appears.
PAPER_EXAMPLE_SWITCH_TIME_S = 20.0

#: Table 2: (rotor speed [Hz], frequency [Hz], damping ratio) of the rotor-speed mode; at 32 Hz
#: the printed open-loop model (3) (31.83 Hz, undamped); above, the estimates of Table 2.
COBRA_ROTOR_MODE_TABLE2 = (
    (32.0, 200.0 / (2 * np.pi), 0.0),
    (33.0, 33.017, 0.0),
    (34.0, 34.00, 0.001),
    (36.0, 36.21, 0.0028),
    (38.0, 37.99, 0.002),
)


def paper_example_systems() -> tuple[ContinuousSystem, ContinuousSystem]:
    """The two systems of the Sec. II example: (2 & 4 Hz, t <= 20 s), (2, 4 & 6 Hz, t > 20 s).

    Each mode block is [[0, 1], [-w^2, -2 zeta w]], B = [0 1 ...]', C = [1 1 ...], D = 0.
    """
    blocks = [(157.91, 0.5), (631.65, 2.51), (1420.0, 3.76)]

    def build(k: int) -> ContinuousSystem:
        a = np.zeros((2 * k, 2 * k))
        for m, (w2, c) in enumerate(blocks[:k]):
            a[2 * m, 2 * m + 1] = 1.0
            a[2 * m + 1, 2 * m] = -w2
            a[2 * m + 1, 2 * m + 1] = -c
        b = np.tile([[0.0], [1.0]], (k, 1))
        c_out = np.ones((1, 2 * k))
        return ContinuousSystem(a, b, c_out, np.zeros((1, 1)))

    return build(2), build(3)


def paper_example_truth(
    duration_s: float = 40.0, switch_time_s: float = PAPER_EXAMPLE_SWITCH_TIME_S
) -> list[TrueMode]:
    """True modes of the Sec. II example over time (the 6 Hz mode from ``switch_time_s``)."""
    sys_a, sys_b = paper_example_systems()
    modes_a, modes_b = sys_a.modes(), sys_b.modes()
    ts = switch_time_s
    out = []
    for i, (f, z) in enumerate(modes_b):
        if i < len(modes_a):
            fa, za = modes_a[i]
            out.append(TrueMode(f"mode_{i + 1}", "structural", (0, ts, ts, duration_s),
                                (fa, fa, f, f), (za, za, z, z)))
        else:
            out.append(TrueMode(f"mode_{i + 1}", "structural", (ts, duration_s), (f, f), (z, z)))
    return out


def cobra_stick_model() -> ContinuousSystem:
    """The cobra stick model of Sec. IV (open loop, 32 Hz rotor speed), 2 inputs, 2 outputs.

    Modal blocks [[0, -1], [w^2, -2 zeta w]] with w^2 = 2.1e4, 4.0e4, 5.3e4 (23.06, 31.83 and
    36.64 Hz; damping 0.31 %, 0 % and 0.54 %), B, C, D as printed in the paper.
    """
    return _cobra(4.0e4, 0.0)


def _cobra(w2_rotor_mode: float, c_rotor_mode: float) -> ContinuousSystem:
    a = np.zeros((6, 6))
    for m, (w2, c) in enumerate([(2.1e4, 0.9), (w2_rotor_mode, c_rotor_mode), (5.3e4, 2.5)]):
        a[2 * m, 2 * m + 1] = -1.0
        a[2 * m + 1, 2 * m] = w2
        a[2 * m + 1, 2 * m + 1] = -c
    b = np.array([[0, 0], [-2.6, -2.9], [0, 0], [0, -0.3], [0, 0], [-2.1, -9.5]], dtype=float)
    c_out = np.array(
        [[-342.2, 4.6, 670.9, 1.3, 655.3, -1.5], [-23.3, 0.1, -57.3, -1.0, -482.7, 1.0]]
    )
    d = np.array([[-0.04, -0.04], [-0.04, 0.02]])
    return ContinuousSystem(a, b, c_out, d)


def cobra_rotor_mode(rotor_speed_hz) -> tuple[np.ndarray, np.ndarray]:
    """(frequency [Hz], damping ratio) of the rotor-speed mode at ``rotor_speed_hz``: linear
    between the points of :data:`COBRA_ROTOR_MODE_TABLE2` (32-38 Hz), held outside."""
    speed, freq, damp = np.array(COBRA_ROTOR_MODE_TABLE2).T
    return np.interp(rotor_speed_hz, speed, freq), np.interp(rotor_speed_hz, speed, damp)


def cobra_stick_at(rotor_speed_hz: float) -> ContinuousSystem:
    """The cobra stick model with its second mode at the rotor speed's frequency and damping
    (Table 2: 31.83 Hz at 32 Hz rotor speed to 37.99 Hz at 38 Hz); the 23 and 36.6 Hz modes,
    B, C and D as in (3). At 32 Hz this is :func:`cobra_stick_model`."""
    f, z = cobra_rotor_mode(float(rotor_speed_hz))
    w = 2 * np.pi * float(f)
    return _cobra(w * w, 2 * float(z) * w)


def paper_example_data(
    duration_s: float = 40.0,
    fs: float = 100.0,
    noise_fraction: float = 0.05,
    seed: int = 0,
    switch_time_s: float = PAPER_EXAMPLE_SWITCH_TIME_S,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Sec. II scenario: (t (N,), u (N, 1), y (N, 1)) with the 6 Hz mode from ``switch_time_s``.

    Wideband input, output noise ``noise_fraction`` of the output std (over the whole record).
    """
    rng = np.random.default_rng(seed)
    n = int(round(duration_s * fs))
    sys_a, sys_b = paper_example_systems()
    u = white(n, 1, rng)
    y = simulate_switching([(0.0, sys_a), (switch_time_s, sys_b)], u, fs)
    y = add_output_noise(y, noise_fraction, rng)
    return np.arange(n) / fs, u, y


def cobra_example_data(
    duration_s: float = 60.0, fs: float = 256.0, noise_fraction: float = 0.05, seed: int = 7
) -> tuple[ContinuousSystem, np.ndarray, np.ndarray]:
    """Sec. IV scenario: (system, u (N, 2), y (N, 2)) of the cobra stick model driven by two
    white inputs, output noise ``noise_fraction`` of each output's std. 256 Hz gives about 7
    samples per period of the 36.6 Hz mode."""
    rng = np.random.default_rng(seed)
    system = cobra_stick_model()
    u = white(int(round(duration_s * fs)), 2, rng)
    y = add_output_noise(simulate(system, u, fs), noise_fraction, rng)
    return system, u, y
