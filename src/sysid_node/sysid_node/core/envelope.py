"""Sec. IV's iterative identification and controller design (envelope expansion).

1. Begin at a known stable operating point theta_0; open-loop experiment; identify (batch DSRA).
2. Design a controller from the identified model (:func:`~.controller.design_lqg`; the paper
   uses H-infinity, which needs slycot here).
3. Step toward the instability: predict the plant at theta + step from the models identified
   so far (LPV interpolation (2), extrapolated linearly from the last two points), and close the
   loop there only if the current controller passes :func:`~.controller.check_closed_loop` on
   both the predicted plant and the plant identified at theta (stable, every closed-loop pole
   damped at least ``min_damping``, loop-at-a-time gain and phase margins); otherwise halve
   the step (down to ``min_step``) or stop with the reason. Closed-loop experiment at the new
   point; open-loop plant from it (:func:`~.closed_loop.identify_closed_loop`).
4. Repeat 2-3 until ``theta_stop``. The models {(theta_k, A_k, B_k, C_k, D_k)} form the LPV
   model (2) (:class:`~.lpv.LpvModel`).

The experiment is a callable ``experiment(theta, controller | None, rng) -> ClosedLoopData``,
so the same procedure drives a simulation (``csm_rotor``) or a test rig. A controller that
fails its own check on the freshly identified model is re-designed with a 4x larger control
weight (gentler) up to 4 times; the step is never taken with a design that fails.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from .batch import identify
from .closed_loop import ClosedLoopData, ClosedLoopResult, identify_closed_loop
from .controller import DiscreteController, LoopCheck, check_closed_loop, design_lqg, plant_ss
from .lpv import LpvModel
from .lti import ContinuousSystem, discretize
from .model import IdentifiedModel


@dataclass
class EnvelopeSettings:
    """Tuning of the procedure (SI units; frequencies in Hz)."""

    theta_start: float
    theta_stop: float
    step: float
    min_step: float = 0.125
    order: int | None = None  # plant order (None: singular-value gap)
    block_rows: int = 20
    control_band_hz: tuple[float, float] | None = None
    control_weight: float = 10.0
    input_noise: float = 100.0
    min_damping: float = 0.0005  # closed-loop poles [-]
    min_gain_margin_db: float = 3.0
    min_phase_margin_deg: float = 20.0


@dataclass
class EnvelopePoint:
    """One operating point of the run."""

    theta: float
    closed_loop: bool  # the experiment ran with a controller
    designed_at: float  # theta of the model the controller in the loop was designed from
    record: ClosedLoopData
    model: IdentifiedModel  # open-loop plant identified here
    result: ClosedLoopResult | None  # closed-loop identification details (None: open loop)
    check_before: LoopCheck | None  # check of the controller on the predicted plant
    controller_out: DiscreteController | None = None  # designed from ``model``
    check_out: LoopCheck | None = None


@dataclass
class EnvelopeRun:
    """The whole run: points, the LPV model, and why it stopped."""

    settings: EnvelopeSettings
    points: list[EnvelopePoint] = field(default_factory=list)
    lpv: LpvModel | None = None
    completed: bool = False
    stop_reason: str = ""
    rejected_steps: list[tuple[float, str]] = field(default_factory=list)

    def unstable_closures(self) -> int:
        """Experiments run on an unstable closed loop (must be 0)."""
        return sum(1 for p in self.points if p.record.true_spectral_radius >= 1.0)


def _as_system(model: IdentifiedModel) -> ContinuousSystem:
    return model.to_continuous()


def _predict(points: list[EnvelopePoint], theta: float) -> ContinuousSystem:
    """Plant predicted at ``theta`` from the identified models: the LPV interpolation of the
    last two points, extrapolated linearly (the single model when there is one)."""
    if len(points) == 1:
        return _as_system(points[0].model)
    last = points[-2:]
    lpv = LpvModel.from_models([p.theta for p in last], [p.model for p in last])
    t0, t1 = lpv.points
    beta = (theta - t0) / (t1 - t0)  # extrapolation beyond t1 (beta > 1)
    return ContinuousSystem(*((1 - beta) * m[0] + beta * m[1]
                              for m in (lpv.A, lpv.B, lpv.C, lpv.D)))


def _design(model: IdentifiedModel, rec: ClosedLoopData, s: EnvelopeSettings
            ) -> tuple[DiscreteController, LoopCheck]:
    """LQG design from ``model`` with the experiment's channel standard deviations as scales;
    a design failing its own check is retried with a 4x larger control weight."""
    g = plant_ss(model.A, model.B, model.C, model.D, model.fs)
    out_scale, in_scale = np.std(rec.y, axis=0), np.std(rec.u, axis=0)
    weight = s.control_weight
    for _ in range(5):
        k = design_lqg(g, s.control_band_hz, weight, s.input_noise, out_scale, in_scale)
        chk = check_closed_loop(g, k, s.min_damping, s.min_gain_margin_db,
                                s.min_phase_margin_deg)
        if chk.ok:
            return k, chk
        weight *= 4.0
    return k, chk


def expand_envelope(
    experiment: Callable[[float, DiscreteController | None, np.random.Generator],
                         ClosedLoopData],
    settings: EnvelopeSettings,
    rng: np.random.Generator,
    log: Callable[[str], None] | None = None,
) -> EnvelopeRun:
    """Run the Sec. IV procedure (module docstring); ``log`` receives one line per event."""
    s = settings
    say = log or (lambda _msg: None)
    run = EnvelopeRun(s)
    direction = 1.0 if s.theta_stop >= s.theta_start else -1.0
    rec = experiment(s.theta_start, None, rng)
    model = identify(rec.y, rec.u, fs=rec.fs, order=s.order, block_rows=s.block_rows,
                     damping_bounds=(-0.5, 0.5))
    point = EnvelopePoint(s.theta_start, False, float("nan"), rec, model, None, None)
    point.controller_out, point.check_out = _design(model, rec, s)
    run.points.append(point)
    say(f"theta {s.theta_start:g}: open loop, {len(model.modes)} modes; controller "
        f"{'ok' if point.check_out.ok else 'FAILS: ' + point.check_out.reason}")
    theta = s.theta_start
    while direction * (s.theta_stop - theta) > 1e-9:
        cur = run.points[-1]
        if cur.check_out is None or not cur.check_out.ok:
            run.stop_reason = (f"no acceptable controller at {cur.theta:g}: "
                               f"{cur.check_out.reason if cur.check_out else 'none'}")
            break
        step = s.step
        while True:
            nxt = theta + direction * min(step, abs(s.theta_stop - theta))
            pred = _predict(run.points, nxt)
            g_pred = plant_ss(*discretize(pred, cur.model.fs), cur.model.fs)
            chk = check_closed_loop(g_pred, cur.controller_out, s.min_damping,
                                    s.min_gain_margin_db, s.min_phase_margin_deg)
            if chk.ok:
                break
            run.rejected_steps.append((nxt, chk.reason))
            say(f"step to {nxt:g} rejected: {chk.reason}")
            step /= 2.0
            if step < s.min_step - 1e-12:
                break
        if not chk.ok:
            run.stop_reason = f"no safe step from {theta:g} (down to {s.min_step:g}): {chk.reason}"
            break
        rec = experiment(nxt, cur.controller_out, rng)
        res = identify_closed_loop(rec.y, rec.u, rec.r, cur.controller_out, fs=rec.fs,
                                   order=cur.model.order, block_rows=s.block_rows)
        point = EnvelopePoint(nxt, True, cur.theta, rec, res.plant, res, chk)
        point.controller_out, point.check_out = _design(res.plant, rec, s)
        run.points.append(point)
        say(f"theta {nxt:g}: closed loop (controller from {cur.theta:g}, predicted margins "
            f"{chk.gain_margin_db:.1f} dB / {chk.phase_margin_deg:.1f} deg), "
            f"{len(res.plant.modes)} modes; new controller "
            f"{'ok' if point.check_out.ok else 'FAILS: ' + point.check_out.reason}")
        theta = nxt
    else:
        run.completed = True
    models = [p.model for p in run.points]
    if len(models) >= 1:
        try:
            run.lpv = LpvModel.from_models([p.theta for p in run.points], models)
        except ValueError as err:  # InputError: local models with different numbers of modes
            run.stop_reason = (run.stop_reason + "; " if run.stop_reason else "") + str(err)
    return run
