"""Closed loop: a plant under a known discrete controller, driven by a reference.

    u_k = r_k + Cc xc_k + Dc e_k,   xc_{k+1} = Ac xc_k + Bc e_k,   e_k = y_{k-delay}
    x_{k+1} = Ad x_k + Bd (u_k + w_k),  y_k = Cd x_k + Dd (u_k + w_k) + v_k

with the controller a :class:`~sysid_node.core.controller.DiscreteController` (the package's
convention u = r + K y; negative feedback by a gain g is ``DiscreteController.static(-g, fs)``),
the plant discretised (ZOH) at the controller's rate, ``w`` an unmeasured disturbance at the
plant input and ``v`` sensor noise, so the controller feeds noise back into the recorded input
(the ``feedback`` effect; the paper's Sec. IV closed-loop experiments). ``delay`` samples
separate the measurement from the controller (0 needs a strictly proper controller, D = 0: no
algebraic loop). The loop is one linear system (the delayed outputs in its state), simulated
by the vectorised modal simulator.
"""

from __future__ import annotations

import numpy as np

from ..core.controller import DiscreteController
from ..core.lti import ContinuousSystem, discretize, simulate_discrete


def closed_loop_matrices(
    plant: ContinuousSystem, controller: DiscreteController, delay: int = 1
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Discrete (A, B, C, D) of the loop: inputs [r (m), w (m), v (l)], outputs [y (l), u (m)],
    state [x (plant), xc (controller), y_{k-1} ... y_{k-delay}]."""
    if delay < 0:
        raise ValueError(f"delay must be >= 0 samples, got {delay}")
    if delay == 0 and controller.D.any():
        raise ValueError("delay 0 needs a strictly proper controller (D = 0): algebraic loop")
    ad, bd, cd, dd = discretize(plant, controller.fs)
    n, m, l = ad.shape[0], bd.shape[1], cd.shape[0]
    ac, bc, cc, dc = controller.A, controller.B, controller.C, controller.D
    nc = controller.order
    if dc.shape != (m, l):
        raise ValueError(f"controller D must be ({m}, {l}), got {dc.shape}")
    ns = n + nc + delay * l
    ix, ic, ie = slice(0, n), slice(n, n + nc), slice(ns - l, ns)  # e = oldest delayed y
    # u = r + Cc xc + Dc e: as a row block over [state | r, w, v]
    u_state = np.zeros((m, ns))
    u_state[:, ic] = cc
    if delay:
        u_state[:, ie] = dc
    u_in = np.hstack([np.eye(m), np.zeros((m, m + l))])
    w_in = np.hstack([np.zeros((m, m)), np.eye(m), np.zeros((m, l))])
    v_in = np.hstack([np.zeros((l, 2 * m)), np.eye(l)])
    # y = Cd x + Dd (u + w) + v
    y_state = dd @ u_state
    y_state[:, ix] += cd
    y_in = dd @ (u_in + w_in) + v_in
    a = np.zeros((ns, ns))
    b = np.zeros((ns, 2 * m + l))
    a[ix] = bd @ u_state
    a[ix, ix] += ad
    b[ix] = bd @ (u_in + w_in)
    if delay:
        a[ic, ic] = ac
        a[ic, ie] += bc
        a[n + nc : n + nc + l] = y_state  # y_{k-1} <- y_k
        b[n + nc : n + nc + l] = y_in
    else:  # xc <- Ac xc + Bc y_k
        a[ic] = bc @ y_state
        a[ic, ic] += ac
        b[ic] = bc @ y_in
    for j in range(1, delay):  # shift the delay line
        row = n + nc + j * l
        a[row : row + l, row - l : row] = np.eye(l)
    return a, b, np.vstack([y_state, u_state]), np.vstack([y_in, u_in])


def simulate_closed_loop(
    plant: ContinuousSystem,
    controller: DiscreteController,
    r: np.ndarray,
    w: np.ndarray | None = None,
    v: np.ndarray | None = None,
    delay: int = 1,
) -> tuple[np.ndarray, np.ndarray]:
    """(y (N, l) measured outputs, u (N, m) recorded plant inputs) of the loop driven by the
    reference ``r`` (N, m), disturbance ``w`` (N, m) and sensor noise ``v`` (N, l) (zeros when
    None), at the controller's rate."""
    r = np.asarray(r, dtype=float).reshape(len(r), -1)
    n, m, l = r.shape[0], plant.n_inputs, plant.n_outputs
    w = np.zeros((n, m)) if w is None else np.asarray(w, dtype=float).reshape(n, m)
    v = np.zeros((n, l)) if v is None else np.asarray(v, dtype=float).reshape(n, l)
    out, _ = simulate_discrete(*closed_loop_matrices(plant, controller, delay),
                               np.hstack([r, w, v]))
    return out[:, :l], out[:, l:]


def loop_is_stable(plant: ContinuousSystem, controller: DiscreteController, delay: int = 1,
                   margin: float = 0.0) -> bool:
    """All closed-loop poles inside the circle of radius 1 - ``margin``."""
    a = closed_loop_matrices(plant, controller, delay)[0]
    return bool(np.max(np.abs(np.linalg.eigvals(a)), initial=0.0) < 1.0 - margin)
