"""HTML report of a validation run on the shared report page (``sysid_node.report``).

Tables: the verdict, the before/after comparison per channel (free-run and one-step fit), the
ranked hypotheses with evidence, the baseline's choice of order and horizon. Figures: measured
vs model (free run and one-step) per channel; the primary error over time before and after
("the error falls"); where the error lies in frequency (its spectrum against the
measurement's); its amplitude dependence (a missing cubic stiffness leaves an error growing
with the output amplitude); residual whiteness and input cross-correlation. A figure that
cannot be drawn says why instead.
"""

from __future__ import annotations

import numpy as np
from scipy import signal

from ..report import Page, figure
from .diagnose import verdict
from .residuals import welch_nperseg
from .workflow import Outcome


def amplitude_profile(
    y: np.ndarray, e: np.ndarray, bins: int = 8
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """RMS of the error e in bins of the measured |y| (quantile bins): (centre, rms, count)."""
    a = np.abs(y)
    edges = np.unique(np.quantile(a, np.linspace(0, 1, bins + 1)))
    idx = np.clip(np.searchsorted(edges, a, side="right") - 1, 0, edges.size - 2)
    cnt = np.bincount(idx, minlength=edges.size - 1)
    ss = np.bincount(idx, weights=e**2, minlength=edges.size - 1)
    ok = cnt > 0
    centre = 0.5 * (edges[:-1] + edges[1:])
    return centre[ok], np.sqrt(ss[ok] / cnt[ok]), cnt[ok]


def _models(out: Outcome) -> list[tuple]:
    label = "after +" + "+".join(out.added)
    return [(out.before, "r", "before")] + ([(out.after, "b", label)] if out.added else [])


def _measured_vs_model(page: Page, out: Outcome, names: list[str]) -> None:
    d, val = out.data, out.split.val
    t = d.t[val]
    fig, axes = figure(d.n_outputs, 1, height=2.6)
    sl = slice(0, min(len(t), max(int(10 * d.fs), 200)))
    for c in range(d.n_outputs):
        ax = axes[c, 0]
        ax.plot(t[sl], d.y[val, c][sl], "k.", ms=1.5, label="measured")
        for a, col, name in _models(out):
            if a.simulation is not None:
                ax.plot(t[sl], a.simulation[val, c][sl], col, lw=0.8, label=f"{name} free run")
            ax.plot(t[sl], a.prediction[val, c][sl], col + ":", lw=0.7, label=f"{name} 1-step")
        ax.set_ylabel(names[c])
        ax.legend(fontsize=7, loc="upper right")
    axes[-1, 0].set_xlabel("time [s]")
    page.figure(fig, "Measured vs model on the first 10 s of the validation samples")
    if not d.n_inputs:
        page.text("No free run drawn: output-only data, there is no input to simulate from.")
    elif out.before.simulation is None:
        page.text(f"No free run drawn before: {out.before.free_run_note}.")


def _error_over_time(page: Page, out: Outcome, names: list[str], what: str) -> None:
    fig, axes = figure(1, 1, height=2.8)
    ax = axes[0, 0]
    for a, col, name in _models(out):
        tw, ew = a.windows
        for c in range(out.data.n_outputs):
            ax.step(tw, ew[:, c], where="post", color=col, label=f"{name} {names[c]}")
    ax.set_xlabel("time [s]")
    ax.set_ylabel(f"{what} error RMS per window")
    ax.legend(fontsize=7)
    page.figure(fig, f"Where in time: the {what} validation error before and after")


def _error_spectrum(page: Page, out: Outcome, names: list[str], what: str) -> None:
    d, val = out.data, out.split.val
    fig, axes = figure(d.n_outputs, 1, height=2.8)
    nper = welch_nperseg(val.size, d.fs)
    for c in range(d.n_outputs):
        ax = axes[c, 0]
        f, py = signal.welch(d.y[val, c], fs=d.fs, nperseg=nper)
        ax.semilogy(f, py, "k", lw=0.8, label="measured")
        for a, col, name in _models(out):
            _, pe = signal.welch(a.primary_error[:, c], fs=d.fs, nperseg=nper)
            ax.semilogy(f, pe, col, lw=0.8, label=f"{what} error {name}")
        ax.set_ylabel(f"PSD {names[c]}")
        ax.legend(fontsize=7)
    axes[-1, 0].set_xlabel("frequency [Hz]")
    page.figure(fig, f"Where in frequency: spectrum of the {what} error against the measurement")


def _amplitude(page: Page, out: Outcome, names: list[str], what: str) -> None:
    d, val = out.data, out.split.val
    fig, axes = figure(1, 1, height=2.8)
    ax = axes[0, 0]
    for a, col, name in _models(out):
        for c in range(d.n_outputs):
            x, r, _ = amplitude_profile(d.y[val, c], a.primary_error[:, c])
            ax.plot(x, r, col + "o-", lw=0.8, ms=3, label=f"{name} {names[c]}")
    ax.set_xlabel("measured |y| (bin centre)")
    ax.set_ylabel(f"{what} error RMS")
    ax.legend(fontsize=7)
    page.figure(fig, "Error against the output amplitude (a missing nonlinearity grows with it)")


def _correlations(page: Page, out: Outcome) -> None:
    fig, axes = figure(1, 2, height=2.8)
    for a, col, name in _models(out):
        w = a.whiteness[0]
        axes[0, 0].plot(w.lags, w.r, col + ".-", lw=0.8, label=name)
        axes[0, 0].axhline(w.bound, color="k", ls=":")
        axes[0, 0].axhline(-w.bound, color="k", ls=":")
        if a.xcorr:
            x = next(iter(a.xcorr.values()))
            axes[0, 1].plot(x.lags, x.r, col + ".-", lw=0.8, label=name)
            axes[0, 1].axhline(x.bound, color="k", ls=":")
            axes[0, 1].axhline(-x.bound, color="k", ls=":")
    axes[0, 0].set_title("one-step residual autocorrelation (99 % bounds)", fontsize=9)
    axes[0, 1].set_title("residual-input cross-correlation (lag > 0: past input)", fontsize=9)
    axes[0, 0].legend(fontsize=7)
    page.figure(fig)
    if not out.before.xcorr:
        page.text("No residual-input cross-correlation: output-only data.")


def write_report(path: str, out: Outcome) -> None:
    """Write the HTML report of a validation run."""
    r = out.result()
    d = out.data
    names = d.output_names or [f"y{c}" for c in range(d.n_outputs)]
    what = "free-run" if r["primary"] == "free_run" else "one-step"
    page = Page("Model against measurement")
    sp = out.split
    page.text(
        f"{d.n} samples at {d.fs:.6g} Hz; estimation {sp.n_est}, validation {sp.n_val} "
        f"({sp.mode}{': ' + sp.reason if sp.reason else ''}); outputs {names}, inputs "
        f"{d.input_names or 'none (output-only)'}, candidate signals {sorted(d.signals) or 'none'}."
    )
    page.text(
        "Baseline: "
        + (r["baseline"]["note"] if r["baseline"] else "model loaded from a file")
        + f". Scored on the {what} prediction"
        + (f": {r['primary_note']}" if r["primary_note"] else ".")
    )
    page.heading("Verdict").text(verdict(out.before, out.hyps)["text"])
    rows = []
    for label, s in [("before", r["before"])] + (
        [("after +" + "+".join(out.added), r["after"])] if out.added else []
    ):
        for c, name in enumerate(names):
            free = s["fit_free_run_percent"]
            rows.append(
                [
                    label if c == 0 else "",
                    name,
                    None if free is None else free[c],
                    s["fit_percent"][c],
                    s["fit_estimation_percent"][c],
                    s["error_ratio_to_estimation"][c],
                ]
            )
    page.heading("Before / after (validation samples)")
    page.table(
        ["model", "channel", "fit free run %", "fit 1-step %", f"{what} fit on estimation %",
         "error / estimation error"],
        rows,
    )
    if out.before.free_run_note:
        page.text(f"Free run before: {out.before.free_run_note}.")
    if out.added:
        page.text(
            f"{what} validation error: {100 * r['before']['primary_nrmse']:.2f} % -> "
            f"{100 * r['after']['primary_nrmse']:.2f} % NRMSE ({100 * r['error_drop']:.0f} % "
            "lower); steps: "
            + "; ".join(f"+{s['model']}: {100 * s['primary_nrmse']:.2f} %" for s in r["steps"])
        )
    page.heading("Which effect is missing")
    page.table(
        ["#", "effect", "significant", "score", "parameters", "evidence"],
        (
            [k, h["effect"], h["significant"], _score(h), _params(h["parameters"]), h["evidence"]]
            for k, h in enumerate(r["diagnoses"], 1)
        ),
    )
    page.heading("Where the model fails")
    _measured_vs_model(page, out, names)
    _error_over_time(page, out, names, what)
    _error_spectrum(page, out, names, what)
    _amplitude(page, out, names, what)
    _correlations(page, out)
    if r["baseline"]:
        page.heading("Baseline: order and block rows")
        page.summary({k: v for k, v in r["baseline"].items() if k != "candidates"})
        page.table(
            ["block rows", "order", "free-run NRMSE", "one-step NRMSE", "stable", "note"],
            (
                [c["block_rows"], c["order"], c["free_run_nrmse"], c["one_step_nrmse"],
                 c["stable"], c["reason"]]
                for c in r["baseline"]["candidates"]
            ),
        )
    page.write(path)


def _score(h: dict) -> str:
    """The trial's score, and what ranked it when that differs (a loop: its model's output drop)."""
    if h["rank_score"] == h["score"]:
        return f"{h['score']:.4g}"
    return f"{h['score']:.4g} (ranked {h['rank_score']:.4g}: the loop model's output drop)"


def _params(p: dict) -> str:
    return ", ".join(f"{k}={_short(v)}" for k, v in p.items()) or "-"


def _short(v) -> str:
    if isinstance(v, float):
        return f"{v:.4g}"
    if isinstance(v, list):
        return "[" + ", ".join(_short(x) for x in v) + "]"
    return "-" if v is None else str(v)
