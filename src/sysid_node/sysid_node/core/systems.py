"""The seed paper's systems and a vectorised LTI simulator.

Mehra & Prasanth, J. Aircraft 41(4) 2004:

* Sec. II: the abruptly changing system (1) with modes at 2 and 4 Hz for t <= 20 s and
  2, 4 and 6 Hz after (:func:`paper_example_systems`, :func:`paper_example_data`).
* Sec. IV: the cobra stick model (CSM) identified open loop at 32 Hz rotor speed, printed in
  modal form (3) with 2 inputs and 2 outputs (:func:`cobra_stick_model`).

Simulation discretises with a zero-order hold (``scipy.signal.cont2discrete``) and runs the
discrete recursion in modal coordinates with ``scipy.signal.lfilter`` (one first-order filter per
eigenvalue, no per-sample Python loop); defective matrices fall back to ``scipy.signal.dlsim``.
Every random function takes an explicit ``numpy.random.Generator``.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from scipy import signal

#: Time [s] at which the 6 Hz mode of the Sec. II example appears.
PAPER_EXAMPLE_SWITCH_TIME_S = 20.0


@dataclass(frozen=True)
class ContinuousSystem:
    """Continuous-time LTI system dx/dt = A x + B u, y = C x + D u (paper eq. (1))."""

    A: np.ndarray
    B: np.ndarray
    C: np.ndarray
    D: np.ndarray

    def __post_init__(self) -> None:
        a = np.atleast_2d(np.asarray(self.A, dtype=float))
        b = np.asarray(self.B, dtype=float).reshape(a.shape[0], -1)
        c = np.asarray(self.C, dtype=float).reshape(-1, a.shape[0])
        d = np.asarray(self.D, dtype=float).reshape(c.shape[0], b.shape[1])
        object.__setattr__(self, "A", a)
        object.__setattr__(self, "B", b)
        object.__setattr__(self, "C", c)
        object.__setattr__(self, "D", d)

    @property
    def order(self) -> int:
        return self.A.shape[0]

    @property
    def n_inputs(self) -> int:
        return self.B.shape[1]

    @property
    def n_outputs(self) -> int:
        return self.C.shape[0]

    def poles(self) -> np.ndarray:
        """Eigenvalues of A [rad/s]."""
        return np.linalg.eigvals(self.A)

    def modes(self) -> list[tuple[float, float]]:
        """True oscillatory modes ``(frequency_hz, damping_ratio)``, sorted by frequency.

        From a direct eigen-analysis of A (independent of any identification): one entry per
        complex-conjugate pole pair s, with f = |s| / 2 pi and zeta = -Re(s) / |s|.
        Real poles are left out (see :meth:`real_poles`).
        """
        s = self.poles()
        s = s[s.imag > 1e-9 * np.maximum(1.0, np.abs(s))]
        out = [(float(abs(p) / (2 * np.pi)), float(-p.real / abs(p)) + 0.0) for p in s]
        return sorted(out)

    def real_poles(self) -> np.ndarray:
        """Real eigenvalues of A [1/s]."""
        s = self.poles()
        return np.sort(s[np.abs(s.imag) <= 1e-9 * np.maximum(1.0, np.abs(s))].real)


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


def cobra_stick_model() -> ContinuousSystem:
    """The cobra stick model of Sec. IV (open loop, 32 Hz rotor speed), 2 inputs, 2 outputs.

    Modal blocks [[0, -1], [w^2, -2 zeta w]] with w^2 = 2.1e4, 4.0e4, 5.3e4 (23.06, 31.83 and
    36.64 Hz; damping 0.31 %, 0 % and 0.54 %), B, C, D as printed in the paper.
    """
    a = np.zeros((6, 6))
    for m, (w2, c) in enumerate([(2.1e4, 0.9), (4.0e4, 0.0), (5.3e4, 2.5)]):
        a[2 * m, 2 * m + 1] = -1.0
        a[2 * m + 1, 2 * m] = w2
        a[2 * m + 1, 2 * m + 1] = -c
    b = np.array([[0, 0], [-2.6, -2.9], [0, 0], [0, -0.3], [0, 0], [-2.1, -9.5]], dtype=float)
    c_out = np.array(
        [[-342.2, 4.6, 670.9, 1.3, 655.3, -1.5], [-23.3, 0.1, -57.3, -1.0, -482.7, 1.0]]
    )
    d = np.array([[-0.04, -0.04], [-0.04, 0.02]])
    return ContinuousSystem(a, b, c_out, d)


def discretize(system: ContinuousSystem, fs: float) -> tuple[np.ndarray, ...]:
    """Zero-order-hold discretisation at sample rate ``fs`` [Hz]: (Ad, Bd, Cd, Dd)."""
    ad, bd, cd, dd, _ = signal.cont2discrete(
        (system.A, system.B, system.C, system.D), 1.0 / fs, method="zoh"
    )
    return ad, bd, cd, dd


def _check_u(u: np.ndarray, m: int) -> np.ndarray:
    u = np.asarray(u, dtype=float)
    if u.ndim == 1:
        u = u[:, None]
    if u.ndim != 2 or u.shape[1] != m:
        raise ValueError(f"u must have shape (N, {m}), got {u.shape}")
    return u


def _simulate_discrete(
    ad: np.ndarray, bd: np.ndarray, cd: np.ndarray, dd: np.ndarray, u: np.ndarray, x0: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """x+ = Ad x + Bd u, y = Cd x + Dd u; returns (y (N, l), state after the last sample)."""
    n_samples = u.shape[0]
    lam, t = np.linalg.eig(ad)
    if n_samples == 0:
        return np.zeros((0, cd.shape[0])), x0.copy()
    if np.linalg.cond(t) > 1e8:  # defective / nearly defective: plain state recursion
        _, y, x = signal.dlsim((ad, bd, cd, dd, 1.0), np.vstack([u, u[-1:]]), x0=x0)
        return y[:-1], x[-1]
    tinv = np.linalg.inv(t)
    drive = (tinv @ bd) @ u.T  # (n, N), modal input
    z0 = tinv @ x0
    z = np.empty((ad.shape[0], n_samples + 1), dtype=complex)
    for k, lk in enumerate(lam):  # one first-order filter per eigenvalue (n is small)
        z[k], _ = signal.lfilter(
            [0.0, 1.0], [1.0, -lk], np.append(drive[k], 0.0), zi=np.array([z0[k]])
        )
    x = np.real(t @ z)
    y = (cd @ x[:, :-1]).T + u @ dd.T
    return y, x[:, -1]


def simulate(
    system: ContinuousSystem, u: np.ndarray, fs: float, x0: np.ndarray | None = None
) -> np.ndarray:
    """Response y (N, n_outputs) of ``system`` to input samples u (N, n_inputs) at ``fs`` [Hz].

    The input is held constant between samples (ZOH); x0 is the state at the first sample
    (zeros by default).
    """
    y, _ = simulate_with_state(system, u, fs, x0)
    return y


def simulate_with_state(
    system: ContinuousSystem, u: np.ndarray, fs: float, x0: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """As :func:`simulate`, also returning the state after the last sample."""
    u = _check_u(u, system.n_inputs)
    x0 = np.zeros(system.order) if x0 is None else np.asarray(x0, dtype=float).ravel()
    return _simulate_discrete(*discretize(system, fs), u, x0)


def simulate_switching(
    systems_with_switch_times: Sequence[tuple[float, ContinuousSystem]],
    u: np.ndarray,
    fs: float,
) -> np.ndarray:
    """Simulate a piecewise-LTI system, e.g. ``[(0.0, sys_a), (20.0, sys_b)]``.

    Each system is active from its start time [s] (sample k has time k / fs) to the next one.
    The state carries over the switch: the first states keep their values and any new states
    (a mode that appears) start at rest; states of a smaller system are dropped.
    """
    segs = sorted(systems_with_switch_times, key=lambda p: p[0])
    u = np.asarray(u, dtype=float)
    if u.ndim == 1:
        u = u[:, None]
    n_samples = u.shape[0]
    starts = [max(0, int(np.ceil(t0 * fs - 1e-9))) for t0, _ in segs]
    starts[0] = 0
    ends = starts[1:] + [n_samples]
    outs = []
    x = np.zeros(segs[0][1].order)
    for (_, sysk), k0, k1 in zip(segs, starts, ends, strict=True):
        x0 = np.zeros(sysk.order)
        n_keep = min(sysk.order, x.size)
        x0[:n_keep] = x[:n_keep]
        y, x = simulate_with_state(sysk, u[k0:k1], fs, x0)
        outs.append(y)
    return np.vstack(outs)


def add_output_noise(y: np.ndarray, fraction: float, rng: np.random.Generator) -> np.ndarray:
    """y plus white Gaussian noise whose std is ``fraction`` x each channel's std (0.05 = 5 %)."""
    y = np.asarray(y, dtype=float)
    std = np.std(y, axis=0, keepdims=True)
    return y + fraction * std * rng.standard_normal(y.shape)


def wideband_input(n: int, m: int, rng: np.random.Generator) -> np.ndarray:
    """White Gaussian input, unit variance, shape (n, m): excites all modes below Nyquist."""
    return rng.standard_normal((n, m))


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
    u = wideband_input(n, 1, rng)
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
    u = wideband_input(int(round(duration_s * fs)), 2, rng)
    y = add_output_noise(simulate(system, u, fs), noise_fraction, rng)
    return system, u, y


def simulate_discrete(
    ad: np.ndarray,
    bd: np.ndarray,
    cd: np.ndarray,
    dd: np.ndarray,
    u: np.ndarray,
    x0: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Discrete x+ = Ad x + Bd u, y = Cd x + Dd u for u (N, m); returns (y (N, l), final state)."""
    u = np.asarray(u, dtype=float).reshape(-1, bd.shape[1])
    x0 = np.zeros(ad.shape[0]) if x0 is None else np.asarray(x0, dtype=float).ravel()
    return _simulate_discrete(ad, bd, cd, dd, u, x0)
