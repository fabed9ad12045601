"""The cobra stick model (CSM) of Sec. IV with an instability, and its closed-loop experiment.

The paper identifies the CSM open loop at 32 Hz rotor speed (modes 23, 32 and 36.8 Hz, printed
in modal form (3)); its second mode "varies with rotor speed", the model "is unstable at
approximately 36 Hz" and open-loop tests are not feasible between 34 and 37 Hz. (The Table-2
structure :func:`~sysid_node.scenarios.paper.cobra_stick_at` moves the mode but is stable
everywhere.) :func:`csm_at` keeps the printed model and makes that mode move: its stiffness is
(2 pi theta)^2 for rotor speed theta [Hz], and it is coupled to the 36.6 Hz mode by a
circulatory (non-symmetric) stiffness ``coupling`` [1/s^2], the mechanism of ground resonance
and flutter: where the two frequencies come close they coalesce and one loses its damping. With
the default coupling the open loop is unstable for rotor speeds of about 35.7 to 37.4 Hz
(damping down to -0.8 %).

:func:`closed_loop_experiment` is the Sec. IV experiment: white test input (reference) r,
unmeasured white disturbance at the plant input (rotor and aerodynamic loads), sensor noise,
and a known controller (:class:`~sysid_node.core.controller.DiscreteController`,
u = r + K y), simulated by :func:`~sysid_node.scenarios.closedloop.simulate_closed_loop`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..core.closed_loop import ClosedLoopData
from ..core.controller import DiscreteController
from ..core.lti import ContinuousSystem
from .closedloop import closed_loop_matrices, simulate_closed_loop
from .paper import cobra_stick_model
from .timevarying import simulate_scheduled

#: Circulatory stiffness coupling the moving mode and the 36.6 Hz mode [1/s^2].
CSM_COUPLING = 1200.0
#: Damping ratio of the moving mode (the paper: "neutrally stable ... in fact lightly damped").
CSM_MOVING_DAMPING = 0.0015
#: Sample rate of the CSM experiments [Hz] (about 7 samples per period of the 38 Hz mode).
CSM_FS = 256.0
#: The paper's rotor-speed range [Hz].
CSM_RANGE = (32.0, 38.0)


def csm_at(rotor_speed_hz: float, coupling: float = CSM_COUPLING,
           moving_damping: float = CSM_MOVING_DAMPING) -> ContinuousSystem:
    """Cobra stick model at rotor speed ``rotor_speed_hz``: 2 inputs, 2 outputs, 6 states.

    States as printed in the paper (blocks [[0, -1], [w^2, -2 zeta w]]); the second block's
    w = 2 pi theta, plus the circulatory terms +coupling (block 2 <- block 3 displacement)
    and -coupling (block 3 <- block 2)."""
    base = cobra_stick_model()
    a = base.A.copy()
    w2 = (2 * np.pi * float(rotor_speed_hz)) ** 2
    a[3, 2] = w2
    a[3, 3] = -2 * moving_damping * np.sqrt(w2)
    a[3, 4] = coupling
    a[5, 2] = -coupling
    return ContinuousSystem(a, base.B, base.C, base.D)


def closed_loop_experiment(
    plant: ContinuousSystem,
    controller: DiscreteController | None,
    duration_s: float,
    rng: np.random.Generator,
    fs: float = CSM_FS,
    reference_std: float = 1.0,
    disturbance_std: float = 0.2,
    noise_fraction: float = 0.05,
) -> ClosedLoopData:
    """Sec. IV experiment on ``plant`` (ZOH at ``fs``): white reference and input disturbance
    (std relative to the reference), sensor noise ``noise_fraction`` of each noise-free
    output's std; ``controller=None`` is the open-loop experiment. Returns r, u, y and the
    true closed loop's spectral radius."""
    m, l = plant.n_inputs, plant.n_outputs
    k = DiscreteController.static(np.zeros((m, l)), fs) if controller is None else controller
    if k.fs != fs:
        raise ValueError(f"the controller runs at {k.fs} Hz, the experiment at {fs} Hz")
    n = int(round(duration_s * fs))
    r = reference_std * rng.standard_normal((n, m))
    w = disturbance_std * reference_std * rng.standard_normal((n, m))
    clean, _ = simulate_closed_loop(plant, k, r, w=w, delay=0)
    v = noise_fraction * np.std(clean, axis=0) * rng.standard_normal((n, l))
    y, u = simulate_closed_loop(plant, k, r, w=w, v=v, delay=0)
    a = closed_loop_matrices(plant, k, delay=0)[0]
    return ClosedLoopData(r, u, y, fs, float(np.max(np.abs(np.linalg.eigvals(a)))))


@dataclass
class StarvedRun:
    """Open-loop CSM record whose excitation stops while the rotor speed moves (the online-LPV
    case): ``t`` [s], ``u`` (N, 2) excitation (zero once starved), ``y`` (N, 2) outputs,
    ``schedule_t`` / ``rotor_speed`` (10 Hz samples, sensor noise), ``theta`` (N,) true rotor
    speed, ``starve_time_s``."""

    fs: float
    t: np.ndarray
    u: np.ndarray
    y: np.ndarray
    schedule_t: np.ndarray
    rotor_speed: np.ndarray
    theta: np.ndarray
    starve_time_s: float

    def moving_mode_hz(self, t: np.ndarray | float) -> np.ndarray:
        """True frequency of the moving mode (the one nearest the rotor speed) at ``t``."""
        th = np.interp(t, self.t, self.theta)
        return np.array([min((f for f, _ in csm_at(x).modes()), key=lambda f, x=x: abs(f - x))
                         for x in np.atleast_1d(th)])


def starved_run(rng: np.random.Generator, fs: float = CSM_FS, excited_s: float = 20.0,
                starved_s: float = 10.0, speeds: tuple[float, float] = (33.0, 35.0),
                ambient: float = 0.01, noise_fraction: float = 0.05,
                speed_noise_hz: float = 0.01) -> StarvedRun:
    """Rotor speed ``speeds[0]`` while the white test input runs for ``excited_s``, then the
    input stops and the speed ramps linearly to ``speeds[1]`` over ``starved_s``; an unmeasured
    ambient input of ``ambient`` times the test level throughout; sensor noise relative to the
    excited output. Simulated as LPV (2) on a 0.01 Hz grid of rotor speed."""
    n_exc, n = int(round(excited_s * fs)), int(round((excited_s + starved_s) * fs))
    t = np.arange(n) / fs
    theta = np.interp(t, [0.0, excited_s, excited_s + starved_s], [speeds[0], speeds[0],
                                                                     speeds[1]])
    u = np.zeros((n, 2))
    u[:n_exc] = rng.standard_normal((n_exc, 2))
    drive = u + ambient * rng.standard_normal((n, 2))
    clean = simulate_scheduled(csm_at, theta, drive, fs, 0.01)
    y = clean + noise_fraction * np.std(clean[:n_exc], axis=0) * rng.standard_normal(clean.shape)
    ts = np.arange(0.0, t[-1], 0.1)
    rs = np.interp(ts, t, theta) + speed_noise_hz * rng.standard_normal(ts.size)
    return StarvedRun(fs, t, u, y, ts, rs, theta, excited_s)
