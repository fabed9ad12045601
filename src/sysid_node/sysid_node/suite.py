"""Randomized identification suite (issue #10): the pipeline with DEFAULT parameters on drawn
modal records (``scenarios.draw_modal_scenario``), scored against the truth.

Only what describes the data is set: ``output_only`` for records without a measured input. Per
draw (``DrawResult``):

* ``found_by_3s`` / ``found_1pct_by_3s``: every true mode has a ``tracked`` mode within 2 % / 1 %
  of its frequency in the estimate made after 3 s of data following the first estimate that
  had a model (the start-up of the identification itself is counted: the first estimate comes
  when the estimator has its first realization);
* ``time_all_s``: data time of the first estimate with every true mode tracked within 2 %;
* ``false_mean`` / ``false_max``: ``tracked`` modes farther than 2 % from every true mode, per
  estimate from that first estimate on (a true mode that is still settling within 2-5 % is not
  counted as false);
* ``settled_share``: estimates with every true mode within 2 %, over the last quarter of the
  record before the change (or of the whole record without one);
* with a change (mode appearing or jumping): ``pickup_s`` the time from the change to the
  first estimate with the new frequency tracked within 2 % (NaN if never), and
  ``after_share`` the estimates with every true mode within 2 % from the change + ``AFTER_S``
  to the end; ``kept_share`` the estimates from the change itself to the end in which every
  mode that did not change is tracked within 2 % (issue #10's "no collapse on change": the
  modes already there must not dissolve while the new one is being found).

``ceiling_3s`` (output-only draws; NaN with a measured input): :func:`ambient_ceiling` at the
data time ``found_by_3s`` is judged at: the chance that an efficient estimator has every mode
within 2 % there, from the asymptotic bound. ``realistic_3s``: :func:`ambient_realistic`, the
same with the wider scatter an efficient fit of a record a few decay times long has (calibrated
on simulated single-mode records). Both are upper bounds of what ``found_by_3s`` can reach on
the output-only draws: close, weak and colour-driven modes lower it further.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from sysid_node.pipeline import Pipeline
from sysid_node.records import EstimateRecord
from sysid_node.scenarios import draw_modal_scenario

T0_NS = 1_700_000_000 * 10**9
#: Relative frequency tolerance of a "right" mode.
RIGHT_TOL = 0.02
#: A tracked mode within this of a true mode is settling, not false.
FALSE_TOL = 0.05
#: Data after the first estimate at which the modes are scored [s].
BY_S = 3.0
#: Settling allowed after a change before the share of right estimates is counted [s].
AFTER_S = 5.0
#: Duration of each drawn record [s] (the change, if any, at 40-60 %).
DURATION_S = 30.0
#: Samples per pushed message (a 100-1000 Hz sensor at 20-200 messages per second).
BLOCK = 5


@dataclass
class DrawResult:
    seed: int
    fs: float
    n_modes: int
    n_outputs: int
    output_only: bool
    change: str
    found_by_3s: bool
    found_1pct_by_3s: bool
    time_all_s: float
    false_mean: float
    false_max: int
    settled_share: float
    pickup_s: float
    after_share: float
    estimates: int
    kept_share: float = math.nan
    ceiling_3s: float = math.nan
    realistic_3s: float = math.nan


def ambient_ceiling(modes: list[tuple[float, float]], data_s: float, tol: float = RIGHT_TOL
                    ) -> float:
    """Chance that an efficient estimator has every mode of ``modes`` ((frequency [Hz], damping
    ratio) pairs) within ``tol`` from ``data_s`` seconds of ambient (white-noise-driven,
    output-only) response. Per mode the asymptotic relative standard deviation of the frequency
    estimate is ``sqrt(zeta / (2 pi f T))`` (an AR(2) process's, about the Cramer-Rao bound), the
    errors Gaussian and independent. Optimistic: measurement noise, close modes and records
    shorter than a few decay times (``zeta 2 pi f T`` < 1: least squares then scatters 20-50 %
    wider) only lower it."""
    p = 1.0
    for f, zeta in modes:
        sigma = math.sqrt(zeta / (2.0 * math.pi * f * data_s))
        p *= math.erf(tol / (sigma * math.sqrt(2.0)))
    return p


#: Widening of an efficient fit's frequency scatter over :func:`ambient_ceiling`'s sd on a
#: record of x = zeta 2 pi f T decay times: sd x sqrt(WIDENING_INF**2 + WIDENING_SHORT / x).
#: Least squares fit to the shares within 1, 2 and 3 sd of prediction-error fits (true-order
#: innovation model, started from the true Kalman predictor) of simulated single-mode ambient
#: records: T = 4 s, fs = 5 f, 5 % output noise, the three sensor kinds in turn, zeta 0.2-5 %,
#: x 0.25-30, 150 records at each of 24 points (rms error of the shares 0.04; the bound alone
#: is 0.09-0.23 too high at x <= 1). Not fitted on the suite's draws. WIDENING_INF: the
#: innovation model's free numerator and the noise cost even a long record about 17 %.
WIDENING_INF = 1.17
WIDENING_SHORT = 0.38


def ambient_realistic(modes: list[tuple[float, float]], data_s: float, tol: float = RIGHT_TOL
                      ) -> float:
    """:func:`ambient_ceiling` with each mode's sd widened as an efficient fit of a short
    ambient record scatters (``WIDENING_INF``, ``WIDENING_SHORT``): the chance that every mode
    of ``modes`` is within ``tol`` from ``data_s`` seconds of data. Still optimistic for close
    modes, modes weak on every output and colour-driven modes (single-mode calibration)."""
    p = 1.0
    for f, zeta in modes:
        x = zeta * 2.0 * math.pi * f * data_s
        sigma = math.sqrt(zeta / (2.0 * math.pi * f * data_s)) * math.sqrt(
            WIDENING_INF**2 + WIDENING_SHORT / x)
        p *= math.erf(tol / (sigma * math.sqrt(2.0)))
    return p


def run_pipeline(scn, params: dict | None = None, log=None) -> list[EstimateRecord]:
    """Feed a drawn record to a Pipeline (defaults unless ``params``; ``log`` its log callback)
    message by message."""
    values = {"output_only": scn.output_only, **(params or {})}
    pl = Pipeline(values, log)
    stamps = scn.stamps_ns(T0_NS)
    recs: list[EstimateRecord] = []
    n = len(stamps)
    step = BLOCK * 20  # a step every 20 messages (as a loaded node would)
    for a in range(0, n, step):
        for b in range(a, min(a + step, n), BLOCK):
            sl = slice(b, min(b + BLOCK, n))
            pl.push_output(stamps[sl], scn.y[sl])
            if scn.u is not None:
                pl.push_input(stamps[sl], scn.u[sl])
        recs += pl.step()
    return recs + pl.step(flush=True)


def run_output_only(y: np.ndarray, fs: float, params: dict | None = None, block: int = 50,
                    log=None) -> tuple[Pipeline, list[EstimateRecord]]:
    """Feed an output-only record ``y`` (n, l) sampled at ``fs`` [Hz], stamped from ``T0_NS``,
    to a Pipeline (defaults unless ``params``; ``log`` its log callback) in messages of
    ``block`` samples, a step after each; returns the pipeline and its records."""
    pl = Pipeline({"output_only": True, **(params or {})}, log)
    stamps = T0_NS + np.round(np.arange(len(y)) / fs * 1e9).astype(np.int64)
    recs: list[EstimateRecord] = []
    for a in range(0, len(y), block):
        pl.push_output(stamps[a : a + block], y[a : a + block])
        recs += pl.step()
    return pl, recs + pl.step(flush=True)


def _tracked(r: EstimateRecord) -> np.ndarray:
    return np.array([m.frequency_hz for m in r.modes if m.status == "tracked"])


def _all_right(found: np.ndarray, truth: list[float], tol: float = RIGHT_TOL) -> bool:
    return all(found.size and np.min(np.abs(found / f - 1)) <= tol for f in truth)


def score(scn, recs: list[EstimateRecord], seed: int = -1) -> DrawResult:
    """Score the estimates of one drawn record (see the module docstring)."""
    t = np.array([(r.stamp_ns - T0_NS) * 1e-9 for r in recs])
    has_model = np.array([r.model_order > 0 for r in recs])
    start = t[np.argmax(has_model)] if has_model.any() else math.inf
    ch = scn.change or {}
    t_change = float(ch.get("time_s", math.inf))
    duration = float(scn.t[-1])
    right, false_counts = [], []
    for r, tk in zip(recs, t, strict=True):
        truth = [f for f, _ in scn.modes_at(tk)]
        found = _tracked(r)
        right.append(_all_right(found, truth))
        if tk >= start:
            far = [x for x in found if not truth or min(abs(x / f - 1) for f in truth) > FALSE_TOL]
            false_counts.append(len(far))
    right = np.array(right, bool)

    def at(time_s: float, tol: float) -> bool:
        k = int(np.searchsorted(t, time_s))
        if k >= len(recs) or not np.isfinite(time_s):
            return False
        truth = [f for f, _ in scn.modes_at(t[k])]
        return _all_right(_tracked(recs[k]), truth, tol)

    first_right = np.flatnonzero(right & (t >= start))
    end_ref = min(t_change, duration)
    last_q = (t >= end_ref - 0.25 * min(end_ref, duration)) & (t < end_ref)
    pickup, after, kept = math.nan, math.nan, math.nan
    if ch:
        new_f = float(ch.get("to_hz", math.nan))
        if not np.isfinite(new_f):  # appear: the mode that exists after the change only
            before = {round(f, 9) for f, _ in scn.modes_at(t_change - 1e-3)}
            new = [f for f, _ in scn.modes_at(t_change + 1e-3) if round(f, 9) not in before]
            new_f = new[0] if new else math.nan
        hit = [tk for r, tk in zip(recs, t, strict=True) if tk >= t_change and np.isfinite(new_f)
               and _all_right(_tracked(r), [new_f])]
        pickup = hit[0] - t_change if hit else math.nan
        sel = t >= t_change + AFTER_S
        after = float(right[sel].mean()) if sel.any() else math.nan
        after_modes = {round(f, 9) for f, _ in scn.modes_at(t_change + 1e-3)}
        unchanged = [f for f, _ in scn.modes_at(t_change - 1e-3) if round(f, 9) in after_modes]
        since = t >= t_change
        if since.any() and unchanged:
            kept = float(np.mean([_all_right(_tracked(r), unchanged)
                                  for r, s in zip(recs, since, strict=True) if s]))
    return DrawResult(
        seed=seed,
        fs=float(scn.fs),
        n_modes=len(scn.structure.frequencies_hz),
        n_outputs=int(scn.y.shape[1]),
        output_only=bool(scn.output_only),
        change=str(ch.get("kind", "none")),
        found_by_3s=at(start + BY_S, RIGHT_TOL),
        found_1pct_by_3s=at(start + BY_S, 0.01),
        time_all_s=float(t[first_right[0]]) if first_right.size else math.nan,
        false_mean=float(np.mean(false_counts)) if false_counts else math.nan,
        false_max=int(max(false_counts)) if false_counts else 0,
        settled_share=float(right[last_q].mean()) if last_q.any() else math.nan,
        pickup_s=pickup,
        after_share=after,
        estimates=len(recs),
        kept_share=kept,
        ceiling_3s=ambient_ceiling(scn.modes_at(start + BY_S), start + BY_S)
        if scn.output_only and np.isfinite(start) else math.nan,
        realistic_3s=ambient_realistic(scn.modes_at(start + BY_S), start + BY_S)
        if scn.output_only and np.isfinite(start) else math.nan,
    )


def run_draw(seed: int, duration_s: float = DURATION_S, **draw) -> DrawResult:
    """Draw scenario ``seed`` (``numpy.random.default_rng(seed)``), run the defaults, score."""
    scn = draw_modal_scenario(np.random.default_rng(seed), duration_s=duration_s, **draw)
    return score(scn, run_pipeline(scn), seed)


def summary(results: list[DrawResult]) -> dict[str, float]:
    """Aggregate rates of the suite (the acceptance figures of issue #10)."""
    def mean(xs):
        xs = [x for x in xs if np.isfinite(x)]
        return float(np.mean(xs)) if xs else math.nan

    changed = [r for r in results if r.change != "none"]
    return {
        "draws": len(results),
        "found_2pct_by_3s": mean([float(r.found_by_3s) for r in results]),
        "found_1pct_by_3s": mean([float(r.found_1pct_by_3s) for r in results]),
        "settled_share": mean([r.settled_share for r in results]),
        "false_per_estimate_mean": mean([r.false_mean for r in results]),
        "false_per_estimate_max": float(max((r.false_max for r in results), default=0)),
        "changes": len(changed),
        "pickup_rate": mean([float(np.isfinite(r.pickup_s)) for r in changed]),
        "pickup_median_s": float(np.nanmedian([r.pickup_s for r in changed]))
        if any(np.isfinite(r.pickup_s) for r in changed) else math.nan,
        "after_change_share": mean([r.after_share for r in changed]),
        "unchanged_kept_share": mean([r.kept_share for r in changed]),
        # output-only draws: found by 3 s, and what an efficient estimator reaches (ceiling_3s)
        "output_only_found_2pct_by_3s": mean([float(r.found_by_3s) for r in results
                                              if r.output_only]),
        "output_only_ceiling_3s": mean([r.ceiling_3s for r in results if r.output_only]),
        "output_only_realistic_3s": mean([r.realistic_3s for r in results if r.output_only]),
    }
