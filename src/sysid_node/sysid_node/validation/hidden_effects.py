"""Scenario data with one hidden physical effect each, on the Sec. II structure of the paper.

The structure is the 2 & 4 Hz system of Sec. II (``paper_example_systems()[0]``), sampled at
50 Hz for 60 s, driven by a white input on ``/excitation`` and measured on ``/vibration`` with 2 %
output noise. Each scenario adds one effect that the nominal 2-mode (order 4) model lacks:

==========================  ==================================================================
clean                       none (control); ``/airspeed`` varies but has no effect
missing_mode                the 6 Hz mode of the Sec. II system after its switch
periodic_disturbance        1/rev and 3/rev lines of a varying ``/rotor_speed`` (about 5 Hz)
parameter_varying           the 4 Hz mode moves 3-5 Hz with ``/airspeed`` 40-80 m/s (LPV (2))
input_delay                 the excitation reaches the structure 3 samples (60 ms) late
nonlinear_stiffness         a cubic spring -k3 y^3 acting where the input acts (Duffing)
sensor_bias                 an offset plus a drift of the sensor
feedback                    closed loop u = r - g y(t-1), small r, strong unmeasured disturbance
==========================  ==================================================================

All random draws come from ``numpy.random.default_rng(seed)``.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..core.systems import (
    ContinuousSystem,
    discretize,
    paper_example_systems,
    simulate,
)

FS = 50.0
DURATION_S = 60.0
SIGNAL_RATE = 10.0  # scheduling / rotating-speed topics [Hz]
NOISE_FRACTION = 0.02
PROCESS_NOISE = 0.1  # std of the unmeasured force relative to the unit-variance input
NOMINAL_ORDER = 4
SCENARIOS = (
    "clean",
    "missing_mode",
    "periodic_disturbance",
    "parameter_varying",
    "input_delay",
    "nonlinear_stiffness",
    "sensor_bias",
    "feedback",
)


@dataclass
class Scenario:
    """One hidden-effect record: sampled output/input plus slow signals and the truth."""

    name: str
    t: np.ndarray
    y: np.ndarray
    u: np.ndarray
    signals: dict[str, tuple[np.ndarray, np.ndarray]] = field(default_factory=dict)
    truth: dict = field(default_factory=dict)


def _noise(y: np.ndarray, rng: np.random.Generator, ref: np.ndarray | None = None) -> np.ndarray:
    std = np.std(y if ref is None else ref, axis=0, keepdims=True)
    return y + NOISE_FRACTION * std * rng.standard_normal(y.shape)


def _slow(t_fast: np.ndarray, fn) -> tuple[np.ndarray, np.ndarray]:
    ts = np.arange(0.0, t_fast[-1] + 1e-9, 1.0 / SIGNAL_RATE)
    return ts, fn(ts)


def _airspeed_distractor(t: np.ndarray) -> dict:
    return {"/airspeed": _slow(t, lambda s: 60.0 + 10.0 * np.sin(2 * np.pi * s / 45.0))}


def _mode_block_system(
    freqs_damps: list[tuple[float, float]], displacement: bool = False
) -> ContinuousSystem:
    """Mode blocks [[0, 1], [-w^2, -2 zeta w]], B = [0 1 ...]' and C = [1 1 ...] as in Sec. II
    (``displacement``: C = [1 0 1 0 ...], the modal displacements only)."""
    k = len(freqs_damps)
    a = np.zeros((2 * k, 2 * k))
    for m, (f, z) in enumerate(freqs_damps):
        w = 2 * np.pi * f
        a[2 * m, 2 * m + 1] = 1.0
        a[2 * m + 1, 2 * m] = -(w**2)
        a[2 * m + 1, 2 * m + 1] = -2 * z * w
    b = np.tile([[0.0], [1.0]], (k, 1))
    c = np.tile([1.0, 0.0 if displacement else 1.0], k)[None, :]
    return ContinuousSystem(a, b, c, np.zeros((1, 1)))


def airspeed_schedule(t: np.ndarray) -> np.ndarray:
    """Flight-test points 40, 60, 80 m/s in the first 60 % of the record, then a slow
    deceleration 80 -> 40 m/s (validation between the test points)."""
    knots_t = [0.0, 10.5, 12.5, 23.0, 25.0, 36.0, 60.0]
    knots_v = [40.0, 40.0, 60.0, 60.0, 80.0, 80.0, 40.0]
    return np.interp(t, knots_t, knots_v)


def lpv_frequency(v: np.ndarray) -> np.ndarray:
    """Frequency [Hz] of the scheduled mode: 4 Hz at 60 m/s, +-1 Hz at 80 / 40 m/s."""
    return 4.0 + 1.0 * (np.asarray(v) - 60.0) / 20.0


def make(name: str, seed: int = 0) -> Scenario:
    """Build scenario ``name`` (one of :data:`SCENARIOS`)."""
    rng = np.random.default_rng(seed)
    n = int(round(DURATION_S * FS))
    t = np.arange(n) / FS
    sys_a, sys_b = paper_example_systems()
    u = rng.standard_normal((n, 1))
    w = PROCESS_NOISE * rng.standard_normal((n, 1))  # unmeasured turbulence on the structure
    truth: dict = {"effect": name if name != "clean" else None, "fs": FS}
    signals: dict = {}
    if name == "clean":
        y = _noise(simulate(sys_a, u + w, FS), rng)
        signals = _airspeed_distractor(t)
    elif name == "missing_mode":
        y = _noise(simulate(sys_b, u + w, FS), rng)
        truth["frequency_hz"] = sys_b.modes()[2][0]
        truth["damping"] = sys_b.modes()[2][1]
    elif name == "periodic_disturbance":
        y0 = simulate(sys_a, u + w, FS)
        rotor = 5.0 + 0.25 * np.sin(2 * np.pi * t / 20.0)
        phi = 2 * np.pi * np.concatenate([[0.0], np.cumsum(0.5 * (rotor[1:] + rotor[:-1]) / FS)])
        s = np.std(y0)
        d = 0.8 * s * np.cos(phi + 0.3) + 0.5 * s * np.cos(3 * phi - 1.0)
        y = _noise(y0, rng) + d[:, None]
        signals = {"/rotor_speed": (t[::5], rotor[::5])} | _airspeed_distractor(t)
        truth.update(source="/rotor_speed", harmonics=[1, 3], frequency_hz=float(rotor.mean()))
    elif name == "parameter_varying":
        v = airspeed_schedule(t)
        y0 = _simulate_lpv(u + w, v)
        y = _noise(y0, rng)
        ts = np.arange(0.0, t[-1] + 1e-9, 1.0 / SIGNAL_RATE)
        signals = {
            "/airspeed": (ts, airspeed_schedule(ts)),
            "/rotor_speed": _slow(t, lambda s: 5.0 + 0.2 * np.sin(2 * np.pi * s / 17.0)),
        }
        truth.update(signal="/airspeed", slope_hz_per_unit=1.0 / 20.0, frequency_hz=4.0)
    elif name == "input_delay":
        d = 3
        ud = np.vstack([np.zeros((d, 1)), u[:-d]])
        y = _noise(simulate(sys_a, ud + w, FS), rng)
        truth.update(samples=d, delay_s=d / FS)
    elif name == "nonlinear_stiffness":
        k3 = 3.0e6
        y = _noise(
            _simulate_duffing(_mode_block_system([(2.0, 0.02), (4.0, 0.05)], True), u + w, k3), rng
        )
        truth.update(channel=0, cubic=k3)
    elif name == "sensor_bias":
        y0 = simulate(sys_a, u + w, FS)
        s = np.std(y0)
        y = _noise(y0, rng) + 0.3 * s + 0.015 * s * t[:, None]
        truth.update(offset=0.3 * s, drift_per_s=0.015 * s)
    elif name == "feedback":
        # active control in turbulence: a small reference excitation, a strong unmeasured
        # disturbance, the recorded /excitation is the actuator command u = r - g y(t-1)
        r = 0.2 * u
        w = 5.0 * w / PROCESS_NOISE
        y, u = _simulate_closed_loop(sys_a, r, w, gain=3.0, rng=rng)
        truth.update(lag=1, gain=3.0)
    else:
        raise ValueError(f"unknown scenario {name!r}; one of {', '.join(SCENARIOS)}")
    return Scenario(name, t, y, u, signals, truth)


def _simulate_lpv(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Linear time-varying simulation: the 4 Hz block of Sec. II follows lpv_frequency(v).

    The matrices change every sample (ZOH per sample), so this recursion is sample by sample;
    the discretisations are cached on a 0.2 m/s grid of v (0.01 Hz steps).
    """
    cache: dict[int, tuple[np.ndarray, np.ndarray]] = {}
    x = np.zeros(4)
    y = np.empty((u.shape[0], 1))
    c = np.ones(4)
    for k in range(u.shape[0]):
        key = int(round(v[k] * 5))
        if key not in cache:
            sysk = _mode_block_system([(2.0, 0.0199), (float(lpv_frequency(key / 5)), 0.02)])
            ad, bd, _, _ = discretize(sysk, FS)
            cache[key] = (ad, bd[:, 0])
        ad, bd = cache[key]
        y[k, 0] = c @ x
        x = ad @ x + bd * u[k, 0]
    return y


def _simulate_duffing(system: ContinuousSystem, u: np.ndarray, k3: float) -> np.ndarray:
    """dx/dt = A x + B (u - k3 (C x)^3), RK4 with 4 substeps per sample, u held (ZOH)."""
    a, b, c = system.A, system.B[:, 0], system.C[0]
    h = 1.0 / FS / 4
    x = np.zeros(system.order)
    y = np.empty((u.shape[0], 1))

    def f(xx: np.ndarray, uk: float) -> np.ndarray:
        return a @ xx + b * (uk - k3 * (c @ xx) ** 3)

    for k in range(u.shape[0]):
        y[k, 0] = c @ x
        uk = float(u[k, 0])
        for _ in range(4):
            k1 = f(x, uk)
            k2 = f(x + 0.5 * h * k1, uk)
            k3_ = f(x + 0.5 * h * k2, uk)
            k4 = f(x + h * k3_, uk)
            x = x + h / 6 * (k1 + 2 * k2 + 2 * k3_ + k4)
    return y


def _simulate_closed_loop(
    system: ContinuousSystem, r: np.ndarray, w: np.ndarray, gain: float, rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray]:
    """u_t = r_t - gain * y_{t-1} with y the noisy measurement; the structure is driven by
    u + w (w unmeasured). The loop runs sample by sample (u depends on the past output)."""
    ad, bd, cd, _ = discretize(system, FS)
    n = r.shape[0]
    noise_std = NOISE_FRACTION * 0.2  # about 2 % of the closed-loop output std
    v = noise_std * rng.standard_normal(n)
    x = np.zeros(system.order)
    y = np.empty((n, 1))
    u = np.empty((n, 1))
    prev = 0.0
    for k in range(n):
        y[k, 0] = float(cd[0] @ x) + v[k]
        u[k, 0] = r[k, 0] - gain * prev
        x = ad @ x + bd[:, 0] * (u[k, 0] + w[k, 0])
        prev = y[k, 0]
    return y, u
