"""The seven physical effects a nominal linear model can miss (the vocabulary of ``validate``),
as parameterised building blocks. Each acts on a structure (a ``ContinuousSystem``), its input
or its output:

==========================  ==================================================================
missing_mode                :func:`add_mode`: one more mode block than the nominal model has
periodic_disturbance        :func:`periodic_disturbance`: harmonics of a varying rotating speed
parameter_varying           ``timevarying.simulate_scheduled``: a mode follows a scheduling
                            signal (LPV, paper eq. (2)); :func:`linear_schedule` maps it
input_delay                 :func:`delay_input`: the excitation reaches the structure late
nonlinear_stiffness         :func:`simulate_cubic_stiffness`: a cubic spring (Duffing)
sensor_bias                 :func:`sensor_bias`: an offset plus a drift of the sensor
feedback                    ``closedloop.simulate_closed_loop``: u = r - K y(t - delay)
==========================  ==================================================================

``hidden_effect`` in :mod:`.bags` builds the committed ``bags/hidden`` records from these;
``draw.draw_hidden_effect`` draws their parameters at random.
"""

from __future__ import annotations

import numpy as np

from ..core.lti import ContinuousSystem
from ..validation.augment import EFFECTS  # the vocabulary of validate

__all__ = ["EFFECTS", "add_mode", "delay_input", "linear_schedule", "mode_blocks",
           "periodic_disturbance", "rotation_phase", "sensor_bias", "simulate_cubic_stiffness"]


def mode_blocks(
    modes: list[tuple[float, float]], displacement: bool = False, n_inputs: int = 1
) -> ContinuousSystem:
    """Mode blocks [[0, 1], [-w^2, -2 zeta w]] per ``(frequency_hz, damping_ratio)``, B = [0 1 ...]'
    on every input and C = [1 1 ...] as in the Sec. II example (``displacement``:
    C = [1 0 1 0 ...], the modal displacements only); one output."""
    k = len(modes)
    a = np.zeros((2 * k, 2 * k))
    for m, (f, z) in enumerate(modes):
        w = 2 * np.pi * f
        a[2 * m, 2 * m + 1] = 1.0
        a[2 * m + 1, 2 * m] = -(w**2)
        a[2 * m + 1, 2 * m + 1] = -2 * z * w
    b = np.tile([[0.0], [1.0]], (k, n_inputs))
    c = np.tile([1.0, 0.0 if displacement else 1.0], k)[None, :]
    return ContinuousSystem(a, b, c, np.zeros((1, n_inputs)))


def add_mode(
    system: ContinuousSystem, frequency_hz: float, damping_ratio: float,
    input_gains=1.0, output_gains=(1.0, 1.0),
) -> ContinuousSystem:
    """``system`` plus a mode block [[0, 1], [-w^2, -2 zeta w]] (missing_mode), driven by the
    inputs through ``input_gains`` (scalar or per input) and seen by each output through
    ``output_gains`` (2 values: on its displacement and its rate; or (outputs, 2))."""
    w = 2 * np.pi * frequency_hz
    n, m, l = system.order, system.n_inputs, system.n_outputs
    a = np.zeros((n + 2, n + 2))
    a[:n, :n] = system.A
    a[n, n + 1] = 1.0
    a[n + 1, n] = -(w**2)
    a[n + 1, n + 1] = -2 * damping_ratio * w
    b = np.vstack([system.B, np.zeros((1, m)), np.broadcast_to(input_gains, (1, m))])
    c = np.hstack([system.C, np.broadcast_to(np.asarray(output_gains, dtype=float), (l, 2))])
    return ContinuousSystem(a, b, c, system.D)


def rotation_phase(t: np.ndarray, speed_hz: np.ndarray) -> np.ndarray:
    """Phase [rad] of a rotation at ``speed_hz`` [rev/s] sampled at times ``t`` (trapezoid)."""
    t = np.asarray(t, dtype=float)
    speed_hz = np.broadcast_to(np.asarray(speed_hz, dtype=float), t.shape)
    steps = 0.5 * (speed_hz[1:] + speed_hz[:-1]) * np.diff(t)
    return 2 * np.pi * np.concatenate([[0.0], np.cumsum(steps)])


def periodic_disturbance(
    t: np.ndarray, speed_hz, amplitudes: dict[int, float], phases: dict[int, float] | None = None
) -> np.ndarray:
    """sum_h a_h cos(h phi(t) + p_h): harmonics ``h`` (1 = 1/rev) of a rotation at ``speed_hz``
    (scalar or per sample), (N,). Add it to the outputs."""
    phi = rotation_phase(t, speed_hz)
    phases = phases or {}
    return sum(a * np.cos(h * phi + phases.get(h, 0.0)) for h, a in amplitudes.items())


def linear_schedule(nominal_hz: float, slope_hz_per_unit: float, reference: float):
    """f(v) = nominal + slope (v - reference): a mode frequency as a function of the scheduling
    value v (airspeed, rotor speed)."""
    def frequency(v):
        return nominal_hz + slope_hz_per_unit * (np.asarray(v) - reference)
    return frequency


def delay_input(u: np.ndarray, samples: int) -> np.ndarray:
    """u delayed by ``samples`` (zeros first): what reaches the structure (input_delay)."""
    u = np.asarray(u, dtype=float)
    if samples <= 0:
        return u.copy()
    return np.vstack([np.zeros((samples, *u.shape[1:])), u[:-samples]])


def sensor_bias(t: np.ndarray, offset, drift_per_s) -> np.ndarray:
    """offset + drift t, (N, outputs) (scalars or per output): add it to the outputs."""
    t = np.asarray(t, dtype=float)[:, None]
    return np.atleast_1d(offset)[None, :] + np.atleast_1d(drift_per_s)[None, :] * t


def simulate_cubic_stiffness(
    system: ContinuousSystem, u: np.ndarray, fs: float, cubic: float,
    spring: np.ndarray | None = None, substeps: int = 4,
) -> np.ndarray:
    """dx/dt = A x + B (u - e_0 k3 (s x)^3), y = C x + D (u - e_0 k3 (s x)^3): a cubic spring of
    stiffness ``cubic`` (k3 > 0 hardening) on the deflection s x (``spring``, default the first
    output's row of C), acting where the first input acts (Duffing). u held over each sample,
    classical Runge-Kutta with ``substeps`` steps per sample (keep h w_max below about 0.5,
    the hardening spring raises w with the amplitude).

    Nonlinear, hence a per-sample recursion (n states, small): the one simulation here that is not
    vectorised; about 0.05 s per 1000 samples and substep.
    """
    a, b, c, d = system.A, system.B, system.C, system.D
    s = c[0] if spring is None else np.asarray(spring, dtype=float).ravel()
    u = np.asarray(u, dtype=float).reshape(len(u), system.n_inputs)
    b0 = b[:, 0]
    rest = u[:, 1:] @ b[:, 1:].T  # (N, n): the other inputs (zeros for one input)
    h = 1.0 / fs / substeps
    x = np.zeros(system.order)
    force = np.empty(u.shape[0])
    xs = np.empty((u.shape[0], system.order))

    def f(xx: np.ndarray, uk: float, other: np.ndarray) -> np.ndarray:
        return a @ xx + b0 * (uk - cubic * (s @ xx) ** 3) + other

    for k in range(u.shape[0]):
        xs[k] = x
        force[k] = cubic * (s @ x) ** 3
        uk, other = float(u[k, 0]), rest[k]
        for _ in range(substeps):
            k1 = f(x, uk, other)
            k2 = f(x + 0.5 * h * k1, uk, other)
            k3_ = f(x + 0.5 * h * k2, uk, other)
            k4 = f(x + h * k3_, uk, other)
            x = x + h / 6 * (k1 + 2 * k2 + 2 * k3_ + k4)
    ueff = u.copy()
    ueff[:, 0] -= force
    return xs @ c.T + ueff @ d.T

