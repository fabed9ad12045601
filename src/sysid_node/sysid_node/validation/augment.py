"""Model structures for validation and their augmentations with one missing physical effect.

The default model is the batch DSRA innovation-form model (Appendix A)
x+ = A x + B u + K e, y = C x + D u + e, identified on the estimation part. Each effect of the
vocabulary changes the structure that is re-fitted (:class:`ModelSpec`):

* ``missing_mode``: two more states (one more mode) and no band restriction;
* ``periodic_disturbance``: additive harmonic regressors cos/sin(k phi(t)), phi = 2 pi int f dt,
  f the measured rotating speed [Hz] (N/rev) or a fixed frequency;
* ``parameter_varying``: with an input, every mode's frequency affine in a scheduling
  signal theta, its decay rate refitted but constant unless ``decay=moving``
  (:mod:`.lpv_affine`: theta may keep moving); ``form=local``, or output-only data: local
  models identified at operating points of theta and interpolated linearly between them,
  the LPV model (2) of Sec. IV;
* ``input_delay``: the input delayed by d samples (fractional d: linear interpolation between
  samples, a transport delay shorter than the sample period);
* ``nonlinear_stiffness``: a cubic stiffness force q = z^3 on a structural coordinate z: an
  output channel (displacement sensors), or its first or second integral from the model's
  states (velocity or acceleration sensors), z = C_c A_c^-p x, A_c the continuous-time A; the
  force enters as a first-order hold over the sample (q_t and q_t+1), the free run is a
  nonlinear feedback of the simulated state;
* ``sensor_bias``: offset and drift regressors (bias states with no dynamics);
* ``feedback``: closed-loop-aware joint input-output identification: the reference is
  reconstructed as the part of u not predicted by past y and u (the controller, fitted by least
  squares), and [y; u] is identified from it, an open-loop problem.

How each structure is fitted, predicted and simulated: :mod:`.models`.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from ..core.model import IdentifiedModel
from .data import ValidationData, ValidationError

EFFECTS = (
    "missing_mode",
    "periodic_disturbance",
    "parameter_varying",
    "input_delay",
    "nonlinear_stiffness",
    "sensor_bias",
    "feedback",
)


@dataclass
class ModelSpec:
    """What to identify: the base DSRA options plus the added effects."""

    order: int | None = None
    block_rows: int = 20
    focus: str = "free_run"  # fit B, D on the free run ("free_run") or keep (A4) ("one_step")
    reduce_from: int = 0  # realize this higher order and keep its dominant modes (0: no)
    decimate: int = 1  # realize A, C from the record decimated by this factor (1: no)
    order_method: str = "gap"
    band: tuple[float, float] | None = None
    extra_order: int = 0
    #: (frequency [Hz], damping) of each added mode where the evidence gave one: a start of
    #: the re-fit next to the realization's (see models.fit)
    mode_hints: list[tuple[float, float]] = field(default_factory=list)
    delay: float = 0.0  # [samples]
    bias: bool = False
    drift: bool = True
    harmonics: list[dict] = field(default_factory=list)
    lpv_signal: str | None = None
    lpv_points: int = 3
    #: "affine": poles move continuously with the signal (lpv_affine; needs an input);
    #: "local": local models at operating points (Sec. IV); "auto": affine when there is an input
    lpv_form: str = "auto"
    #: the affine form's decay rates follow the signal too (default: frequencies only; a free
    #: damping slope over-fits a lightly damped mode unless the data ask for it)
    lpv_decay: bool = False
    cubic_channel: int | None = None
    cubic_integrals: int = 0  # the spring's coordinate: output (0), its integral (1) or double (2)
    cubic_input: int = 0  # the input the spring force acts with (Duffing: where the input acts)
    #: how the spring's force enters the discrete model: "best" (the "input" or "free" form
    #: with the lower estimation error, see models.fit_simulation) or "input" only
    cubic_force: str = "best"
    feedback: bool = False
    feedback_lags: int = 5
    added: list[str] = field(default_factory=list)

    def with_effect(self, effect: str, params: dict) -> ModelSpec:
        """A copy with ``effect`` added, using ``params`` (diagnosed or given by the user)."""
        s = replace(self, harmonics=list(self.harmonics), added=[*self.added, effect],
                    mode_hints=list(self.mode_hints))
        p = params
        if effect == "missing_mode":
            s.extra_order += 2 * int(p.get("modes", 1))
            s.band = None
            f = float(p.get("frequency_hz") or np.nan)
            if np.isfinite(f) and f > 0 and int(p.get("modes", 1)) == 1:
                z = float(p.get("damping") or np.nan)
                s.mode_hints.append((f, z if np.isfinite(z) else np.nan))
        elif effect == "periodic_disturbance":
            orders = p.get("harmonics", [1, 2, 3])
            if isinstance(orders, str):
                orders = [int(k) for k in orders.replace("/", " ").replace("+", " ").split()]
            src = p.get("source")
            f0 = p.get("frequency_hz")
            if src is None and f0 is None:
                raise ValidationError("periodic_disturbance needs source=TOPIC or frequency_hz=F")
            s.harmonics.append(
                {
                    "source": src,
                    "frequency_hz": None if f0 is None or src else float(f0),
                    "orders": [int(k) for k in orders],
                    "scale": float(p.get("scale", 1.0)),
                }
            )
        elif effect == "parameter_varying":
            if not p.get("signal"):
                raise ValidationError("parameter_varying needs signal=TOPIC")
            s.lpv_signal = str(p["signal"])
            s.lpv_points = int(p.get("points", s.lpv_points))
            s.lpv_form = str(p.get("form", s.lpv_form))
            if s.lpv_form not in ("auto", "affine", "local"):
                raise ValidationError("parameter_varying: form must be auto, affine or local")
            decay = str(p.get("decay", "constant"))
            if decay not in ("constant", "moving"):
                raise ValidationError("parameter_varying: decay must be constant or moving")
            s.lpv_decay = decay == "moving"
        elif effect == "input_delay":
            if "samples" in p:
                s.delay = float(p["samples"])
            elif "delay_s" in p:
                s.delay = float(p["delay_s"]) * float(p.get("fs", 1.0))
            else:
                raise ValidationError("input_delay needs samples=N or delay_s=T")
        elif effect == "nonlinear_stiffness":
            s.cubic_channel = int(p.get("channel", 0))
            s.cubic_integrals = int(p.get("integrals", 0))
            s.cubic_input = int(p.get("input", 0))
            s.cubic_force = str(p.get("force", "best"))
            if s.cubic_integrals not in (0, 1, 2):
                raise ValidationError("nonlinear_stiffness: integrals must be 0, 1 or 2")
            if s.cubic_force not in ("best", "input"):
                raise ValidationError("nonlinear_stiffness: force must be best or input")
        elif effect == "sensor_bias":
            s.bias = True
            s.drift = str(p.get("drift", True)).lower() not in ("0", "false", "no")
        elif effect == "feedback":
            s.feedback = True
            s.feedback_lags = int(p.get("lags", s.feedback_lags))
        else:
            raise ValidationError(f"unknown effect {effect!r}; one of {', '.join(EFFECTS)}")
        return s


def rotor_phase(f_hz: np.ndarray, fs: float) -> np.ndarray:
    """phi(t) = 2 pi int f dt (trapezoidal), f the rotating speed [Hz]."""
    f = np.asarray(f_hz, float)
    inc = 0.5 * (f[1:] + f[:-1]) / fs
    return 2 * np.pi * np.concatenate([[0.0], np.cumsum(inc)])


def rotating_signals(signals: dict[str, np.ndarray], fs: float) -> list[str]:
    """Signals that can be a rotating speed [Hz]: positive, below Nyquist, not too variable."""
    out = []
    for name, s in signals.items():
        m = float(np.mean(s))
        if 0.05 < m < 0.5 * fs and np.all(s > 0) and np.std(s) < 0.5 * m:
            out.append(name)
    return out


def harmonic_regressors(data: ValidationData, h: dict) -> np.ndarray:
    """cos/sin(k phi) columns for one harmonic set (rotor-driven or fixed frequency)."""
    if h.get("source"):
        if h["source"] not in data.signals:
            raise ValidationError(f"no signal {h['source']} in the data for the harmonics")
        phi = rotor_phase(h.get("scale", 1.0) * data.signals[h["source"]], data.fs)
    else:
        phi = 2 * np.pi * float(h["frequency_hz"]) * data.t
    cols = []
    for k in h["orders"]:
        cols += [np.cos(k * phi), np.sin(k * phi)]
    return np.column_stack(cols)


def regressors(spec: ModelSpec, data: ValidationData) -> np.ndarray | None:
    """Additive output regressors Phi (N, p) of the spec, or None."""
    cols = []
    if spec.bias:
        cols.append(np.ones((data.n, 1)))
        if spec.drift:
            cols.append((data.t - data.t.mean())[:, None] / max(np.ptp(data.t), 1e-9))
    for h in spec.harmonics:
        cols.append(harmonic_regressors(data, h))
    return np.hstack(cols) if cols else None


def _lpv_weights(theta: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Linear interpolation weights (N, K) over sorted operating points (clamped outside)."""
    k = points.size
    w = np.zeros((theta.size, k))
    th = np.clip(theta, points[0], points[-1])
    j = np.clip(np.searchsorted(points, th, side="right") - 1, 0, k - 2)
    beta = (th - points[j]) / (points[j + 1] - points[j])
    w[np.arange(th.size), j] = 1 - beta
    w[np.arange(th.size), j + 1] += beta
    return w


def modal_form(m: IdentifiedModel, ref_channel: int) -> tuple[np.ndarray, ...]:
    """(A, B, C, D, K, eigenvalues) in a real modal basis with a unique scaling.

    Complex pairs sorted by frequency then real poles by value; each complex mode's basis is
    [2 Re v, -2 Im v] with (C v)[ref] = 1/2, each real one v with (C v)[ref] = 1, so local
    models identified at different operating points have comparable coordinates (Sec. IV).
    """
    lam, v = np.linalg.eig(m.A)
    cplx = np.flatnonzero(lam.imag > 1e-10)
    real = np.flatnonzero(np.abs(lam.imag) <= 1e-10)
    cplx = cplx[np.argsort(np.abs(np.angle(lam[cplx])))]
    real = real[np.argsort(lam[real].real)]
    cols, eig = [], []
    for i in cplx:
        g = (m.C @ v[:, i])[ref_channel]
        vi = v[:, i] * (0.5 / g) if abs(g) > 1e-12 else v[:, i]
        cols += [2 * vi.real, -2 * vi.imag]
        eig.append(lam[i])
    for i in real:
        g = (m.C @ v[:, i])[ref_channel].real
        cols.append(v[:, i].real / (g if abs(g) > 1e-12 else 1.0))
        eig.append(lam[i])
    t = np.column_stack(cols)
    ti = np.linalg.inv(t)
    return ti @ m.A @ t, ti @ m.B, m.C @ t, m.D, ti @ m.K, np.array(eig)


@dataclass
class LpvModel:
    """Local modal-form models at operating points, interpolated linearly (Sec. IV, Eq. (2)):
    M(theta) = beta M_i + (1 - beta) M_{i+1} for A, B, C, D and K."""

    points: np.ndarray
    A: np.ndarray  # (P, n, n)
    B: np.ndarray
    C: np.ndarray
    D: np.ndarray
    K: np.ndarray
    eigenvalues: np.ndarray  # (P, n)

    @classmethod
    def from_locals(cls, local: list[tuple[float, IdentifiedModel]]) -> LpvModel:
        mid = local[len(local) // 2][1]
        ref = int(np.argmax(np.var(mid.C, axis=1))) if mid.n_outputs > 1 else 0
        forms = [modal_form(m, ref) for _, m in local]
        n_c = [int(np.sum(f[5].imag > 1e-10)) for f in forms]
        if len(set(n_c)) != 1:
            raise ValidationError(
                "parameter_varying: local models differ in their number of modes "
                f"({', '.join(map(str, n_c))}); try another order"
            )
        st = [np.stack([f[j] for f in forms]) for j in range(6)]
        return cls(np.array([p for p, _ in local]), *st)

    def run(self, theta: np.ndarray, u: np.ndarray, y: np.ndarray | None) -> np.ndarray:
        """One-step prediction (y given) or free-run simulation (y None) along theta(t).

        The matrices change with every sample, so the state recursion is sample by sample;
        the interpolated matrices of all samples are formed in one block first.
        """
        w = _lpv_weights(np.asarray(theta, float), self.points)
        a = np.einsum("tk,kij->tij", w, self.A)
        b = np.einsum("tk,kij->tij", w, self.B)
        c = np.einsum("tk,kij->tij", w, self.C)
        d = np.einsum("tk,kij->tij", w, self.D)
        kk = np.einsum("tk,kij->tij", w, self.K)
        n = theta.shape[0]
        x = np.zeros(self.A.shape[1]).astype(float)
        out = np.empty((n, c.shape[1]))
        for t in range(n):
            yt = c[t] @ x + d[t] @ u[t]
            out[t] = yt
            x = a[t] @ x + b[t] @ u[t]
            if y is not None:
                x = x + kk[t] @ (y[t] - yt)
        return out

    def frequencies(self, fs: float) -> np.ndarray:
        """Mode frequencies [Hz] per operating point, (P, modes)."""
        ev = self.eigenvalues
        out = []
        for row in ev:
            z = row[row.imag > 1e-10]
            out.append(np.abs(np.log(z)) * fs / (2 * np.pi))
        return np.array(out)


def _longest_run(mask: np.ndarray) -> tuple[int, int]:
    """(start, stop) of the longest run of True in mask ((0, 0) if none)."""
    if not mask.any():
        return 0, 0
    d = np.diff(np.concatenate([[0], mask.astype(np.int8), [0]]))
    starts, stops = np.flatnonzero(d == 1), np.flatnonzero(d == -1)
    k = int(np.argmax(stops - starts))
    return int(starts[k]), int(stops[k])


def operating_points(
    theta: np.ndarray, k: int, min_len: int, allowed: np.ndarray | None = None
) -> list[tuple[float, int, int]]:
    """Up to k operating points of the scheduling signal: (value, start, stop) of the longest
    stretch of (``allowed``, e.g. estimation) samples near each quantile (the local
    experiments of Sec. IV)."""
    ok = np.ones(theta.size, bool) if allowed is None else allowed
    th = theta[ok]
    lo, hi = np.min(th), np.max(th)
    tol = 0.5 * (hi - lo) / k if hi > lo else 1.0
    out = []
    for q in (np.arange(k) + 0.5) / k:
        c = float(np.quantile(th, q))
        a, b = _longest_run((np.abs(theta - c) <= tol) & ok)
        if b - a >= min_len and all(abs(c - p) > 1e-9 for p, _, _ in out):
            out.append((float(np.mean(theta[a:b])), a, b))
    out.sort()
    return out
