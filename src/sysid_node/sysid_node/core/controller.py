"""A known discrete feedback controller, its LQG design and the closed-loop checks of Sec. IV,
with python-control (``control``) doing the Riccati equations, interconnections and margins.

Convention (used everywhere in the package): the actuator command is the reference (the test
excitation) plus the controller output, ``u = r + K y``; the controller is the discrete system
``x+ = A x + B y, u_c = C x + D y`` at the plant's sample rate. An LQG controller has D = 0
(strictly proper: u_k depends on y up to k - 1), which the direct closed-loop identification of
:mod:`~sysid_node.core.closed_loop` needs.

The paper designs an H-infinity controller from each identified model (step 2 of the Sec. IV
procedure). H-infinity synthesis in python-control needs slycot, which has no wheel here, so
:func:`design_lqg` designs a linear-quadratic-Gaussian controller instead: the regulator weights
the output energy of the modes in a frequency band (the modes to be stabilised; the others are
left alone, which keeps them identifiable in closed loop) and the Kalman filter assumes a large
disturbance at the plant input (loop-transfer recovery at the input, for robustness to the
mode moving between operating points). Before the loop is closed, :func:`check_closed_loop`
verifies stability, the damping of the closed-loop poles and loop-at-a-time gain and phase
margins at the plant input.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import control as ct
import numpy as np

from .inputs import InputError, as_2d
from .loop_analysis import crossings
from .lti import simulate_discrete


@dataclass(frozen=True)
class DiscreteController:
    """Discrete controller ``x+ = A x + B y, u_c = C x + D y`` at ``fs`` [Hz]; ``u = r + u_c``."""

    A: np.ndarray
    B: np.ndarray
    C: np.ndarray
    D: np.ndarray
    fs: float

    def __post_init__(self) -> None:
        d = np.atleast_2d(np.asarray(self.D, dtype=float))
        m, l = d.shape
        a = np.asarray(self.A, dtype=float)
        n = int(round(np.sqrt(a.size)))
        object.__setattr__(self, "A", a.reshape(n, n))
        object.__setattr__(self, "B", np.asarray(self.B, dtype=float).reshape(n, l))
        object.__setattr__(self, "C", np.asarray(self.C, dtype=float).reshape(m, n))
        object.__setattr__(self, "D", d)
        object.__setattr__(self, "fs", float(self.fs))

    @classmethod
    def static(cls, gain, fs: float) -> DiscreteController:
        """A memoryless controller u_c = ``gain`` y (scalar or (actuators, sensors) matrix);
        negative feedback u = r - g y is ``static(-g, fs)``."""
        d = np.atleast_2d(np.asarray(gain, dtype=float))
        return cls(np.zeros((0, 0)), np.zeros((0, d.shape[1])), np.zeros((d.shape[0], 0)), d, fs)

    @property
    def order(self) -> int:
        return self.A.shape[0]

    @property
    def n_sensors(self) -> int:
        """Number of plant outputs the controller reads."""
        return self.D.shape[1]

    @property
    def n_actuators(self) -> int:
        """Number of plant inputs it drives."""
        return self.D.shape[0]

    def to_control(self) -> ct.StateSpace:
        """The controller as a python-control discrete state-space system (dt = 1 / fs)."""
        return ct.ss(self.A, self.B, self.C, self.D, 1.0 / self.fs)

    def output(self, y: np.ndarray) -> np.ndarray:
        """Controller output u_c (N, actuators) for the measured outputs y (N, sensors)."""
        y = as_2d(y, "y", self.n_sensors)
        if self.order == 0:
            return y @ self.D.T
        uc, _ = simulate_discrete(self.A, self.B, self.C, self.D, y)
        return uc

    def reference(self, u: np.ndarray, y: np.ndarray) -> np.ndarray:
        """The reference r = u - K y reconstructed from the applied input and the output."""
        u = as_2d(u, "u", self.n_actuators)
        return u - self.output(y)

    def save(self, path: str | Path) -> None:
        """Store as .npz: arrays A, B, C, D and ``meta`` (JSON: fs, convention)."""
        meta = {"fs": self.fs, "convention": "u = r + K y; x+ = A x + B y, u_c = C x + D y"}
        with open(path, "wb") as fh:
            np.savez(fh, A=self.A, B=self.B, C=self.C, D=self.D, meta=np.array(json.dumps(meta)))

    @classmethod
    def load(cls, path: str | Path) -> DiscreteController:
        """Reload a controller written by :meth:`save`; InputError with the reason otherwise."""
        try:
            with np.load(path, allow_pickle=False) as z:
                meta = json.loads(str(z["meta"]))
                return cls(z["A"], z["B"], z["C"], z["D"], float(meta["fs"]))
        except (OSError, KeyError, ValueError) as exc:
            raise InputError(f"cannot load controller from {path}: {exc}") from None


def plant_ss(a: np.ndarray, b: np.ndarray, c: np.ndarray, d: np.ndarray,
             fs: float) -> ct.StateSpace:
    """A discrete plant as a python-control system."""
    return ct.ss(a, b, c, d, 1.0 / fs)


def closed_loop(plant: ct.StateSpace, controller: DiscreteController) -> ct.StateSpace:
    """Closed loop from the reference r to [y; u] for u = r + K y (python-control
    ``feedback`` with positive sign, then the input appended as outputs)."""
    k = controller.to_control()
    t_yr = ct.feedback(plant, k, sign=1)  # y = G (I - K G)^-1 r
    s_ur = ct.feedback(ct.ss([], [], [], np.eye(plant.ninputs), plant.dt), k * plant, sign=1)
    return ct.append(t_yr, s_ur) * ct.ss([], [], [], np.vstack([np.eye(plant.ninputs)] * 2),
                                         plant.dt)


def closed_loop_poles(plant: ct.StateSpace, controller: DiscreteController) -> np.ndarray:
    """Discrete poles of the loop formed by ``plant`` and ``controller``."""
    return ct.poles(ct.feedback(plant, controller.to_control(), sign=1))


def _damping(z: np.ndarray, fs: float) -> np.ndarray:
    s = np.log(z.astype(complex)) * fs
    return -s.real / np.maximum(np.abs(s), 1e-300)


@dataclass(frozen=True)
class LoopCheck:
    """Result of :func:`check_closed_loop` (margins at the plant input, loop at a time)."""

    stable: bool
    spectral_radius: float
    min_damping: float  # smallest damping ratio of the closed-loop poles [-]
    gain_margin_db: float  # smallest over the input channels [dB]
    phase_margin_deg: float  # smallest over the input channels [deg]
    ok: bool
    reason: str


def input_loop_margins(
    plant: ct.StateSpace, controller: DiscreteController, n_freq: int = 4000
) -> tuple[np.ndarray, np.ndarray]:
    """Loop-at-a-time gain [dB] and phase [deg] margins at each plant input, the other loops
    closed (MIMO disk margins need slycot). With H = K G and positive feedback, the return
    ratio at input i is L_i = 1 - 1 / [(I - H)^-1]_ii, from python-control's frequency response
    of (I - H)^-1 on a dense grid up to Nyquist; every crossing by
    :func:`~sysid_node.core.loop_analysis.crossings`. A lightly damped
    structure crosses unity gain near each resonance and an open-loop unstable plant makes the
    loop conditionally stable (a gain *decrease* destabilises it), so the margin is the
    smallest distance to instability over all crossings, in either direction: min |GM| [dB]
    and min |PM| [deg]."""
    k = controller.to_control()
    h = k * plant
    m = plant.ninputs
    sens = ct.feedback(ct.ss([], [], [], np.eye(m), plant.dt), h, sign=1)  # (I - H)^-1
    nyq = np.pi / plant.dt
    omega = np.geomspace(1e-3 * nyq, 0.999 * nyq, n_freq)
    fr = np.asarray(sens.frequency_response(omega).complex).reshape(m, m, -1)
    gm = np.full(m, np.inf)
    pm = np.full(m, np.inf)
    for i in range(m):
        li = 1.0 - 1.0 / fr[i, i]
        # crossings() takes a negative-feedback loop: L_neg = -L_i
        g, p, _ = crossings(omega, -li)
        if g.size:
            gm[i] = float(np.min(np.abs(g)))
        if p.size:
            pm[i] = float(np.min(np.abs(p)))
    return gm, pm


def check_closed_loop(
    plant: ct.StateSpace,
    controller: DiscreteController,
    min_damping: float = 0.0,
    min_gain_margin_db: float = 0.0,
    min_phase_margin_deg: float = 0.0,
) -> LoopCheck:
    """Is it safe to close ``controller`` around ``plant``? Stable (spectral radius < 1), every
    closed-loop pole damped at least ``min_damping``, loop-at-a-time margins at the plant input
    at least the given ones. ``reason`` says which test failed ('' when ok)."""
    poles = closed_loop_poles(plant, controller)
    rho = float(np.max(np.abs(poles))) if poles.size else 0.0
    fs = 1.0 / plant.dt
    osc = poles[np.abs(poles.imag) > 1e-9]
    zmin = float(np.min(_damping(osc, fs))) if osc.size else 1.0
    stable = rho < 1.0
    if stable:
        gm, pm = input_loop_margins(plant, controller)
        gmin, pmin = float(np.min(gm)), float(np.min(pm))
    else:
        gmin, pmin = float("nan"), float("nan")
    reason = ""
    if not stable:
        reason = f"closed loop unstable (spectral radius {rho:.5f})"
    elif zmin < min_damping:
        reason = f"closed-loop damping {100 * zmin:.2f} % below {100 * min_damping:.2f} %"
    elif gmin < min_gain_margin_db:
        reason = f"gain margin {gmin:.1f} dB below {min_gain_margin_db:g} dB"
    elif pmin < min_phase_margin_deg:
        reason = f"phase margin {pmin:.1f} deg below {min_phase_margin_deg:g} deg"
    return LoopCheck(stable, rho, zmin, gmin, pmin, reason == "", reason)


def design_lqg(
    plant: ct.StateSpace,
    band_hz: tuple[float, float] | None = None,
    control_weight: float = 0.1,
    input_noise: float = 100.0,
    output_scale: np.ndarray | None = None,
    input_scale: np.ndarray | None = None,
) -> DiscreteController:
    """LQG controller (python-control ``dlqr`` + ``dlqe``) for a discrete plant.

    Regulator: minimise sum |W_y y_band|^2 + control_weight |W_u u|^2, y_band the output part
    of the modes whose frequency lies in ``band_hz`` (all modes when None), W = diag(1/scale)
    (typically the channels' standard deviations, so the weights are free of units). Estimator:
    Kalman predictor with disturbance covariance ``input_noise`` W_u^-2 at the plant input and
    unit (scaled) sensor noise. Returns u_c = -K_c x_hat, x_hat+ = A x_hat + B u_c + L (y - C
    x_hat - D u_c) (strictly proper).
    """
    a, b, c, d = (np.asarray(x, dtype=float) for x in (plant.A, plant.B, plant.C, plant.D))
    n, m = b.shape
    l = c.shape[0]
    fs = 1.0 / plant.dt
    wy = np.diag(1.0 / np.asarray(output_scale if output_scale is not None else np.ones(l)))
    wu = np.diag(1.0 / np.asarray(input_scale if input_scale is not None else np.ones(m)))
    lam, v = np.linalg.eig(a)
    if band_hz is None:
        proj = np.eye(n)
    else:
        f = np.abs(np.log(lam.astype(complex)) * fs) / (2 * np.pi)
        sel = (f >= band_hz[0]) & (f <= band_hz[1])
        if not sel.any():
            raise InputError(f"no mode of the plant in the band {band_hz} Hz")
        proj = np.real(v[:, sel] @ np.linalg.inv(v)[sel])
    cz = wy @ c @ proj
    q = cz.T @ cz
    q = 0.5 * (q + q.T) + 1e-12 * np.trace(q) * np.eye(n)
    r = control_weight * wu.T @ wu
    kc, _, _ = ct.dlqr(a, b, q, r)
    bw = b @ np.linalg.inv(wu)
    qn = input_noise * (bw @ bw.T)
    qn = 0.5 * (qn + qn.T) + 1e-12 * max(np.trace(qn), 1e-300) * np.eye(n)
    rn = np.linalg.inv(wy.T @ wy)
    lk, _, _ = ct.dlqe(a, np.eye(n), c, qn, 0.5 * (rn + rn.T))
    ak = a - b @ kc - lk @ (c - d @ kc)
    return DiscreteController(ak, lk, -kc, np.zeros((m, l)), fs)
