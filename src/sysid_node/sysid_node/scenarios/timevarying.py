"""Time-varying and parameter-varying (LPV, paper eq. (2)) simulation, vectorised in blocks.

The system is held constant over runs of samples and discretised exactly (ZOH) on each run; the
state is carried from one run to the next, so no per-sample Python loop is needed:

* :func:`simulate_piecewise`: the general form, one integer key per sample; a run is a stretch of
  equal keys, ``system_for(key)`` its system (discretisation and eigen-decomposition cached per
  key);
* :func:`simulate_switching`: abrupt changes at given times (the Sec. II example);
* :func:`simulate_scheduled`: LPV, the system follows a scheduling signal (airspeed, rotor
  speed) quantised to ``resolution``;
* :func:`simulate_time_varying`: the system at the middle of each ``segment_s`` of time.

When the state dimension changes between runs, the first states keep their values, new states
(a mode that appears) start at rest and states of a smaller system are dropped.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np

from ..core.lti import ContinuousSystem, DiscreteModalForm, discretize


def _runs(keys: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Start and end (exclusive) indices of the stretches of equal keys."""
    if keys.size == 0:
        return np.zeros(0, int), np.zeros(0, int)
    starts = np.flatnonzero(np.r_[True, keys[1:] != keys[:-1]])
    return starts, np.r_[starts[1:], keys.size]


def simulate_piecewise(
    system_for: Callable[[int], ContinuousSystem],
    keys: np.ndarray,
    u: np.ndarray,
    fs: float,
    x0: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Response (N, outputs) and final state of the system ``system_for(keys[k])`` at sample k.

    ``u`` (N, inputs); ``keys`` (N,) integers. Each run of equal keys is simulated as LTI (modal
    ``lfilter``) from the state left by the previous run.
    """
    u = np.asarray(u, dtype=float)
    u = u[:, None] if u.ndim == 1 else u
    keys = np.asarray(keys)
    if keys.shape != (u.shape[0],):
        raise ValueError(f"keys must have shape ({u.shape[0]},), got {keys.shape}")
    cache: dict = {}
    outs = []
    x = None if x0 is None else np.asarray(x0, dtype=float).ravel()
    for k0, k1 in zip(*_runs(keys), strict=True):
        key = keys[k0].item()
        if key not in cache:
            cache[key] = DiscreteModalForm.of(*discretize(system_for(key), fs))
        form = cache[key]
        start = np.zeros(form.ad.shape[0])
        if x is not None:
            n_keep = min(start.size, x.size)
            start[:n_keep] = x[:n_keep]
        y, x = form.simulate(u[k0:k1], start)
        outs.append(y)
    if not outs:
        return np.zeros((0, system_for(0).n_outputs)), np.zeros(0)
    return np.vstack(outs), x


def simulate_switching(
    systems_with_switch_times: Sequence[tuple[float, ContinuousSystem]],
    u: np.ndarray,
    fs: float,
) -> np.ndarray:
    """Piecewise-LTI system, e.g. ``[(0.0, sys_a), (20.0, sys_b)]``: each system is active from
    its start time [s] (sample k has time k / fs) to the next one."""
    segs = sorted(systems_with_switch_times, key=lambda p: p[0])
    n = np.asarray(u).shape[0]
    starts = [max(0, int(np.ceil(t0 * fs - 1e-9))) for t0, _ in segs]
    keys = np.zeros(n, dtype=int)
    for i, k0 in enumerate(starts[1:], start=1):
        keys[k0:] = i
    y, _ = simulate_piecewise(lambda i: segs[i][1], keys, u, fs)
    return y


def simulate_scheduled(
    system_at: Callable[[float], ContinuousSystem],
    schedule: np.ndarray,
    u: np.ndarray,
    fs: float,
    resolution: float,
) -> np.ndarray:
    """LPV (paper eq. (2)): the system ``system_at(value)`` follows the scheduling signal
    ``schedule`` (N,), quantised to multiples of ``resolution`` (its units)."""
    per_unit = 1.0 / resolution
    keys = np.round(np.asarray(schedule, dtype=float) * per_unit).astype(np.int64)
    y, _ = simulate_piecewise(lambda k: system_at(k / per_unit), keys, u, fs)
    return y


def simulate_time_varying(
    system_at: Callable[[float], ContinuousSystem],
    u: np.ndarray,
    fs: float,
    segment_s: float,
) -> np.ndarray:
    """The system ``system_at(t)`` taken at the middle of each ``segment_s`` of time [s]."""
    n = np.asarray(u).shape[0]
    step = max(1, int(round(segment_s * fs)))
    keys = np.arange(n) // step

    def system_for(i: int) -> ContinuousSystem:
        k0, k1 = i * step, min(n, (i + 1) * step)
        return system_at(0.5 * (k0 + k1 - 1) / fs)

    y, _ = simulate_piecewise(system_for, keys, u, fs)
    return y
