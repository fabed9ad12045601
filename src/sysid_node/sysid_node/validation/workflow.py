"""The validate workflow on in-memory data: baseline, compare, diagnose, add effects, re-fit.

:func:`run_validation` is what the ``validate`` tool does between reading the data and writing
its outputs, so tests and other tools run it on arrays without a bag.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field, replace

import numpy as np

from ..core.order import select_order
from . import gates as G
from .assess import Assessment, assess, compare_primary
from .augment import EFFECTS, ModelSpec
from .baseline import BaselineChoice, horizons, select_baseline
from .data import ValidationData, ValidationError
from .diagnose import MIN_DROP, P_DROP, diagnose, verdict
from .gates import Hypothesis, jsonable
from .models import FittedModel, data_projection, fit
from .split import Split, make_split

AUTO_MIN_GAIN = MIN_DROP  # --auto keeps adding while the primary error falls by >= 5 %


@dataclass
class Options:
    """What to validate and how (the CLI flags of ``validate``)."""

    split: float = 0.6  # estimation fraction, or the first validation sample when > 1
    split_mode: str = "auto"  # chronological / interleaved / auto (interleaved for sweeps)
    order: int | None = None
    block_rows: int | None = None
    order_method: str = "validation"  # or gap / aic / bic / mdl at the given block rows
    add: list[tuple[str, dict]] = field(default_factory=list)
    auto: bool = False
    signal: str | None = None  # the one candidate signal; '' = none
    max_lag: int = 20
    model: object | None = None  # an IdentifiedModel to validate instead of identifying


@dataclass
class Outcome:
    """Everything a run produced (the JSON is :meth:`result`)."""

    data: ValidationData
    split: Split
    choice: BaselineChoice | None
    base: FittedModel
    before: Assessment
    hyps: list[Hypothesis]
    current: FittedModel
    after: Assessment
    added: list[str]
    steps: list[dict]
    seconds: float
    source: str = ""

    @property
    def error_drop(self) -> float:
        """Relative drop of the primary validation error, before -> after."""
        return 1.0 - self.after.primary_nrmse / max(self.before.primary_nrmse, 1e-300)

    def result(self) -> dict:
        d = self.data
        return jsonable(
            {
                "source": self.source,
                "fs": d.fs,
                "n_estimation": self.split.n_est,
                "n_validation": self.split.n_val,
                "split": self.split.summary(),
                "outputs": d.output_names,
                "inputs": d.input_names,
                "candidate_signals": sorted(d.signals),
                "order": self.base.order,
                "baseline": None if self.choice is None else self.choice.summary(),
                "primary": self.before.primary,
                "primary_note": self.before.primary_note,
                "before": self.before.summary(),
                "diagnoses": [h.to_dict() for h in self.hyps],
                "verdict": verdict(self.before, self.hyps),
                "added": self.added,
                "steps": self.steps,
                "after": self.after.summary(),
                "error_drop": self.error_drop,
                "residual_rms_reduction": 1.0
                - float(np.mean(self.after.residual_rms / self.before.residual_rms)),
                "seconds": round(self.seconds, 3),
            }
        )


def _baseline(
    data: ValidationData, split: Split, opts: Options, spec: ModelSpec, criterion: str
) -> tuple[FittedModel, BaselineChoice | None]:
    if opts.model is not None:
        m = opts.model
        spec.order = m.order
        shortest = min(b - a for a, b in split.est_segments)
        spec.block_rows = opts.block_rows or horizons(
            split.n_est, data.n_inputs, data.n_outputs, m.order, None, shortest
        )[-1]
        return FittedModel(spec, m.order, model=m, n_outputs=data.n_outputs), None
    order = opts.order
    if order is None and opts.order_method != "validation":
        i = opts.block_rows or 20
        dp = data_projection(data.y, data.u, data.fs, i, split.est_segments)
        order = select_order(dp.proj, opts.order_method)
    fm, choice = select_baseline(data, split, spec, order, opts.block_rows, criterion)
    return fm, choice


def baseline_assessment(
    data: ValidationData, opts: Options
) -> tuple[Split, FittedModel, BaselineChoice | None, Assessment]:
    """The split, the baseline model (order and horizon as ``opts`` asks), how it was chosen
    and its assessment: what ``validate`` compares before any hypothesis. The primary error
    is the free run, or the one-step prediction for output-only or closed-loop data."""
    need = 2 * (opts.block_rows or 10) * (1 + data.n_inputs + data.n_outputs) + 50
    split = make_split(data, opts.split, need, opts.split_mode)
    spec = ModelSpec(order=opts.order, block_rows=opts.block_rows or 20)
    criterion, note = "free_run" if data.n_inputs else "one_step", ""
    if data.n_inputs:  # closed loop: the input is not exogenous, a free run from it is no test
        p_loop, share = G.closed_loop_test(data, split.est)
        if p_loop < G.P_GATE and share >= G.CLOSED_LOOP_SHARE:
            criterion = "one_step"
            note = (
                f"the input depends on past outputs (closed loop: ARX innovations explain "
                f"{100 * share:.0f} % of its unpredictable part, Granger p={p_loop:.1e}): a free "
                "run from it is not independent of the measurement, so the one-step prediction "
                "is scored"
            )
    base, choice = _baseline(data, split, opts, spec, criterion)
    before = assess(base, data, split, opts.max_lag, primary=criterion)
    before.primary_note = note
    return split, base, choice, before


def run_validation(data: ValidationData, opts: Options, source: str = "") -> Outcome:
    """Baseline, compare, diagnose; then ``opts.add`` and/or ``--auto`` additions."""
    t0 = time.perf_counter()
    for name, _ in opts.add:
        if name not in EFFECTS:
            raise ValidationError(f"unknown effect {name!r}; one of {', '.join(EFFECTS)}")
    if opts.signal and opts.signal not in data.signals:
        raise ValidationError(
            f"no candidate signal {opts.signal}; available: "
            + (", ".join(sorted(data.signals)) or "-")
        )
    split, base, choice, before = baseline_assessment(data, opts)
    spec = base.spec
    scans: dict = {}  # the delay scan's fits, shared by the diagnoses of this run
    hyps = diagnose(data, split, spec, base, before, signal=opts.signal, scans=scans)
    current, cur_a, added, steps = base, before, [], []
    if opts.add:
        current, cur_a = _add_given(data, split, opts, hyps, base, before)
        added = [name for name, _ in opts.add]
        steps.append(_step(added, before, cur_a))
    if opts.auto:
        cur_hyps = hyps if not added else diagnose(
            data, split, current.spec, current, cur_a, opts.signal, scans=scans
        )
        for _ in range(len(EFFECTS)):
            top = next((h for h in cur_hyps if h.significant and h.trial is not None), None)
            if top is None:
                break
            cand = assess(top.trial, data, split, opts.max_lag, primary=before.primary)
            cmp = compare_primary(cur_a, cand.primary_error)
            if top.effect == "feedback":  # its gain is the input's error (diagnose), the
                if cmp.drop <= -AUTO_MIN_GAIN:  # output's must not rise
                    break
            elif cmp.drop < AUTO_MIN_GAIN or cmp.p_value >= P_DROP:
                break
            steps.append(_step([*added, top.effect], cur_a, cand))
            current, cur_a = top.trial, cand
            added.append(top.effect)
            cur_hyps = diagnose(data, split, current.spec, current, cur_a, opts.signal,
                                scans=scans)
    return Outcome(
        data,
        split,
        choice,
        base,
        before,
        hyps,
        current,
        cur_a,
        added,
        steps,
        time.perf_counter() - t0,
        source,
    )


def _step(added: list[str], before: Assessment, after: Assessment) -> dict:
    drop = 1.0 - after.primary_nrmse / max(before.primary_nrmse, 1e-300)
    return {
        "model": "+".join(added),
        "primary_nrmse": after.primary_nrmse,
        "drop": drop,
    }


def _add_given(
    data: ValidationData,
    split: Split,
    opts: Options,
    hyps: list[Hypothesis],
    base: FittedModel,
    before: Assessment,
) -> tuple[FittedModel, Assessment]:
    """The structure with the ``--add`` effects (diagnosed parameters unless given)."""
    if len(opts.add) == 1 and not opts.add[0][1]:
        diag = next(h for h in hyps if h.effect == opts.add[0][0])
        if diag.trial is not None:  # the diagnosis already re-fitted exactly this structure
            return diag.trial, assess(diag.trial, data, split, opts.max_lag, before.primary)
    spec = base.spec
    for name, params in opts.add:
        diag = next(h for h in hyps if h.effect == name)
        keep = {"frequency_hz", "damping", "channel", "source", "harmonics", "signal"}
        merged = {k: v for k, v in diag.parameters.items() if v is not None and k in keep}
        if name == "input_delay" and "samples" in diag.parameters:
            merged["samples"] = diag.parameters["samples"]
        merged.update(params)
        if name == "input_delay":
            merged.setdefault("fs", data.fs)
            if "samples" not in merged and "delay_s" not in merged:
                merged["samples"] = 1
        if name == "parameter_varying" and "signal" not in merged and data.signals:
            merged["signal"] = sorted(data.signals)[0]
        spec = spec.with_effect(name, merged)
    current = fit(replace(spec), data, split)
    return current, assess(current, data, split, opts.max_lag, before.primary)
