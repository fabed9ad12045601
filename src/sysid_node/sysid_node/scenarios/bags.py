"""The scenarios of the committed bags (``bags/``, fixed seeds); ``bags/generate_bags.py`` and
``bags/hidden/generate_hidden.py`` only write them.

:data:`BAG_SCENARIOS` (Mehra & Prasanth, J. Aircraft 41(4) 2004), each a :class:`BagScenario`:

* ``paper_example``: Sec. II, system (1) with 2 and 4 Hz modes, a 6 Hz mode appearing at 20 s;
  100 Hz, wideband input, 5 % output noise (the shipped default bag).
* ``wing_bending_drift``: a V-22-like symmetric wing beam (SWB) mode drifting 2.6 -> 3.0 Hz
  with airspeed 150 -> 250 kn (damping 2.1 -> 3.6 %, the trend of Table 1), the symmetric wing
  torsion mode (5.18 Hz, 4.6 %, Table 1) and a lightly damped 1 Hz rigid-body mode that the
  flight controller must keep; 100 Hz, 60 s, 3 accelerometers.
* ``cobra_stick``: the Sec. IV cobra stick model (3), 2 wideband inputs, 2 outputs, 256 Hz.
* ``output_only``: four structural modes driven by unmeasured turbulence, 4 accelerometers,
  no ``/excitation``.

:func:`hidden_effect` builds the ``bags/hidden`` records (:data:`HIDDEN_SCENARIOS`): the 2 & 4 Hz
system of Sec. II at 50 Hz for 60 s, white input, 2 % output noise, plus one effect of
:mod:`.effects` that the nominal order-4 model lacks (or none: ``clean``).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from ..core.controller import DiscreteController
from ..core.lti import simulate
from . import effects as E
from .closedloop import simulate_closed_loop
from .excitations import white
from .noise import add_output_noise
from .paper import (
    PAPER_EXAMPLE_SWITCH_TIME_S,
    cobra_stick_model,
    paper_example_data,
    paper_example_systems,
    paper_example_truth,
)
from .structures import modal_system
from .timevarying import simulate_scheduled, simulate_time_varying
from .truth import TrueMode

START_TIME_S = 1_700_000_000.0  # stamp of the first sample [s since epoch]
KNOT = 0.514444  # [m/s]
SCHEDULE_RATE = 10.0  # rate of /airspeed and /rotor_speed [Hz]
NOISE = 0.05  # output noise, fraction of each channel's std


@dataclass
class BagScenario:
    """Signals of one bag (``{topic: (t [s from start], values (N, c), channel names)}``)."""

    name: str
    description: str
    fs: float
    seed: int
    signals: dict[str, tuple[np.ndarray, np.ndarray, list[str]]]
    modes: list[TrueMode]
    extra: dict = field(default_factory=dict)

    @property
    def duration(self) -> float:
        return max(float(t[-1]) for t, _, _ in self.signals.values()) + 1.0 / self.fs

    def truth(self) -> dict:
        """The content of ``<name>.truth.json``."""
        topics = {
            topic: {
                "channels": names,
                "rate_hz": float(np.round(1.0 / np.median(np.diff(t)), 6)),
                "samples": int(len(t)),
            }
            for topic, (t, _, names) in self.signals.items()
        }
        return {
            "name": self.name,
            "description": self.description,
            "seed": self.seed,
            "sample_rate_hz": self.fs,
            "duration_s": self.duration,
            "start_time_s": START_TIME_S,
            "noise_fraction": NOISE,
            "output_only": "/excitation" not in self.signals,
            "topics": topics,
            "modes_note": (
                "t_s is time since start_time_s; frequency_hz and damping_ratio are linear "
                "between the t_s points; a mode exists from t_s[0] to t_s[-1]"
            ),
            "modes": [m.as_dict() for m in self.modes],
            **self.extra,
        }


def _schedule_times(duration: float) -> np.ndarray:
    return np.arange(int(round(duration * SCHEDULE_RATE))) / SCHEDULE_RATE


def paper_example(seed: int = 1) -> BagScenario:
    """Sec. II: 2 and 4 Hz, a 6 Hz mode from 20 s; 100 Hz, 40 s, wideband input, 5 % noise."""
    fs, duration = 100.0, 40.0
    t, u, y = paper_example_data(duration_s=duration, fs=fs, noise_fraction=NOISE, seed=seed)
    return BagScenario(
        "paper_example",
        "Sec. II example: modes at 2 and 4 Hz, a 6 Hz mode appears at 20 s (system (1)); "
        "wideband input, 5 % output noise, 100 Hz",
        fs,
        seed,
        {"/vibration": (t, y, ["y"]), "/excitation": (t, u, ["u"])},
        paper_example_truth(duration),
        {"switch_time_s": PAPER_EXAMPLE_SWITCH_TIME_S},
    )


def wing_bending_drift(seed: int = 2) -> BagScenario:
    """V-22-like SWB mode drifting 2.6 -> 3.0 Hz with airspeed, SWT 5.18 Hz, 1 Hz rigid body."""
    fs, duration, segment = 100.0, 60.0, 0.25
    rng = np.random.default_rng(seed)
    n = int(round(duration * fs))

    def airspeed_kn(t: np.ndarray | float) -> np.ndarray:
        return np.interp(t, [0.0, 10.0, 50.0, duration], [150.0, 150.0, 250.0, 250.0])

    def swb(t: np.ndarray | float) -> tuple[np.ndarray, np.ndarray]:
        s = (airspeed_kn(t) - 150.0) / 100.0
        return 2.6 + 0.4 * s, 0.021 + 0.015 * s

    rigid = (1.0, 0.05)
    swt = (5.18, 0.0458)
    b = np.array([[0.4], [1.0], [0.8]])  # flaperon command -> rigid body, SWB, SWT
    shapes = np.array(  # wing tip left, wing tip right, fuselage (vertical accelerations)
        [[1.0, 1.0, 0.6], [1.0, 1.0, -0.6], [1.0, -0.25, 0.05]]
    )

    def system_at(t: float):
        f, z = swb(t)
        return modal_system(
            [rigid[0], float(f), swt[0]], [rigid[1], float(z), swt[1]], b, shapes * 0.05
        )

    u = white(n, 1, rng)
    y = add_output_noise(simulate_time_varying(system_at, u, fs, segment), NOISE, rng)
    t = np.arange(n) / fs
    t_s = _schedule_times(duration)
    v = airspeed_kn(t_s) * KNOT + 0.2 * rng.standard_normal(t_s.size)  # [m/s], sensor noise
    nr = 333.0 / 60.0 + 0.005 * rng.standard_normal(t_s.size)  # proprotor 333 rpm [Hz]
    bp = np.array([0.0, 10.0, 50.0, duration])
    f_b, z_b = swb(bp)
    modes = [
        TrueMode.constant("rigid_body_1hz", "rigid_body", *rigid, 0.0, duration),
        TrueMode("symmetric_wing_beam", "structural", bp, f_b, z_b),
        TrueMode.constant("symmetric_wing_torsion", "structural", *swt, 0.0, duration),
    ]
    return BagScenario(
        "wing_bending_drift",
        "V-22-like symmetric wing beam mode drifting 2.6 -> 3.0 Hz as airspeed ramps "
        "150 -> 250 kn (10-50 s), wing torsion 5.18 Hz, 1 Hz rigid-body mode to keep; "
        "flaperon wideband input, 3 accelerometers, 5 % noise, 100 Hz",
        fs,
        seed,
        {
            "/vibration": (
                t,
                y,
                ["wing_tip_left_z[m/s^2]", "wing_tip_right_z[m/s^2]", "fuselage_z[m/s^2]"],
            ),
            "/excitation": (t, u, ["flaperon_cmd[rad]"]),
            "/airspeed": (t_s, v[:, None], ["airspeed[m/s]"]),
            "/rotor_speed": (t_s, nr[:, None], ["rotor_speed[Hz]"]),
        },
        modes,
        {
            "scheduling": {
                "signal": "/airspeed",
                "airspeed_mps": [round(float(x * KNOT), 4) for x in airspeed_kn(bp)],
                "t_s": bp.tolist(),
                "mode": "symmetric_wing_beam",
                "frequency_hz_per_mps": round(0.4 / (100.0 * KNOT), 6),
            },
            "simulation_segment_s": segment,
        },
    )


def cobra_stick(seed: int = 3) -> BagScenario:
    """Sec. IV cobra stick model (3), open loop at 32 Hz rotor speed: 2 in, 2 out, 256 Hz."""
    fs, duration = 256.0, 30.0
    rng = np.random.default_rng(seed)
    n = int(round(duration * fs))
    csm = cobra_stick_model()
    u = white(n, 2, rng)
    y = add_output_noise(simulate(csm, u, fs), NOISE, rng)
    t = np.arange(n) / fs
    t_s = _schedule_times(duration)
    nr = 32.0 + 0.01 * rng.standard_normal(t_s.size)
    modes = [
        TrueMode.constant(f"csm_mode_{i + 1}", "structural", f, z, 0.0, duration)
        for i, (f, z) in enumerate(csm.modes())
    ]
    return BagScenario(
        "cobra_stick",
        "Sec. IV cobra stick model (3), open loop at 32 Hz rotor speed: 2 wideband inputs, "
        "2 accelerometers, 5 % noise, 256 Hz",
        fs,
        seed,
        {
            "/vibration": (t, y, ["acc_1", "acc_2"]),
            "/excitation": (t, u, ["shaker_1", "shaker_2"]),
            "/rotor_speed": (t_s, nr[:, None], ["rotor_speed[Hz]"]),
        },
        modes,
    )


def output_only(seed: int = 4) -> BagScenario:
    """Four structural modes driven by unmeasured turbulence; 4 accelerometers, no input topic."""
    fs, duration = 100.0, 40.0
    rng = np.random.default_rng(seed)
    n = int(round(duration * fs))
    freqs = np.array([1.8, 3.4, 5.9, 8.2])
    zetas = np.array([0.02, 0.015, 0.03, 0.02])
    b = np.array([[1.0, 0.3], [0.5, 1.0], [0.8, -0.6], [0.4, 0.7]])  # two gust inputs
    shapes = 0.02 * np.array(
        [[1.0, 0.8, 0.5, 0.3], [1.0, -0.8, 0.5, -0.3], [0.6, 0.3, -1.0, 0.6], [0.2, 0.5, 0.4, 1.0]]
    )
    system = modal_system(freqs, zetas, b, shapes)
    w = white(n, 2, rng)  # turbulence, not recorded
    y = add_output_noise(simulate(system, w, fs), NOISE, rng)
    t = np.arange(n) / fs
    t_s = _schedule_times(duration)
    v = 100.0 + 0.3 * rng.standard_normal(t_s.size)
    modes = [
        TrueMode.constant(f"mode_{i + 1}", "structural", f, z, 0.0, duration)
        for i, (f, z) in enumerate(system.modes())
    ]
    return BagScenario(
        "output_only",
        "Output-only: 4 structural modes (1.8, 3.4, 5.9, 8.2 Hz) driven by unmeasured "
        "turbulence, 4 accelerometers, 5 % noise, 100 Hz, no /excitation topic",
        fs,
        seed,
        {
            "/vibration": (
                t,
                y,
                ["wing_left_z[m/s^2]", "wing_right_z[m/s^2]", "tail_z[m/s^2]", "nacelle_z[m/s^2]"],
            ),
            "/airspeed": (t_s, v[:, None], ["airspeed[m/s]"]),
        },
        modes,
    )


BAG_SCENARIOS: dict[str, Callable[[], BagScenario]] = {
    "paper_example": paper_example,
    "wing_bending_drift": wing_bending_drift,
    "cobra_stick": cobra_stick,
    "output_only": output_only,
}

# --------------------------------------------------------------------------------------------
# bags/hidden: one hidden effect each on the Sec. II structure
# --------------------------------------------------------------------------------------------

HIDDEN_FS = 50.0
HIDDEN_DURATION_S = 60.0
HIDDEN_SIGNAL_RATE = 10.0  # scheduling / rotating-speed topics [Hz]
HIDDEN_NOISE = 0.02
HIDDEN_PROCESS_NOISE = 0.1  # std of the unmeasured force relative to the unit-variance input
HIDDEN_NOMINAL_ORDER = 4
HIDDEN_SCENARIOS = ("clean", *E.EFFECTS)
#: seeds of the committed bags/hidden records
HIDDEN_SEEDS = {name: 100 + k for k, name in enumerate(HIDDEN_SCENARIOS)}
#: the 4 Hz mode of the parameter_varying record: 4 Hz at 60 m/s, +-1 Hz at 80 / 40 m/s
hidden_lpv_frequency = E.linear_schedule(4.0, 1.0 / 20.0, 60.0)


@dataclass
class HiddenEffectRecord:
    """One hidden-effect record: sampled output/input plus slow signals and the truth."""

    name: str
    t: np.ndarray
    y: np.ndarray
    u: np.ndarray
    signals: dict[str, tuple[np.ndarray, np.ndarray]] = field(default_factory=dict)
    truth: dict = field(default_factory=dict)


def _slow(t_fast: np.ndarray, fn) -> tuple[np.ndarray, np.ndarray]:
    ts = np.arange(0.0, t_fast[-1] + 1e-9, 1.0 / HIDDEN_SIGNAL_RATE)
    return ts, fn(ts)


def _airspeed_distractor(t: np.ndarray) -> dict:
    return {"/airspeed": _slow(t, lambda s: 60.0 + 10.0 * np.sin(2 * np.pi * s / 45.0))}


def hidden_airspeed(t: np.ndarray) -> np.ndarray:
    """Airspeed [m/s] of the parameter_varying record: flight-test points 40, 60, 80 m/s in the
    first 60 % of the record, then a slow deceleration 80 -> 40 m/s (validation between the
    test points)."""
    knots_t = [0.0, 10.5, 12.5, 23.0, 25.0, 36.0, 60.0]
    knots_v = [40.0, 40.0, 60.0, 60.0, 80.0, 80.0, 40.0]
    return np.interp(t, knots_t, knots_v)


def hidden_effect(name: str, seed: int = 0) -> HiddenEffectRecord:
    """Build the hidden-effect record ``name`` (one of :data:`HIDDEN_SCENARIOS`)."""
    if name not in HIDDEN_SCENARIOS:
        raise ValueError(f"unknown scenario {name!r}; one of {', '.join(HIDDEN_SCENARIOS)}")
    fs = HIDDEN_FS
    rng = np.random.default_rng(seed)
    n = int(round(HIDDEN_DURATION_S * fs))
    t = np.arange(n) / fs
    sys_a, sys_b = paper_example_systems()
    u = white(n, 1, rng)
    w = HIDDEN_PROCESS_NOISE * white(n, 1, rng)  # unmeasured turbulence on the structure
    truth: dict = {"effect": name if name != "clean" else None, "fs": fs}
    signals: dict = {}

    def noisy(y0: np.ndarray) -> np.ndarray:
        return add_output_noise(y0, HIDDEN_NOISE, rng)

    if name == "clean":
        y = noisy(simulate(sys_a, u + w, fs))
        signals = _airspeed_distractor(t)
    elif name == "missing_mode":
        f6, z6 = sys_b.modes()[2]
        y = noisy(simulate(sys_b, u + w, fs))
        truth.update(frequency_hz=f6, damping=z6)
    elif name == "periodic_disturbance":
        y0 = simulate(sys_a, u + w, fs)
        rotor = 5.0 + 0.25 * np.sin(2 * np.pi * t / 20.0)
        s = np.std(y0)
        d = E.periodic_disturbance(t, rotor, {1: 0.8 * s, 3: 0.5 * s}, {1: 0.3, 3: -1.0})
        y = noisy(y0) + d[:, None]
        signals = {"/rotor_speed": (t[::5], rotor[::5])} | _airspeed_distractor(t)
        truth.update(source="/rotor_speed", harmonics=[1, 3], frequency_hz=float(rotor.mean()))
    elif name == "parameter_varying":
        v = hidden_airspeed(t)

        def system_at(speed: float):
            return E.mode_blocks([(2.0, 0.0199), (float(hidden_lpv_frequency(speed)), 0.02)])

        y = noisy(simulate_scheduled(system_at, v, u + w, fs, resolution=0.2))
        ts = np.arange(0.0, t[-1] + 1e-9, 1.0 / HIDDEN_SIGNAL_RATE)
        signals = {
            "/airspeed": (ts, hidden_airspeed(ts)),
            "/rotor_speed": _slow(t, lambda s: 5.0 + 0.2 * np.sin(2 * np.pi * s / 17.0)),
        }
        truth.update(signal="/airspeed", slope_hz_per_unit=1.0 / 20.0, frequency_hz=4.0)
    elif name == "input_delay":
        d = 3
        y = noisy(simulate(sys_a, E.delay_input(u, d) + w, fs))
        truth.update(samples=d, delay_s=d / fs)
    elif name == "nonlinear_stiffness":
        k3 = 3.0e6
        duffing = E.mode_blocks([(2.0, 0.02), (4.0, 0.05)], displacement=True)
        y = noisy(E.simulate_cubic_stiffness(duffing, u + w, fs, k3))
        truth.update(channel=0, cubic=k3)
    elif name == "sensor_bias":
        y0 = simulate(sys_a, u + w, fs)
        s = np.std(y0)
        y = noisy(y0) + E.sensor_bias(t, 0.3 * s, 0.015 * s)
        truth.update(offset=0.3 * s, drift_per_s=0.015 * s)
    else:  # feedback
        # active control in turbulence: a small reference excitation, a strong unmeasured
        # disturbance, the recorded /excitation is the actuator command u = r - g y(t-1)
        gain = 3.0
        v_noise = HIDDEN_NOISE * 0.2 * white(n, 1, rng)  # about 2 % of the closed-loop output
        y, u = simulate_closed_loop(sys_a, DiscreteController.static(-gain, fs), 0.2 * u,
                                    w=5.0 * w / HIDDEN_PROCESS_NOISE, v=v_noise, delay=1)
        truth.update(lag=1, gain=gain)
    return HiddenEffectRecord(name, t, y, u, signals, truth)
