"""Which physical effect is missing: ranked hypotheses with evidence and parameters.

Each effect of the fixed vocabulary (:data:`~.augment.EFFECTS`) has a statistical gate on the
validation residual of the current model (the symptom) and parameter estimates from it:

=====================  =======================================================================
missing_mode           narrow-band residual peak above the 99.9 % noise-floor bound, not a line,
                       not at a mode of the model or a harmonic of a rotating speed
periodic_disturbance   harmonics of a candidate rotating speed (or a fixed line) explaining
                       residual variance (F-test)
parameter_varying      residual power depending on a candidate scheduling signal (F-test)
input_delay            residual correlated with past inputs (cross-correlation portmanteau)
nonlinear_stiffness    residual correlated with the cubic Hermite term of an output
                       (higher-order correlation test)
sensor_bias            non-zero residual mean or trend (t-tests on block means)
feedback               past outputs predicting the input (Granger F-test) or the residual
                       correlated with future inputs (cross-correlation portmanteau)
=====================  =======================================================================

A hypothesis whose gate fires is confirmed by a trial re-fit with the effect added; its score is
the fractional drop of the validation residual RMS, 1 - rms_after / rms_before (averaged over the
channels). A hypothesis is significant when its gate fires with p < 0.01 and the trial lowers the
residual RMS by at least 20 %.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy import stats

from . import residuals as rs
from .augment import EFFECTS, FittedModel, ModelSpec, fit, rotor_phase
from .data import ValidationData, ValidationError

P_GATE = 1e-2
MIN_GAIN = 0.2
MAX_DELAY_SAMPLES = 8


@dataclass
class Hypothesis:
    """One candidate missing effect."""

    effect: str
    score: float = 0.0
    significant: bool = False
    evidence: str = ""
    parameters: dict = field(default_factory=dict)
    p_value: float = 1.0
    trial: FittedModel | None = None

    def to_dict(self) -> dict:
        return {
            "effect": self.effect,
            "score": round(float(self.score), 4),
            "significant": bool(self.significant),
            "p_value": float(self.p_value),
            "evidence": self.evidence,
            "parameters": _jsonable(self.parameters),
        }


def _jsonable(x):
    if isinstance(x, dict):
        return {k: _jsonable(v) for k, v in x.items()}
    if isinstance(x, list | tuple):
        return [_jsonable(v) for v in x]
    if isinstance(x, np.generic):
        return x.item()
    if isinstance(x, float) and not np.isfinite(x):
        return None
    return x


@dataclass
class Assessment:
    """Compare and residual tests of one model on the validation part."""

    fit_percent: np.ndarray
    fit_free_run_percent: np.ndarray | None
    residual_rms: np.ndarray
    residual: np.ndarray  # validation residual (Nv, l)
    prediction: np.ndarray  # one-step prediction, whole record
    simulation: np.ndarray | None  # free run, whole record
    whiteness: list[rs.WhitenessTest]
    xcorr: dict[tuple[int, int], rs.CrossCorrelationTest]  # (output, input)
    spectrum: rs.Spectrum
    windows: tuple[np.ndarray, np.ndarray]

    @property
    def white(self) -> bool:
        return all(w.passed for w in self.whiteness)

    @property
    def uncorrelated(self) -> bool:
        return all(x.passed for x in self.xcorr.values())

    def summary(self) -> dict:
        return {
            "fit_percent": [round(float(v), 3) for v in self.fit_percent],
            "fit_free_run_percent": None
            if self.fit_free_run_percent is None
            else [round(float(v), 3) for v in self.fit_free_run_percent],
            "residual_rms": [float(v) for v in self.residual_rms],
            "whiteness_p": [float(w.p_value) for w in self.whiteness],
            "whiteness_passed": self.white,
            "xcorr_p_past": [float(x.p_past) for x in self.xcorr.values()],
            "xcorr_p_future": [float(x.p_future) for x in self.xcorr.values()],
            "xcorr_passed": self.uncorrelated,
        }


def assess(fm: FittedModel, data: ValidationData, n_est: int, max_lag: int = 20) -> Assessment:
    """One-step and free-run comparison and the residual tests on samples [n_est, N)."""
    yhat = fm.predict(data)
    with np.errstate(all="ignore"):
        ysim = fm.simulate(data)
    scale = 1e6 * max(float(np.max(np.abs(data.y))), 1e-300)
    if ysim is not None and not np.all(np.abs(ysim[n_est:]) < scale):
        ysim = np.full_like(data.y, np.nan)  # a diverging free run: no free-run fit
    yv = data.y[n_est:]
    e = yv - yhat[n_est:]
    fit_free = None if ysim is None else rs.nrmse_fit(yv, ysim[n_est:])
    white = [rs.whiteness(e[:, c], max_lag) for c in range(e.shape[1])]
    xc = {
        (c, j): rs.cross_correlation(e[:, c], data.u[n_est:, j], max_lag)
        for c in range(e.shape[1])
        for j in range(data.n_inputs)
    }
    return Assessment(
        rs.nrmse_fit(yv, yhat[n_est:]),
        fit_free,
        rs.rms(e),
        e,
        yhat,
        ysim,
        white,
        xc,
        rs.residual_spectrum(e, data.fs),
        rs.error_windows(e, data.fs),
    )


def _gain(before: np.ndarray, after: np.ndarray) -> float:
    return float(np.mean(1.0 - np.asarray(after) / np.asarray(before)))


def _trial(
    spec: ModelSpec, effect: str, params: dict, data: ValidationData, n_est: int, rms0: np.ndarray
) -> tuple[float, FittedModel | None, str]:
    try:
        fm = fit(spec.with_effect(effect, params), data, n_est)
    except ValidationError as err:
        return 0.0, None, f"; trial re-fit failed: {err}"
    e = data.y[n_est:] - fm.predict(data)[n_est:]
    if not np.all(np.isfinite(e)):
        return 0.0, None, "; trial re-fit diverged"
    return _gain(rms0, rs.rms(e)), fm, ""


def _rotating_candidates(data: ValidationData) -> list[str]:
    """Signals that can be a rotating speed [Hz]: positive, below Nyquist, not too variable."""
    out = []
    for name, s in data.signals.items():
        m = float(np.mean(s))
        if 0.05 < m < 0.5 * data.fs and np.all(s > 0) and np.std(s) < 0.5 * m:
            out.append(name)
    return out


def _harmonic_test(
    e: np.ndarray, phi: np.ndarray, orders=(1, 2, 3, 4)
) -> tuple[float, float, list]:
    """F-test of cos/sin(k phi) regressors on e: (p-value, R^2, significant orders)."""
    n = e.size
    cols = []
    for k in orders:
        cols += [np.cos(k * phi), np.sin(k * phi)]
    x = np.column_stack(cols)
    th, *_ = np.linalg.lstsq(x, e - e.mean(), rcond=None)
    fitted = x @ th
    ss_res = float(np.sum((e - e.mean() - fitted) ** 2))
    ss_tot = float(np.sum((e - e.mean()) ** 2))
    p = x.shape[1]
    r2 = 1 - ss_res / ss_tot if ss_tot > 0 else 0.0
    f = (r2 / p) / max((1 - r2) / (n - p - 1), 1e-300)
    pval = float(stats.f.sf(f, p, n - p - 1))
    sigma2 = ss_res / (n - p - 1)
    sig = []
    for i, k in enumerate(orders):  # each harmonic: chi2(2) on its amplitude (x'x ~ n/2 I)
        a = th[2 * i : 2 * i + 2]
        chi = float(np.sum(a**2) * (n / 2) / max(sigma2, 1e-300))
        if stats.chi2.sf(chi, 2) < P_GATE:
            sig.append(int(k))
    return pval, r2, sig


def _block_means(
    e: np.ndarray, t: np.ndarray, blocks: int = 12
) -> tuple[float, float, float, float]:
    """(offset, p offset, slope [1/s], p slope) from block means of e (robust to colour)."""
    k = e.size // blocks
    bm = e[: k * blocks].reshape(blocks, k).mean(axis=1)
    bt = t[: k * blocks].reshape(blocks, k).mean(axis=1)
    tt = stats.ttest_1samp(bm, 0.0)
    lr = stats.linregress(bt, bm)
    return float(bm.mean()), float(tt.pvalue), float(lr.slope), float(lr.pvalue)


def _power_dependence(e: np.ndarray, s: np.ndarray, fs: float) -> tuple[float, float]:
    """F-test of log window power of e on [1, s, s^2]: (p-value, R^2)."""
    w = max(int(fs / 2), 8)
    k = e.size // w
    if k < 8:
        return 1.0, 0.0
    lp = np.log(np.mean(e[: k * w].reshape(k, w) ** 2, axis=1) + 1e-300)
    sm = s[: k * w].reshape(k, w).mean(axis=1)
    if np.ptp(sm) <= 1e-9 * max(1.0, abs(sm.mean())):
        return 1.0, 0.0
    z = (sm - sm.mean()) / sm.std()
    x = np.column_stack([np.ones(k), z, z**2])
    th, *_ = np.linalg.lstsq(x, lp, rcond=None)
    ss_res = float(np.sum((lp - x @ th) ** 2))
    ss_tot = float(np.sum((lp - lp.mean()) ** 2))
    r2 = 1 - ss_res / ss_tot if ss_tot > 0 else 0.0
    f = (r2 / 2) / max((1 - r2) / (k - 3), 1e-300)
    return float(stats.f.sf(f, 2, k - 3)), r2


def diagnose(
    data: ValidationData,
    n_est: int,
    spec: ModelSpec,
    current: FittedModel,
    assessment: Assessment,
    signal: str | None = None,
    trials: bool = True,
) -> list[Hypothesis]:
    """Rank the effects of the vocabulary for the model ``current`` (fitted with ``spec``).

    ``signal`` restricts the candidate explanatory signals to one name. Returns one Hypothesis
    per effect, best first.
    """
    e = assessment.residual
    rms0 = assessment.residual_rms
    fs = data.fs
    tv = data.t[n_est:]
    cands = {k: v for k, v in data.signals.items() if signal is None or k == signal}
    if signal is not None and not cands:
        raise ValidationError(
            f"no signal {signal} in the data; candidates: {', '.join(data.signals) or '-'}"
        )
    hyps: dict[str, Hypothesis] = {k: Hypothesis(k) for k in EFFECTS}
    model_freqs = [md.frequency_hz for md in current.modes()]

    # -------------------------------------------------------------- sensor_bias
    best = (1.0, 0)
    parts = []
    for c in range(e.shape[1]):
        off, p_off, slope, p_slope = _block_means(e[:, c], tv)
        p = min(p_off, p_slope)
        parts.append(
            f"ch{c}: mean {off:.3g} (p={p_off:.1e}), trend {slope:.3g}/s (p={p_slope:.1e})"
        )
        if p < best[0]:
            best = (p, c)
    h = hyps["sensor_bias"]
    h.p_value = best[0]
    h.evidence = "residual block means: " + "; ".join(parts)

    # -------------------------------------------------------------- periodic_disturbance
    h = hyps["periodic_disturbance"]
    per_best = None
    for name in _rotating_candidates(data) if cands else []:
        if name not in cands:
            continue
        phi = rotor_phase(data.signals[name], fs)[n_est:]
        for c in range(e.shape[1]):
            p, r2, sig = _harmonic_test(e[:, c], phi)
            if per_best is None or p < per_best[0]:
                per_best = (p, r2, sig, name, c)
    if per_best is not None and per_best[2]:
        p, r2, sig, name, c = per_best
        h.p_value = p
        h.parameters = {
            "source": name,
            "harmonics": sig,
            "frequency_hz": float(np.mean(data.signals[name])),
        }
        h.evidence = (
            f"harmonics {sig} of {name} (mean {np.mean(data.signals[name]):.3f} Hz) explain "
            f"{100 * r2:.1f} % of the ch{c} residual variance (F-test p={p:.1e})"
        )
    peaks = rs.spectral_peaks(assessment.spectrum)
    line_peaks = []
    mode_peaks = []
    for pk in peaks:
        frac, f1, amp = rs.line_fraction(e[:, pk.channel], fs, pk.frequency_hz)
        harmonic_of_rotor = (
            per_best is not None
            and per_best[2]
            and any(
                abs(pk.frequency_hz - k * h.parameters["frequency_hz"])
                < 0.03 * k * h.parameters["frequency_hz"]
                for k in range(1, 9)
            )
        )
        if harmonic_of_rotor:
            continue
        near_mode = any(abs(pk.frequency_hz - f) <= 0.05 * f for f in model_freqs)
        if frac > 0.7 and not near_mode:
            line_peaks.append((pk, frac, f1))
        else:
            mode_peaks.append(pk)
    if not h.parameters and line_peaks:
        pk, frac, f1 = line_peaks[0]
        h.p_value = 0.0
        h.parameters = {"source": None, "frequency_hz": f1, "harmonics": [1]}
        h.evidence = (
            f"a line at {f1:.3f} Hz on ch{pk.channel} ({pk.ratio:.0f}x the noise floor); one "
            f"sinusoid explains {100 * frac:.0f} % of the band power"
        )
    if not h.parameters:
        h.evidence = "no residual line and no harmonics of a candidate rotating speed"

    # -------------------------------------------------------------- missing_mode
    h = hyps["missing_mode"]
    far = [pk for pk in mode_peaks if all(abs(pk.frequency_hz - f) > 0.05 * f for f in model_freqs)]
    if far:
        pk = far[0]
        h.p_value = float(stats.chi2.sf(pk.ratio * 2, 2)) if pk.ratio < 300 else 0.0
        h.p_value = min(h.p_value, P_GATE / 10)  # above margin x the 99.9 % bound
        h.parameters = {
            "frequency_hz": pk.frequency_hz,
            "damping": pk.damping,
            "channel": pk.channel,
        }
        coh = ""
        if data.n_inputs:
            f, cxy, bnd = rs.coherence(e[:, pk.channel], data.u[n_est:, 0], fs)
            cv = float(np.interp(pk.frequency_hz, f, cxy))
            coh = f", residual-input coherence there {cv:.2f} (99 % bound {bnd:.2f})"
        h.evidence = (
            f"residual peak at {pk.frequency_hz:.3f} Hz on ch{pk.channel}, {pk.ratio:.0f}x the "
            f"noise floor (99.9 % bound {assessment.spectrum.bound_factor:.1f}x), no model mode "
            f"within 5 %{coh}"
        )
    else:
        near = [pk.frequency_hz for pk in mode_peaks]
        h.evidence = "no narrow-band residual peak away from the model modes" + (
            f" (peaks near model modes at {', '.join(f'{f:.2f}' for f in near)} Hz)" if near else ""
        )

    # -------------------------------------------------------------- parameter_varying
    h = hyps["parameter_varying"]
    pv_best = None
    for name, s in cands.items():
        sv = s[n_est:]
        for c in range(e.shape[1]):
            p, r2 = _power_dependence(e[:, c], sv, fs)
            if pv_best is None or p < pv_best[0]:
                pv_best = (p, r2, name, c)
    if pv_best is not None:
        p, r2, name, c = pv_best
        h.p_value = p
        h.parameters = {"signal": name}
        h.evidence = (
            f"ch{c} residual power depends on {name} ({100 * r2:.0f} % of its log-power "
            f"variance explained by a quadratic in {name}, F-test p={p:.1e})"
        )
    else:
        h.evidence = "no candidate scheduling signal in the data"

    # -------------------------------------------------------------- input_delay / feedback
    hd, hf = hyps["input_delay"], hyps["feedback"]
    if assessment.xcorr:
        key_p = min(assessment.xcorr, key=lambda k: assessment.xcorr[k].p_past)
        xp = assessment.xcorr[key_p]
        lag, val = xp.peak("past")
        hd.p_value = xp.p_past
        hd.evidence = (
            f"residual ch{key_p[0]} vs input {key_p[1]}: past-input cross-correlation "
            f"portmanteau p={xp.p_past:.1e}, peak {val:+.2f} at lag {lag} "
            f"(99 % bound {xp.bound:.2f})"
        )
        key_f = min(assessment.xcorr, key=lambda k: assessment.xcorr[k].p_future)
        xf = assessment.xcorr[key_f]
        lag_f, val_f = xf.peak("future")
        grang = [rs.granger_feedback(data.u[:, j], data.y) for j in range(data.n_inputs)]
        j_g = int(np.argmin([g[1] for g in grang]))
        f_g, p_g = grang[j_g]
        hf.p_value = min(xf.p_future, p_g)
        hf.parameters = {"lag": -lag_f, "lag_s": -lag_f / fs}
        hf.evidence = (
            f"past outputs predict input {j_g} (Granger F={f_g:.1f}, p={p_g:.1e}); residual "
            f"ch{key_f[0]} vs FUTURE input {key_f[1]}: portmanteau p={xf.p_future:.1e}, peak "
            f"{val_f:+.2f} at lag {lag_f} (99 % bound {xf.bound:.2f})"
        )
    else:
        hd.evidence = hf.evidence = "output-only data: no input to correlate with"

    # -------------------------------------------------------------- nonlinear_stiffness
    h = hyps["nonlinear_stiffness"]
    nl_best = None
    for c in range(e.shape[1]):
        for j in range(data.n_outputs):
            r, bnd, p = rs.higher_order_correlation(e[:, c], data.y[n_est:, j])
            if nl_best is None or p < nl_best[0]:
                nl_best = (p, j, c, float(np.max(np.abs(r))), bnd)
    p, j, c, rmax, bnd = nl_best
    h.p_value = p
    h.parameters = {"channel": j}
    h.evidence = (
        f"residual ch{c} correlated with the cubic term of output {j}: max |r| {rmax:.2f} "
        f"(99 % bound {bnd:.2f}), portmanteau p={p:.1e}"
    )

    # -------------------------------------------------------------- trials
    if trials:
        for h in hyps.values():
            if h.p_value >= P_GATE:
                continue
            if h.effect in ("missing_mode", "periodic_disturbance") and not h.parameters:
                continue
            _confirm(h, spec, data, n_est, rms0, current)
    return rank(list(hyps.values()))


#: Parameters an effect adds, in order of complexity (Occam tie-break of :func:`rank`).
COMPLEXITY = {
    "input_delay": 1,
    "sensor_bias": 2,
    "periodic_disturbance": 3,
    "nonlinear_stiffness": 4,
    "missing_mode": 5,
    "feedback": 6,
    "parameter_varying": 7,
}
TIE = 0.05


def rank(hyps: list[Hypothesis]) -> list[Hypothesis]:
    """Best first by score; within TIE of the best, the simpler effect first (parsimony)."""
    out = sorted(hyps, key=lambda hh: (-hh.score, hh.p_value))
    if out and out[0].score > 0:
        top = [h for h in out if h.score >= out[0].score - TIE and h.significant]
        if top:
            first = min(top, key=lambda hh: (COMPLEXITY[hh.effect], -hh.score))
            out.remove(first)
            out.insert(0, first)
    return out


def _confirm(
    h: Hypothesis,
    spec: ModelSpec,
    data: ValidationData,
    n_est: int,
    rms0: np.ndarray,
    current: FittedModel,
) -> None:
    """Trial re-fit with the effect added: score and refined parameters."""
    eff = h.effect
    note = ""
    if eff == "input_delay":
        # increasing delays; stop two steps after the gain last improved
        best, trend = (0.0, None, 0), 0
        for d in range(spec.delay + 1, spec.delay + MAX_DELAY_SAMPLES + 1):
            g, fm, _ = _trial(spec, eff, {"samples": d}, data, n_est, rms0)
            if g > best[0]:
                best, trend = (g, fm, d), 0
            else:
                trend += 1
                if trend >= 2:
                    break
        g, fm, d = best
        if fm is not None:
            h.parameters = {"samples": d, "delay_s": d / data.fs}
    elif eff == "sensor_bias":
        g, fm, note = _trial(spec, eff, {}, data, n_est, rms0)
        if fm is not None and fm.theta is not None:
            span = max(np.ptp(data.t), 1e-9)
            k0 = 2 * len([x for x in spec.harmonics for _ in x["orders"]]) * 0  # bias cols first
            off = fm.theta[k0] - fm.theta[k0 + 1] * data.t.mean() / span
            h.parameters = {
                "offset": [float(v) for v in off],
                "drift_per_s": [float(v) for v in fm.theta[k0 + 1] / span],
            }
    else:
        g, fm, note = _trial(spec, eff, h.parameters, data, n_est, rms0)
        if fm is not None and eff == "missing_mode":
            old = [md.frequency_hz for md in current.modes()]
            new = [md for md in fm.modes() if all(abs(md.frequency_hz - f) > 0.03 * f for f in old)]
            if new:
                f0 = h.parameters["frequency_hz"]
                md = min(new, key=lambda m: abs(m.frequency_hz - f0))
                h.parameters.update(frequency_hz=md.frequency_hz, damping=md.damping_ratio)
        if fm is not None and eff == "parameter_varying" and fm.lpv is not None:
            fr = fm.lpv.frequencies(data.fs)
            if fr.ndim == 2 and fr.shape[1]:
                span = fr.max(axis=0) - fr.min(axis=0)
                k = int(np.argmax(span))
                slope = float(np.polyfit(fm.lpv.points, fr[:, k], 1)[0])
                h.parameters.update(
                    operating_points=[float(v) for v in fm.lpv.points],
                    mode_frequency_hz=[float(v) for v in fr[:, k]],
                    frequency_slope_hz_per_unit=slope,
                )
        if fm is not None and eff == "feedback" and fm.controller is not None:
            c = data.n_outputs + data.n_inputs
            gy = np.abs(fm.controller[:, 0]).reshape(-1, c)[:, : data.n_outputs].max(axis=1)
            lag = int(np.argmax(gy)) + 1
            h.parameters = {"lag": lag, "lag_s": lag / data.fs, "lags_fitted": len(gy)}
        if fm is not None and eff == "nonlinear_stiffness":
            h.parameters["cubic_gain"] = fm.cubic_gain()
    h.trial = fm
    h.score = max(0.0, g)
    h.significant = h.p_value < P_GATE and g >= MIN_GAIN
    h.evidence += f"; trial re-fit lowers the residual RMS by {100 * g:.0f} %" + note
