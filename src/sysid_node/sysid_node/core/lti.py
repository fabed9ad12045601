"""Continuous LTI systems and a vectorised simulator (used by the identified model's
prediction and simulation, and by the scenario generators in ``sysid_node.scenarios``).

Simulation discretises with a zero-order hold (``scipy.signal.cont2discrete``) and runs the
discrete recursion in modal coordinates with ``scipy.signal.lfilter`` (one first-order filter per
eigenvalue, no per-sample Python loop); defective matrices fall back to ``scipy.signal.dlsim``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import signal


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


@dataclass(frozen=True)
class DiscreteModalForm:
    """x+ = Ad x + Bd u, y = Cd x + Dd u in eigen-coordinates z = T^-1 x (``None`` eigenvectors:
    defective or nearly so, simulate with the plain recursion). Build once, simulate many
    stretches (e.g. the runs of a piecewise-constant system)."""

    ad: np.ndarray
    bd: np.ndarray
    cd: np.ndarray
    dd: np.ndarray
    eigenvalues: np.ndarray
    t: np.ndarray | None
    tinv: np.ndarray | None

    @classmethod
    def of(cls, ad, bd, cd, dd) -> DiscreteModalForm:
        lam, t = np.linalg.eig(ad)
        if t.size and np.linalg.cond(t) > 1e8:  # defective / nearly defective
            return cls(ad, bd, cd, dd, lam, None, None)
        return cls(ad, bd, cd, dd, lam, t, np.linalg.inv(t))

    def simulate(self, u: np.ndarray, x0: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(y (N, l), state after the last sample) for u (N, m) from state x0."""
        n_samples = u.shape[0]
        if n_samples == 0:
            return np.zeros((0, self.cd.shape[0])), x0.copy()
        if self.t is None:
            _, y, x = signal.dlsim((self.ad, self.bd, self.cd, self.dd, 1.0),
                                   np.vstack([u, u[-1:]]), x0=x0)
            return y[:-1], x[-1]
        drive = (self.tinv @ self.bd) @ u.T  # (n, N), modal input
        z0 = self.tinv @ x0
        z = np.empty((self.ad.shape[0], n_samples + 1), dtype=complex)
        for k, lk in enumerate(self.eigenvalues):  # one first-order filter per eigenvalue
            z[k], _ = signal.lfilter(
                [0.0, 1.0], [1.0, -lk], np.append(drive[k], 0.0), zi=np.array([z0[k]])
            )
        x = np.real(self.t @ z)
        y = (self.cd @ x[:, :-1]).T + u @ self.dd.T
        return y, x[:, -1]


def _simulate_discrete(
    ad: np.ndarray, bd: np.ndarray, cd: np.ndarray, dd: np.ndarray, u: np.ndarray, x0: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """x+ = Ad x + Bd u, y = Cd x + Dd u; returns (y (N, l), state after the last sample)."""
    return DiscreteModalForm.of(ad, bd, cd, dd).simulate(u, x0)


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
