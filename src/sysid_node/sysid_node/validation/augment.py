"""Model structures for validation and their augmentations with one missing physical effect.

The default model is the batch DSRA innovation-form model (Appendix A)
x+ = A x + B u + K e, y = C x + D u + e, identified on the estimation part. Each effect of the
vocabulary changes the structure that is re-fitted (:class:`ModelSpec`):

* ``missing_mode``: two more states (one more mode) and no band restriction;
* ``periodic_disturbance``: additive harmonic regressors cos/sin(k phi(t)), phi = 2 pi int f dt,
  f the measured rotating speed [Hz] (N/rev) or a fixed frequency;
* ``parameter_varying``: local models identified at operating points of a scheduling signal
  theta and interpolated linearly between them, the LPV model (2) of Sec. IV;
* ``input_delay``: the input delayed by d samples;
* ``nonlinear_stiffness``: a cubic stiffness force, the extra input q = yhat_c^3 of one channel,
  yhat the one-step prediction of the model without it (causal and noise-free);
* ``sensor_bias``: offset and drift regressors (bias states with no dynamics);
* ``feedback``: closed-loop-aware joint input-output identification: the reference is
  reconstructed as the part of u not predicted by past y and u (the controller, fitted by least
  squares), and [y; u] is identified from it, an open-loop problem.

Additive regressors Phi are estimated by least squares on the predictor-filtered regressors
F(Phi) = Phi - P(Phi, 0) (P the one-step predictor), i.e. the prediction error is minimised.
Predictions and free-run simulations run over the whole record (the estimation part then
provides the initial state of the validation part).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from ..core.batch import identify
from ..core.inputs import InputError
from ..core.lti import simulate_discrete
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
    order_method: str = "gap"
    band: tuple[float, float] | None = None
    extra_order: int = 0
    delay: int = 0
    bias: bool = False
    drift: bool = True
    harmonics: list[dict] = field(default_factory=list)
    lpv_signal: str | None = None
    lpv_points: int = 3
    cubic_channel: int | None = None
    feedback: bool = False
    feedback_lags: int = 5
    added: list[str] = field(default_factory=list)

    def with_effect(self, effect: str, params: dict) -> ModelSpec:
        """A copy with ``effect`` added, using ``params`` (diagnosed or given by the user)."""
        s = replace(self, harmonics=list(self.harmonics), added=[*self.added, effect])
        p = params
        if effect == "missing_mode":
            s.extra_order += 2 * int(p.get("modes", 1))
            s.band = None
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
        elif effect == "input_delay":
            if "samples" in p:
                s.delay = int(p["samples"])
            elif "delay_s" in p:
                s.delay = int(round(float(p["delay_s"]) * float(p.get("fs", 1.0))))
            else:
                raise ValidationError("input_delay needs samples=N or delay_s=T")
        elif effect == "nonlinear_stiffness":
            s.cubic_channel = int(p.get("channel", 0))
        elif effect == "sensor_bias":
            s.bias = True
            s.drift = str(p.get("drift", True)).lower() not in ("0", "false", "no")
        elif effect == "feedback":
            s.feedback = True
            s.feedback_lags = int(p.get("lags", s.feedback_lags))
        else:
            raise ValidationError(f"unknown effect {effect!r}; one of {', '.join(EFFECTS)}")
        return s


def _shift(u: np.ndarray, d: int) -> np.ndarray:
    if d <= 0:
        return u
    out = np.zeros_like(u)
    out[d:] = u[:-d]
    return out


def rotor_phase(f_hz: np.ndarray, fs: float) -> np.ndarray:
    """phi(t) = 2 pi int f dt (trapezoidal), f the rotating speed [Hz]."""
    f = np.asarray(f_hz, float)
    inc = 0.5 * (f[1:] + f[:-1]) / fs
    return 2 * np.pi * np.concatenate([[0.0], np.cumsum(inc)])


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


def _predictor(model: IdentifiedModel, y: np.ndarray, u: np.ndarray) -> np.ndarray:
    """One-step prediction of an innovation-form model (Kalman predictor)."""
    return model.predict(y, u if model.n_inputs else None)


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


@dataclass
class FittedModel:
    """A fitted structure: base DSRA model, LPV local models or the joint closed-loop model."""

    spec: ModelSpec
    order: int
    model: IdentifiedModel | None = None
    locals: list[tuple[float, IdentifiedModel]] = field(default_factory=list)
    theta: np.ndarray | None = None  # (p, l) regressor coefficients
    controller: np.ndarray | None = None  # least-squares controller (feedback)
    n_outputs: int = 1
    lpv: LpvModel | None = None
    cubic_prior: FittedModel | None = None  # model whose one-step prediction feeds the cubic

    # ---------------------------------------------------------------- input construction
    def inputs(self, data: ValidationData, yc: np.ndarray) -> np.ndarray:
        """Effective model inputs: the (delayed) measured input plus the cubic term."""
        u = _shift(data.u, self.spec.delay)
        if self.spec.cubic_channel is not None:
            # the cubic force at t from the one-step prediction of y_t by the model without it
            # (known before y_t arrives, and free of the measurement noise)
            ch = self.spec.cubic_channel
            prior = self.cubic_prior
            z = prior.predict(data)[:, ch] - prior.additive(data)[:, ch]
            u = np.hstack([u, z[:, None] ** 3])
        return u

    def reference(self, y: np.ndarray, u: np.ndarray) -> np.ndarray:
        """Reconstructed reference r = u - controller(past y, past u) (feedback)."""
        reg = _lagged(np.hstack([y, u]), self.spec.feedback_lags)
        return u - reg @ self.controller

    # ---------------------------------------------------------------- core predictor
    def _core_predict(self, data: ValidationData, yc: np.ndarray, ue: np.ndarray) -> np.ndarray:
        if self.spec.feedback:
            r = self.reference(yc, ue)
            return _predictor(self.model, np.hstack([yc, ue]), r)[:, : self.n_outputs]
        if self.locals:
            return self.lpv.run(data.signals[self.spec.lpv_signal], ue, yc)
        return _predictor(self.model, yc, ue)

    def additive(self, data: ValidationData) -> np.ndarray:
        phi = regressors(self.spec, data)
        if phi is None or self.theta is None:
            return np.zeros((data.n, self.n_outputs))
        return phi @ self.theta

    def predict(self, data: ValidationData) -> np.ndarray:
        """One-step-ahead prediction over the whole record (N, l)."""
        add = self.additive(data)
        yc = data.y - add
        return add + self._core_predict(data, yc, self.inputs(data, yc))

    def simulate(self, data: ValidationData) -> np.ndarray | None:
        """Free-run simulation from the measured input (None for output-only data)."""
        if data.n_inputs == 0:
            return None
        add = self.additive(data)
        if self.spec.feedback:
            r = self.reference(data.y - add, data.u)
            m = self.model
            y, _ = simulate_discrete(m.A, m.B, m.C, m.D, r)
            return add + y[:, : self.n_outputs]
        u = _shift(data.u, self.spec.delay)
        if self.locals:
            return add + self.lpv.run(data.signals[self.spec.lpv_signal], u, None)
        m = self.model
        if self.spec.cubic_channel is None:
            return add + m.simulate(u)
        return add + _simulate_cubic(m, u, self.spec.cubic_channel)

    def residuals(self, data: ValidationData) -> np.ndarray:
        return data.y - self.predict(data)

    # ---------------------------------------------------------------- reporting
    def modes(self) -> list:
        if self.locals:
            return self.locals[len(self.locals) // 2][1].modes
        return self.model.modes if self.model is not None else []

    def cubic_gain(self) -> float:
        """Estimated cubic stiffness term relative to the input path: B_q ~ -k3 B_u."""
        if self.spec.cubic_channel is None or self.model is None or self.model.n_inputs < 2:
            return float("nan")
        b = self.model.B
        bu, bq = b[:, 0], b[:, -1]
        return float(-(bq @ bu) / (bu @ bu))


def _lagged(x: np.ndarray, lags: int) -> np.ndarray:
    """[x_{t-1}, ..., x_{t-lags}] (N, lags * c), zeros before the start."""
    n, c = x.shape
    out = np.zeros((n, lags * c))
    for k in range(1, lags + 1):
        out[k:, (k - 1) * c : k * c] = x[:-k]
    return out


def _simulate_cubic(m: IdentifiedModel, u: np.ndarray, ch: int) -> np.ndarray:
    """Free run of x+ = A x + B [u; y_ch^3], y = C x + D_u u (the cubic input is nonlinear
    feedback of the simulated output, so this recursion runs sample by sample)."""
    n = u.shape[0]
    x = np.zeros(m.order)
    du = m.D[:, : u.shape[1]]
    bu, bq = m.B[:, : u.shape[1]], m.B[:, -1]
    y = np.empty((n, m.n_outputs))
    lim = 1e6
    for k in range(n):
        y[k] = m.C @ x + du @ u[k]
        q = float(np.clip(y[k, ch], -lim, lim)) ** 3
        x = m.A @ x + bu @ u[k] + bq * q
        if not np.all(np.isfinite(x)):
            y[k:] = np.nan
            break
    return y


def _identify(
    spec: ModelSpec, order: int | None, y: np.ndarray, u: np.ndarray, fs: float
) -> IdentifiedModel:
    try:
        return identify(
            y,
            u if u.shape[1] else None,
            fs=fs,
            order=order,
            block_rows=spec.block_rows,
            order_method=spec.order_method,
            band=spec.band,
        )
    except InputError as err:
        raise ValidationError(f"identification failed: {err}") from None
    except (np.linalg.LinAlgError, ValueError) as err:
        raise ValidationError(f"identification failed: {' '.join(str(err).split())}") from None


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


def operating_points(theta: np.ndarray, k: int, min_len: int) -> list[tuple[float, int, int]]:
    """Up to k operating points of the scheduling signal: (value, start, stop) of the longest
    stretch of data near each quantile (the local experiments of Sec. IV)."""
    lo, hi = np.min(theta), np.max(theta)
    tol = 0.5 * (hi - lo) / k if hi > lo else 1.0
    out = []
    for q in (np.arange(k) + 0.5) / k:
        c = float(np.quantile(theta, q))
        a, b = _longest_run(np.abs(theta - c) <= tol)
        if b - a >= min_len and all(abs(c - p) > 1e-9 for p, _, _ in out):
            out.append((float(np.mean(theta[a:b])), a, b))
    out.sort()
    return out


def fit(spec: ModelSpec, data: ValidationData, n_est: int) -> FittedModel:
    """Identify the structure ``spec`` on samples [0, n_est) of ``data``."""
    l = data.n_outputs
    order = None if spec.order is None else spec.order + spec.extra_order
    phi = regressors(spec, data)
    fm = FittedModel(spec, order or 0, n_outputs=l)
    if spec.cubic_channel is not None:
        if not 0 <= spec.cubic_channel < l:
            raise ValidationError(f"nonlinear_stiffness: no output channel {spec.cubic_channel}")
        fm.cubic_prior = fit(replace(spec, cubic_channel=None), data, n_est)
    y = data.y
    if phi is not None:  # first pass: plain least squares on the raw outputs
        fm.theta, *_ = np.linalg.lstsq(phi[:n_est], y[:n_est], rcond=None)
    passes = 2 if phi is not None else 1
    for _ in range(passes):
        yc = y - fm.additive(data)
        ue = fm.inputs(data, yc)
        _fit_core(fm, data, yc, ue, n_est, order)
        if phi is not None:
            _refine_theta(fm, data, phi, yc, ue, n_est)
    return fm


def _fit_core(
    fm: FittedModel,
    data: ValidationData,
    yc: np.ndarray,
    ue: np.ndarray,
    n_est: int,
    order: int | None,
) -> None:
    spec = fm.spec
    if spec.feedback:
        if data.n_inputs == 0:
            raise ValidationError("feedback needs an input topic (closed-loop data)")
        reg = _lagged(np.hstack([yc, ue]), spec.feedback_lags)[:n_est]
        fm.controller, *_ = np.linalg.lstsq(
            reg[spec.feedback_lags :], ue[spec.feedback_lags : n_est], rcond=None
        )
        r = fm.reference(yc, ue)
        joint_order = None if order is None else order + 2
        fm.model = _identify(spec, joint_order, np.hstack([yc, ue])[:n_est], r[:n_est], data.fs)
        fm.order = fm.model.order
        return
    if spec.lpv_signal is not None:
        if spec.lpv_signal not in data.signals:
            raise ValidationError(f"no scheduling signal {spec.lpv_signal} in the data")
        theta = data.signals[spec.lpv_signal][:n_est]
        min_len = 2 * spec.block_rows * (1 + data.n_inputs + data.n_outputs) + 50
        pts = operating_points(theta, spec.lpv_points, min_len)
        if len(pts) < 2:
            raise ValidationError(
                f"parameter_varying: fewer than 2 operating points of {spec.lpv_signal} with "
                f">= {min_len} samples in the estimation part"
            )
        fm.locals = [(p, _identify(spec, order, yc[a:b], ue[a:b], data.fs)) for p, a, b in pts]
        fm.lpv = LpvModel.from_locals(fm.locals)
        fm.order = fm.locals[0][1].order
        return
    m = _identify(spec, order, yc[:n_est], ue[:n_est], data.fs)
    fm.model = m
    fm.order = m.order


def _refine_theta(
    fm: FittedModel,
    data: ValidationData,
    phi: np.ndarray,
    yc: np.ndarray,
    ue: np.ndarray,
    n_est: int,
) -> None:
    """theta += argmin || e - F(Phi) dtheta || on the estimation part, F the innovation filter."""
    l = data.n_outputs
    e = (yc - fm._core_predict(data, yc, ue))[:n_est]
    zero_u = np.zeros_like(ue)
    cols = []
    for j in range(phi.shape[1]):
        for c in range(l):
            x = np.zeros((data.n, l))
            x[:, c] = phi[:, j]
            cols.append((x - fm._core_predict(data, x, zero_u))[:n_est].ravel())
    design = np.column_stack(cols)
    d, *_ = np.linalg.lstsq(design, e.ravel(), rcond=None)
    fm.theta = fm.theta + d.reshape(phi.shape[1], l)
