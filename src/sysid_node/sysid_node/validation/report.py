"""HTML report of a validation run: figures and tables (``sysid_node.report`` page)."""

from __future__ import annotations

import json

import numpy as np

from ..report import Page
from .augment import FittedModel
from .data import ValidationData
from .diagnose import Assessment, Hypothesis, _jsonable


def _figures(
    data: ValidationData, n_est: int, before: Assessment, after: Assessment | None, label: str
) -> list:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    figs = []
    t = data.t[n_est:]
    l = data.n_outputs
    # measured vs model
    fig, axes = plt.subplots(l, 1, figsize=(10, 2.6 * l), squeeze=False)
    sl = slice(0, min(len(t), int(10 * data.fs)))
    for c in range(l):
        ax = axes[c, 0]
        ax.plot(t[sl], data.y[n_est:, c][sl], "k", lw=1, label="measured")
        ax.plot(t[sl], before.prediction[n_est:, c][sl], "r", lw=0.8, label="before (1-step)")
        if after is not None:
            ax.plot(t[sl], after.prediction[n_est:, c][sl], "b--", lw=0.8, label=f"after {label}")
        if before.simulation is not None and np.all(np.isfinite(before.simulation[n_est:, c])):
            ax.plot(
                t[sl], before.simulation[n_est:, c][sl], "r:", lw=0.6, label="before (free run)"
            )
        ax.set_ylabel(data.output_names[c] if c < len(data.output_names) else f"y{c}")
        ax.legend(fontsize=7, loc="upper right")
    axes[-1, 0].set_xlabel("time [s]")
    fig.suptitle("Measured vs model on the validation part (first 10 s)")
    figs.append(fig)
    # error over time
    fig, ax = plt.subplots(figsize=(10, 2.8))
    tw, ew = before.windows
    for c in range(l):
        ax.step(tw + t[0], ew[:, c], where="post", color="r", label=f"before ch{c}")
        if after is not None:
            ta, ea = after.windows
            ax.step(ta + t[0], ea[:, c], where="post", color="b", label=f"after ch{c}")
    ax.set_xlabel("time [s]")
    ax.set_ylabel("residual RMS per window")
    ax.legend(fontsize=7)
    figs.append(fig)
    # residual spectrum
    fig, axes = plt.subplots(l, 1, figsize=(10, 2.8 * l), squeeze=False)
    for c in range(l):
        ax = axes[c, 0]
        sp = before.spectrum
        ax.semilogy(sp.f, sp.psd[:, c], "r", lw=0.8, label="residual before")
        ax.semilogy(sp.f, sp.floor[:, c] * sp.bound_factor, "r:", lw=0.8, label="99.9 % bound")
        if after is not None:
            sa = after.spectrum
            ax.semilogy(sa.f, sa.psd[:, c], "b", lw=0.8, label="residual after")
            ax.semilogy(sa.f, sa.floor[:, c] * sa.bound_factor, "b:", lw=0.8)
        ax.set_ylabel("PSD")
        ax.legend(fontsize=7)
    axes[-1, 0].set_xlabel("frequency [Hz]")
    fig.suptitle("Residual spectrum against its white noise floor")
    figs.append(fig)
    # whiteness and cross-correlation
    fig, axes = plt.subplots(1, 2, figsize=(10, 2.8))
    for a, col, name in ((before, "r", "before"), (after, "b", "after")):
        if a is None:
            continue
        w = a.whiteness[0]
        axes[0].plot(w.lags, w.r, col + ".-", lw=0.8, label=name)
        axes[0].axhline(w.bound, color="k", ls=":")
        axes[0].axhline(-w.bound, color="k", ls=":")
        if a.xcorr:
            x = next(iter(a.xcorr.values()))
            axes[1].plot(x.lags, x.r, col + ".-", lw=0.8, label=name)
            axes[1].axhline(x.bound, color="k", ls=":")
            axes[1].axhline(-x.bound, color="k", ls=":")
    axes[0].set_title("residual autocorrelation (99 % bounds)", fontsize=9)
    axes[1].set_title("residual-input cross-correlation (lag > 0: past input)", fontsize=9)
    axes[0].legend(fontsize=7)
    figs.append(fig)
    return figs


def write_report(
    path: str,
    data: ValidationData,
    n_est: int,
    base: FittedModel,
    before: Assessment,
    current: FittedModel,
    after: Assessment,
    hyps: list[Hypothesis],
    added: list[str],
) -> None:
    """Write the HTML report (measured vs model, error over time, residual spectra, ranking)."""
    label = "+" + "+".join(added) if added else ""
    figs = _figures(data, n_est, before, after if added else None, label)
    page = Page("Model against measurement")
    page.text(f"{data.n} samples at {data.fs:.4g} Hz; estimation {n_est}, validation "
              f"{data.n - n_est}; outputs {data.output_names}, inputs {data.input_names}, "
              f"candidate signals {sorted(data.signals)}; model order {base.order}.")
    keys = ("fit_percent", "fit_free_run_percent", "residual_rms", "whiteness_p",
            "xcorr_p_past", "xcorr_p_future")
    rows = [["before", *(before.summary()[k] for k in keys)]]
    if added:
        rows.append([f"after {label}", *(after.summary()[k] for k in keys)])
    page.heading("Before / after").table(
        ["model", "fit 1-step %", "fit free run %", "residual RMS", "whiteness p",
         "xcorr p (past)", "xcorr p (future)"], rows)
    page.heading("Which effect is missing").table(
        ["#", "effect", "score", "parameters", "evidence"],
        ([k, ("*" if h.significant else "") + h.effect, h.score,
          json.dumps(_jsonable(h.parameters)), h.evidence] for k, h in enumerate(hyps, 1)))
    page.heading("Where the model fails")
    for fig in figs:
        page.figure(fig, dpi=90)
    page.write(path)
