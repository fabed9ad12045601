"""Fitted model structures: the DSRA model (Appendix A) with or without one added effect, its
one-step prediction and its free run (simulation).

Every structure is fitted on the estimation part in two steps:

1. A and C (and the Kalman gain K of the innovation form) from the batch DSRA realization of
   the structure's inputs and outputs (Appendix A, (A2)-(A4));
2. with A and C fixed, B, D, the initial state and the coefficients of additive regressors by
   least squares on the *simulation* error (:mod:`.simulation`) when the data have an input:
   the free run is what the model is compared with the measurement by (``compare``).

A model whose A is unstable (no bounded free run) or whose predictor A - K C is unstable (no
bounded one-step prediction) is flagged: :mod:`.baseline` refits such candidates, never
reports them.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass, field, replace

import numpy as np
from scipy import linalg, signal

from ..core.batch import model_from_projection
from ..core.hankel import Layout, window_rows
from ..core.inputs import InputError, validate_batch
from ..core.lti import simulate_discrete
from ..core.modal import ModalParameters
from ..core.model import IdentifiedModel
from ..core.realization import kalman_gain, project
from .augment import LpvModel, ModelSpec, operating_points, regressors
from .data import ValidationData, ValidationError
from .lpv_affine import AffineModal, fit_affine
from .residuals import lstsq
from .simulation import (
    LinearDynamics,
    OutputErrorFit,
    block_matrix,
    cubic_coordinate,
    fit_output_error,
    integrate,
    next_sample,
    real_modal_basis,
    refine_poles,
    simulate_cubic,
    simulate_linear,
    spectral_radius,
    spring_inputs,
)
from .split import Split

#: The schedule name that stands for time itself (the placebo of the parameter_varying gate).
TIME_SIGNAL = "(time)"

#: Residual evaluations of each output-error refinement of the poles.
REFINE_EVALUATIONS = 30
#: Refine the poles of linear structures by output error too (the subspace poles minimise a
#: one-step criterion; a mode between the lines of a multisine can sit off by its bandwidth).
REFINE_LINEAR = True
#: A segment is decimated by k only when it holds this many samples per k: the anti-alias
#: filter's impulse response holds 99.9 % of its energy within ~16 k samples, so filtered
#: forward and backward its start-up reaches at most a quarter of such a segment (the short
#: blocks of an interleaved split are realized at the full rate only).
DECIMATION_MIN_SAMPLES = 128


def _shift_int(u: np.ndarray, d: int) -> np.ndarray:
    if d <= 0:
        return u
    out = np.zeros_like(u)
    if d < u.shape[0]:
        out[d:] = u[:-d]
    return out


def shift(u: np.ndarray, d: float) -> np.ndarray:
    """u delayed by d samples (zeros first); a fractional d interpolates linearly between
    samples (u_t-d = (1 - a) u_t-k + a u_t-k-1, k = floor d, a = d - k)."""
    if d <= 0:
        return u
    k = int(np.floor(d))
    a = float(d - k)
    if a < 1e-9:
        return _shift_int(u, k)
    return (1.0 - a) * _shift_int(u, k) + a * _shift_int(u, k + 1)


def lagged(x: np.ndarray, lags: int) -> np.ndarray:
    """[x_{t-1}, ..., x_{t-lags}] (N, lags * c), zeros before the start."""
    n, c = x.shape
    out = np.zeros((n, lags * c))
    for k in range(1, lags + 1):
        out[k:, (k - 1) * c : k * c] = x[:-k]
    return out


@dataclass
class DataProjection:
    """Steps 1-2 of Appendix A on channel-scaled data: realizations of any order from it."""

    proj: object
    su: np.ndarray
    sy: np.ndarray
    fs: float
    block_rows: int

    @property
    def max_order(self) -> int:
        return self.proj.layout.l * (self.proj.layout.i - 1)

    def model(self, order: int) -> IdentifiedModel:
        """The order-``order`` innovation-form model (A4) with its Riccati Kalman gain."""
        if not 1 <= order <= self.max_order:
            raise ValidationError(
                f"order {order} is not realizable with block_rows={self.block_rows} "
                f"(at most {self.max_order})"
            )
        return model_from_projection(
            self.proj, order, self.fs, self.su, self.sy, None, (0.0, 1.0), None
        )


def data_projection(
    y: np.ndarray,
    u: np.ndarray,
    fs: float,
    block_rows: int,
    segments: list[tuple[int, int]] | None = None,
) -> DataProjection:
    """QR of the stacked windows (A1) of unit-variance channels and the projection (A2); with
    ``segments`` only windows inside each [a, b) (an interleaved estimation part)."""
    segs = segments or [(0, y.shape[0])]
    segs = [(a, b) for a, b in segs if b - a >= 2 * block_rows + 1]
    idx = np.concatenate([np.arange(a, b) for a, b in segs]) if segs else np.zeros(0, int)
    try:
        if block_rows < 2:
            raise InputError("block_rows must be >= 2")
        if not segs:
            raise InputError(f"no estimation segment holds 2 x {block_rows} + 1 samples")
        validate_batch(y[idx], u[idx] if u.shape[1] else None, block_rows)
    except InputError as err:
        raise ValidationError(f"identification failed: {err}") from None
    su, sy = np.std(u[idx], axis=0), np.std(y[idx], axis=0)
    z = np.vstack([window_rows(u[a:b] / su, y[a:b] / sy, block_rows) for a, b in segs])
    r_fac = linalg.qr(z, mode="r", check_finite=False)[0]
    lay = Layout(block_rows, u.shape[1], y.shape[1])
    proj = project(np.ascontiguousarray(r_fac[: lay.dim].T), lay, z.shape[0], z.shape[0])
    return DataProjection(proj, su, sy, fs, block_rows)


@dataclass
class DecimatedProjection:
    """A :class:`DataProjection` of the record decimated by ``factor``: its realizations are
    returned at the full rate (poles z -> z^(1/factor), see :func:`to_full_rate`)."""

    inner: DataProjection
    factor: int
    fs: float  # the full rate [Hz]

    @property
    def max_order(self) -> int:
        return self.inner.max_order

    @property
    def block_rows(self) -> int:
        return self.inner.block_rows

    def model(self, order: int) -> IdentifiedModel:
        """The order-``order`` model at the full rate; B and D are zero (fit them by output
        error at the full rate, :func:`.simulation.fit_output_error`)."""
        return to_full_rate(self.inner.model(order), self.factor, self.fs)


def decimate_segments(
    x: np.ndarray, factor: int, segments: list[tuple[int, int]]
) -> tuple[np.ndarray, list[tuple[int, int]]]:
    """Each segment of ``x`` low-pass filtered (zero phase, Chebyshev I of order 8 at 0.8 of
    the new Nyquist, :func:`scipy.signal.decimate`) and decimated by ``factor``, separately:
    no held-out sample leaks into a segment through the filter. Returns the concatenated
    pieces and their segments in that array (segments too short to filter are dropped)."""
    pieces, segs, start = [], [], 0
    for a, b in segments:
        if b - a < DECIMATION_MIN_SAMPLES * factor:
            continue
        z = signal.decimate(x[a:b], factor, axis=0, zero_phase=True)
        pieces.append(z)
        segs.append((start, start + z.shape[0]))
        start += z.shape[0]
    if not pieces:
        raise ValidationError(f"no estimation segment long enough to decimate by {factor}")
    return np.concatenate(pieces), segs


def decimated_projection(
    y: np.ndarray,
    u: np.ndarray,
    fs: float,
    factor: int,
    block_rows: int,
    segments: list[tuple[int, int]] | None = None,
) -> DataProjection | DecimatedProjection:
    """:func:`data_projection` of ``segments`` decimated by ``factor`` (1: the record itself):
    a Hankel window of ``block_rows`` spans ``factor`` times as long, and the noise above the
    band (white input measurement noise, errors in variables) is filtered out."""
    if factor <= 1:
        return data_projection(y, u, fs, block_rows, segments)
    segs = segments or [(0, y.shape[0])]
    yd, dsegs = decimate_segments(y, factor, segs)
    ud = decimate_segments(u, factor, segs)[0] if u.shape[1] else np.zeros((yd.shape[0], 0))
    return DecimatedProjection(data_projection(yd, ud, fs / factor, block_rows, dsegs), factor, fs)


def to_full_rate(m: IdentifiedModel, factor: int, fs: float) -> IdentifiedModel:
    """A model realized at ``fs / factor`` mapped to ``fs``: A in its real modal form with each
    pole z -> z^(1/factor) (principal branch: right for a band below the decimated Nyquist;
    a negative real pole keeps its decay, |z|^(1/factor)), C in the same basis, the noise
    covariances per sample (process Q / factor, measurement R x factor: white noise of the
    same density) and their Kalman gain; B and D zero."""
    t, eig, kinds = real_modal_basis(m.A)
    mapped = np.where(
        np.abs(eig.imag) > 0, np.exp(np.log(eig.astype(complex)) / factor),
        np.abs(eig) ** (1.0 / factor),
    )
    a, c = block_matrix(mapped, kinds), m.C @ t
    ti = np.linalg.inv(t)
    q, s, r = ti @ m.Q @ ti.T / factor, ti @ m.S, m.R * factor
    k, re = kalman_gain(a, c, q, s, r)
    return replace(
        m, A=a, B=np.zeros_like(m.B), C=c, D=np.zeros_like(m.D), K=k, Q=q, S=s, R=r,
        innovation_covariance=re, fs=fs, modes=modes_of(a, fs),
    )


def identify_dsra(
    y: np.ndarray,
    u: np.ndarray,
    fs: float,
    order: int,
    block_rows: int,
    segments: list[tuple[int, int]] | None = None,
    decimate: int = 1,
    projection: DataProjection | DecimatedProjection | None = None,
) -> IdentifiedModel:
    """Batch DSRA of a fixed order on ``segments`` of the record (ValidationError with a
    one-line reason on failure); ``decimate`` > 1: realized from the segments decimated by it
    and mapped to the full rate (:func:`to_full_rate`; B, D zero). ``projection``: that of
    these arguments (:func:`dsra_projection`) when the caller has it already."""
    try:
        if projection is None:
            projection = decimated_projection(y, u, fs, decimate, block_rows, segments)
        return projection.model(order)
    except (np.linalg.LinAlgError, ValueError) as err:
        raise _identification_failed(err) from None


def dsra_projection(
    y: np.ndarray, u: np.ndarray, fs: float, spec: ModelSpec, split: Split
) -> DataProjection | DecimatedProjection:
    """The data projection :func:`realize` realizes ``spec``'s dynamics from (its horizon and
    decimation, the estimation segments; ValidationError on failure): one QR of the stacked
    windows serves realizations of any order, direct or reduced."""
    try:
        return decimated_projection(
            y, u, fs, spec.decimate, spec.block_rows, split.est_segments
        )
    except (np.linalg.LinAlgError, ValueError) as err:
        raise _identification_failed(err) from None


def _identification_failed(err: Exception) -> ValidationError:
    """A numerical failure of the DSRA as the one-line ValidationError the CLI prints."""
    if isinstance(err, ValidationError):
        return err
    return ValidationError(f"identification failed: {' '.join(str(err).split())}")


@dataclass
class FittedModel:
    """A fitted structure: base DSRA model, LPV local models or the joint closed-loop model."""

    spec: ModelSpec
    order: int
    model: IdentifiedModel | None = None
    x0: np.ndarray | None = None  # free-run initial state at sample 0
    locals: list[tuple[float, IdentifiedModel]] = field(default_factory=list)
    theta: np.ndarray | None = None  # (p, l) additive regressor coefficients
    controller: np.ndarray | None = None  # least-squares controller (feedback)
    n_outputs: int = 1
    lpv: LpvModel | None = None
    affine: AffineModal | None = None  # parameter_varying, continuous schedule (lpv_affine)
    cubic_prior: FittedModel | None = None  # model whose one-step prediction feeds the cubic
    cubic_c: np.ndarray | None = None  # row c_z of the spring's coordinate z = c_z x
    cubic_scale: float = 1.0  # RMS of the spring coordinate on the data (q = (z / scale)^3)
    cubic_form: str = ""  # "input" (the force acts like input cubic_input) or "free"
    simulation_fit: bool = False  # B, D (and theta) from the simulation error
    _dyn: LinearDynamics | None = field(default=None, repr=False)

    # ---------------------------------------------------------------- stability
    @property
    def free_run_radius(self) -> float:
        """Spectral radius of the free-run dynamics (the plant's A; < 1: bounded free run)."""
        if self.locals:
            return float(max(spectral_radius(m.A) for _, m in self.locals))
        if self.affine is not None:
            return self.affine.radius
        if self.spec.feedback and self.model is not None:
            return spectral_radius(self.plant()[0])
        return spectral_radius(self.model.A) if self.model is not None else np.inf

    @property
    def predictor_radius(self) -> float:
        """Spectral radius of the one-step predictor A - K C (< 1: bounded prediction)."""
        if self.affine is not None:  # free run plus an AR (FIR in past errors) correction
            return self.affine.radius
        ms = [m for _, m in self.locals] if self.locals else [self.model]
        return float(max(spectral_radius(m.A - m.K @ m.C) for m in ms))

    def stable(self, free_run: bool) -> bool:
        ok = self.predictor_radius < 1.0
        return ok and (self.free_run_radius < 1.0 if free_run else True)

    # ---------------------------------------------------------------- inputs
    def one_step_inputs(self, data: ValidationData) -> np.ndarray:
        """Model inputs for the one-step predictor: the (delayed) measured input."""
        return shift(data.u, self.spec.delay)

    def spring_force(self, data: ValidationData) -> np.ndarray:
        """q_t = z_t^3 for the one-step predictor: the spring coordinate from the prior (linear)
        model's predicted states (known before y_t arrives, free of the measurement noise)."""
        sp = self.spec
        z = coordinate_prediction(self.cubic_prior, data, sp.cubic_channel, sp.cubic_integrals)
        return (z[:-1] / self.cubic_scale) ** 3

    def structural_prediction(self, data: ValidationData) -> np.ndarray:
        return self.predict(data) - self.additive(data)

    def reference(self, y: np.ndarray, u: np.ndarray) -> np.ndarray:
        """Reconstructed reference r = u - controller(past y, past u) (feedback)."""
        return u - lagged(np.hstack([y, u]), self.spec.feedback_lags) @ self.controller

    def plant(self) -> tuple[np.ndarray, ...]:
        """Open-loop plant u -> y of the joint closed-loop model r -> [y; u]: the reference
        r = Du^-1 (u - Cu x) substituted into the joint state equation (its free run uses the
        measured input only, never the measured output)."""
        m, l = self.model, self.n_outputs
        cy, cu = m.C[:l], m.C[l:]
        dy, du = m.D[:l], m.D[l:]
        dui = np.linalg.pinv(du)
        return m.A - m.B @ dui @ cu, m.B @ dui, cy - dy @ dui @ cu, dy @ dui

    # ---------------------------------------------------------------- prediction
    def additive(self, data: ValidationData) -> np.ndarray:
        phi = regressors(self.spec, data)
        if phi is None or self.theta is None:
            return np.zeros((data.n, self.n_outputs))
        return phi @ self.theta

    def schedule(self, data: ValidationData) -> np.ndarray:
        """The scheduling signal on the samples (time for :data:`TIME_SIGNAL`)."""
        name = self.spec.lpv_signal
        return data.t if name == TIME_SIGNAL else data.signals[name]

    def _core_predict(self, data: ValidationData, yc: np.ndarray, ue: np.ndarray) -> np.ndarray:
        if self.affine is not None:
            return self.affine.predict(self.schedule(data), ue, yc)
        if self.spec.feedback:
            r = self.reference(yc, ue)
            return _predictor(self.model, np.hstack([yc, ue]), r)[:, : self.n_outputs]
        if self.locals:
            return self.lpv.run(data.signals[self.spec.lpv_signal], ue, yc)
        if self.spec.cubic_channel is not None:
            v, w = spring_inputs(ue, self.spring_force(data))
            m = self.model
            b = np.hstack([m.B, -m.K @ m.D, m.K])
            d = np.hstack([np.zeros_like(m.D), m.D, np.zeros((m.n_outputs, m.n_outputs))])
            y, _ = simulate_discrete(m.A - m.K @ m.C, b, m.C, d, np.hstack([v, w, yc]))
            return y
        return _predictor(self.model, yc, ue)

    def predict(self, data: ValidationData) -> np.ndarray:
        """One-step-ahead prediction over the whole record (N, l)."""
        add = self.additive(data)
        yc = data.y - add
        return add + self._core_predict(data, yc, self.one_step_inputs(data))

    def simulate(self, data: ValidationData) -> np.ndarray | None:
        """Free run from the measured input over the whole record (None for output-only data).

        The estimation part gives the state at the start of the validation part: no measured
        output is used after the first sample (x0 is estimated on the estimation part). A
        closed-loop structure runs the plant of its joint model (:meth:`plant`) from the
        measured input: the reconstructed reference would carry the measured output.
        """
        if data.n_inputs == 0:
            return None
        add = self.additive(data)
        u = shift(data.u, self.spec.delay)
        if not self.free_run_radius < 1.0:
            return np.full_like(data.y, np.nan)  # no bounded free run
        with np.errstate(all="ignore"):
            if self.spec.feedback:  # the plant of the joint model, from the measured input
                a, b, c, d = self.plant()
                if spectral_radius(a) >= 1.0:
                    return np.full_like(data.y, np.nan)
                y, _ = simulate_discrete(a, b, c, d, u)
            elif self.locals:
                y = self.lpv.run(data.signals[self.spec.lpv_signal], u, None)
            elif self.affine is not None:
                y = self.affine.simulate(self.schedule(data), u)
            else:
                m = self.model
                if self.spec.cubic_channel is None:
                    y = simulate_linear(self.dynamics(data.n), m.B, m.D, u, self.x0)
                else:
                    dyn = LinearDynamics.build(m.A, np.vstack([m.C, self.cubic_c]), data.n)
                    y, _ = simulate_cubic(dyn, m.B, m.D, u, self.x0)
        return add + y

    def dynamics(self, n_samples: int) -> LinearDynamics:
        """(A, C) with their Markov kernel for records of up to ``n_samples`` (cached)."""
        if self._dyn is None or self._dyn.kernel.shape[0] < min(
            n_samples, _kernel_need(self.model.A)
        ):
            self._dyn = LinearDynamics.build(self.model.A, self.model.C, n_samples)
        return self._dyn

    # ---------------------------------------------------------------- reporting
    def modes(self) -> list:
        if self.locals:
            return self.locals[len(self.locals) // 2][1].modes
        return self.model.modes if self.model is not None else []

    def cubic_gain(self) -> float:
        """Cubic stiffness k3 relative to input ``cubic_input``: b_q ~ -k3 B_j (z in the
        coordinate's units; > 0: hardening)."""
        if self.spec.cubic_channel is None or self.model is None:
            return float("nan")
        bj, bq = self.model.B[:, self.spec.cubic_input], self.model.B[:, -1]
        return float(-(bq @ bj) / max(bj @ bj, 1e-300)) / self.cubic_scale**3


def predicted_states(fm: FittedModel, data: ValidationData) -> np.ndarray:
    """One-step predicted states x_t|t-1 of a linear structure, t = 0..N, (N + 1, n)."""
    m = fm.model
    yc = data.y - fm.additive(data)
    ak = m.A - m.K @ m.C
    bk = np.hstack([m.B - m.K @ m.D, m.K])
    n = m.order
    xs, x_end = simulate_discrete(
        ak, bk, np.eye(n), np.zeros((n, bk.shape[1])), np.hstack([fm.one_step_inputs(data), yc])
    )
    return np.vstack([xs, x_end])


def coordinate_prediction(
    fm: FittedModel, data: ValidationData, channel: int, integrals: int
) -> np.ndarray:
    """A spring coordinate z = C_c A_c^-p x from the predicted states of ``fm``, (N + 1,)."""
    row = cubic_coordinate(fm.model.A, fm.model.C[channel], data.fs, integrals)
    return predicted_states(fm, data) @ row


def measured_spring_force(fm: FittedModel, data: ValidationData) -> np.ndarray:
    """q = z^3 with z the spring coordinate from the measurement: the output channel, or its
    integral(s) below the prior model's lowest mode / 2 (for fitting: the measured motion is
    what the spring feels; the one-step predictor uses :meth:`FittedModel.spring_force`)."""
    sp = fm.spec
    prior = fm.cubic_prior
    yc = data.y - prior.additive(data)
    freqs = [md.frequency_hz for md in prior.modes()] or [data.fs / data.n]
    z = integrate(yc[:, sp.cubic_channel], data.fs, sp.cubic_integrals, 0.5 * min(freqs))
    fm.cubic_scale = max(float(np.std(z)), 1e-300)  # q in units of the coordinate's RMS
    return (z / fm.cubic_scale) ** 3


def _kernel_need(a: np.ndarray) -> int:
    rho = spectral_radius(a)
    if rho >= 1.0:
        return 1 << 62
    return int(np.ceil(np.log(1e-13) / np.log(max(rho, 1e-300)))) + 1


def _predictor(model: IdentifiedModel, y: np.ndarray, u: np.ndarray) -> np.ndarray:
    """One-step prediction of an innovation-form model (Kalman predictor)."""
    return model.predict(y, u if model.n_inputs else None)


# -------------------------------------------------------------------- fitting
def is_plain(fm: FittedModel | None) -> bool:
    """A single linear DSRA model (no LPV, closed-loop or cubic structure)."""
    sp = fm.spec if fm is not None else None
    return (
        fm is not None
        and fm.model is not None
        and not fm.locals
        and fm.affine is None
        and not sp.feedback
        and sp.cubic_channel is None
    )


def fit(
    spec: ModelSpec, data: ValidationData, split: Split, like: FittedModel | None = None
) -> FittedModel:
    """Identify the structure ``spec`` on the estimation samples of ``data``.

    ``like``: a fitted plain model; a cubic structure of the same order and delay uses it as
    its linear prior. (Every other structure identifies its dynamics again: a baseline fitted
    without a bias or a line may have bent a pole to imitate it.)
    """
    l = data.n_outputs
    if spec.order is None:
        raise ValidationError("internal: fit() needs an order (see baseline.select_baseline)")
    order = spec.order + spec.extra_order
    if spec.lpv_signal is not None and data.n_inputs and spec.lpv_form != "local":
        return _fit_affine(spec, data, split, like)
    phi = regressors(spec, data)
    fm = FittedModel(spec, order, n_outputs=l)
    if spec.cubic_channel is not None:
        if not 0 <= spec.cubic_channel < l:
            raise ValidationError(f"nonlinear_stiffness: no output channel {spec.cubic_channel}")
        if not 0 <= spec.cubic_input < data.n_inputs:
            raise ValidationError("nonlinear_stiffness needs an input (the spring acts with it)")
        linear = replace(spec, cubic_channel=None)
        same = is_plain(like) and like.spec.delay == spec.delay and like.order == order
        fm.cubic_prior = like if same else fit(linear, data, split)
    if phi is not None:  # first pass: plain least squares on the raw outputs
        fm.theta = lstsq(phi[split.est], data.y[split.est])
    yc = data.y - fm.additive(data)
    ue = fm.one_step_inputs(data)
    _fit_core(fm, data, yc, ue, split, order)
    if data.n_inputs and spec.focus == "free_run" and not spec.feedback and not fm.locals:
        fit_simulation(fm, data, phi, split)
        alt = _hinted(fm, like, data)
        if alt is not None:
            fit_simulation(alt, data, phi, split)
            if estimation_cost(alt, data, split) < estimation_cost(fm, data, split):
                return alt
    elif phi is not None:
        _refine_theta(fm, data, phi, yc, ue, split)
    return fm


#: Damping of an added mode whose evidence gives none (a coherence peak), and the range a
#: residual peak's half-power estimate is kept in.
HINT_DAMPING = 0.02
HINT_DAMPING_RANGE = (0.002, 0.2)


def _hinted(fm: FittedModel, like: FittedModel | None, data: ValidationData):
    """The missing-mode structure started from the current model's poles plus one pole pair
    at each evidence frequency (``spec.mode_hints``), for the output-error refinement: a
    realization of order n + 2 can spend the two states elsewhere (noise, a real pole pair)
    and never try the mode the residual shows. None when there is nothing to start from."""
    sp = fm.spec
    if not sp.mode_hints or not is_plain(like) or like.spec.delay != sp.delay:
        return None
    m = like.model
    if m.order + 2 * len(sp.mode_hints) != fm.order or spectral_radius(m.A) >= 1.0:
        return None
    a, c = m.A, m.C
    shape = np.maximum(np.std(data.y, axis=0), 1e-12)[:, None] * np.array([[1.0, 0.0]])
    for f, z in sp.mode_hints:
        z = HINT_DAMPING if not np.isfinite(z) else float(np.clip(z, *HINT_DAMPING_RANGE))
        p = discrete_pole(min(f, 0.45 * data.fs), z, data.fs)
        blk = np.array([[p.real, p.imag], [-p.imag, p.real]])
        a = np.block([[a, np.zeros((a.shape[0], 2))], [np.zeros((2, a.shape[0])), blk]])
        c = np.hstack([c, shape])
    n, k = a.shape[0], m.order
    q = np.zeros((n, n))
    q[:k, :k] = m.Q
    q[k:, k:] = np.eye(n - k) * max(float(np.trace(m.Q)) / max(k, 1), 1e-12)
    s_ = np.vstack([m.S, np.zeros((n - k, m.S.shape[1]))])
    b = np.vstack([m.B, np.zeros((n - k, m.B.shape[1]))])
    alt = FittedModel(sp, fm.order, n_outputs=fm.n_outputs)
    alt.theta = None if fm.theta is None else fm.theta.copy()
    alt.model = _to_basis(replace(m, A=a, C=c, B=b, Q=q, S=s_, order=n), a, c, np.eye(n))
    return alt


def estimation_cost(fm: FittedModel, data: ValidationData, split: Split) -> float:
    """Mean square free-run error on the estimation samples, channels scaled by their
    variance (inf when the free run is unbounded)."""
    ys = fm.simulate(data)
    if ys is None:
        return np.inf
    e = (data.y - ys)[split.est] / np.maximum(np.std(data.y[split.est], axis=0), 1e-300)
    return float(np.mean(e**2)) if np.all(np.isfinite(e)) else np.inf


def _fit_core(
    fm: FittedModel,
    data: ValidationData,
    yc: np.ndarray,
    ue: np.ndarray,
    split: Split,
    order: int,
) -> None:
    spec = fm.spec
    br = spec.block_rows
    segs = split.est_segments
    if spec.feedback:
        if data.n_inputs == 0:
            raise ValidationError("feedback needs an input topic (closed-loop data)")
        lags = spec.feedback_lags
        rows = split.est[split.est >= lags]
        fm.controller = lstsq(lagged(np.hstack([yc, ue]), lags)[rows], ue[rows])
        r = fm.reference(yc, ue)
        joint = np.hstack([yc, ue])
        m = identify_dsra(joint, r, data.fs, order + 2 * data.n_inputs, br, segs)
        # the closed loop's free run from the reference: poles and B, D by output error
        a, c, t, _ = refine_poles(
            m.A, m.C, joint, split.est, lambda _: (r, r), np.zeros(0), None, REFINE_EVALUATIONS
        )
        m = _to_basis(m, a, c, t)
        oe = fit_output_error(LinearDynamics.build(a, c, data.n), joint, r, split.est)
        fm.model, fm.x0 = replace(m, B=oe.B, D=oe.D), oe.x0
        fm.order = fm.model.order
        return
    if spec.lpv_signal is not None:
        _fit_lpv(fm, data, yc, ue, split, order)
        return
    if spec.cubic_channel is not None:  # initial A, C and stiffness: DSRA with q as an input
        q = measured_spring_force(fm, data)[:, None]
        fm.model = identify_dsra(yc, np.hstack([ue, q]), data.fs, order, br, segs)
        m = fm.model
        row = cubic_coordinate(m.A, m.C[spec.cubic_channel], data.fs, spec.cubic_integrals)
        fm.cubic_c = row / fm.cubic_scale
    else:
        fm.model = realize(yc, ue, data.fs, order, spec, split)
    fm.order = fm.model.order


def realize(
    y: np.ndarray,
    u: np.ndarray,
    fs: float,
    order: int,
    spec: ModelSpec,
    split: Split,
    projection: DataProjection | DecimatedProjection | None = None,
) -> IdentifiedModel:
    """The linear dynamics of ``spec`` on the estimation segments: directly at ``order`` or
    (``spec.reduce_from``, with an input) the dominant modes of a higher-order realization;
    from the record decimated by ``spec.decimate``, B and D then by output error at the full
    rate. ``projection``: :func:`dsra_projection` of these arguments, when the caller has it."""
    segs, br, k = split.est_segments, spec.block_rows, spec.decimate
    if spec.reduce_from > order and u.shape[1]:
        big = identify_dsra(y, u, fs, spec.reduce_from, br, segs, k, projection)
        return dominant_modes(big, y, u, split.est, order)
    m = identify_dsra(y, u, fs, order, br, segs, k, projection)
    if k > 1 and u.shape[1] and spectral_radius(m.A) < 1.0:
        oe = fit_output_error(LinearDynamics.build(m.A, m.C, y.shape[0]), y, u, split.est)
        m = replace(m, B=oe.B, D=oe.D)
    return m


def _bare(spec: ModelSpec) -> ModelSpec:
    return replace(spec, lpv_signal=None, lpv_form="auto", lpv_points=3, lpv_decay=False,
                   added=[])


def _fit_affine(
    spec: ModelSpec, data: ValidationData, split: Split, like: FittedModel | None
) -> FittedModel:
    """parameter_varying with a continuous schedule: the structure without it is fitted first
    (its poles refined on the free run; ``like`` when it is that structure already), then every
    complex pole's frequency (and with ``spec.lpv_decay`` its decay rate) is made affine in
    the signal and refined on the estimation samples' free run (:func:`.lpv_affine.fit_affine`)."""
    if spec.lpv_signal not in data.signals and spec.lpv_signal != TIME_SIGNAL:
        raise ValidationError(f"no scheduling signal {spec.lpv_signal} in the data")
    same = is_plain(like) and _bare(like.spec) == _bare(spec)
    base = like if same else fit(replace(spec, lpv_signal=None), data, split)
    m = base.model
    if m is None or spectral_radius(m.A) >= 1.0:
        raise ValidationError("parameter_varying: the structure without it has no bounded free run")
    phi = regressors(spec, data)
    fm = FittedModel(spec, base.order, model=m, n_outputs=data.n_outputs)
    u = shift(data.u, spec.delay)
    fm.affine, fm.theta = fit_affine(m.A, fm.schedule(data), u, data.y, split.est, data.fs, phi,
                                     decay_slope=spec.lpv_decay)
    fm.simulation_fit = True
    return fm


def _fit_lpv(
    fm: FittedModel, data: ValidationData, yc: np.ndarray, ue: np.ndarray, split: Split, order: int
) -> None:
    """Local models at operating points of the scheduling signal (Sec. IV), each with its poles
    refined and B, D solved on its own segment's simulation error, interpolated in modal
    coordinates (Eq. (2))."""
    spec = fm.spec
    if spec.lpv_signal not in data.signals:
        raise ValidationError(f"no scheduling signal {spec.lpv_signal} in the data")
    theta = data.signals[spec.lpv_signal]
    min_len = 2 * spec.block_rows * (1 + data.n_inputs + data.n_outputs) + 50
    pts = operating_points(theta, spec.lpv_points, min_len, split.est_mask)
    if len(pts) < 2:
        raise ValidationError(
            f"parameter_varying: fewer than 2 operating points of {spec.lpv_signal} with "
            f">= {min_len} samples in the estimation part"
        )
    local = []
    for p, a, b in pts:
        m = identify_dsra(yc[a:b], ue[a:b], data.fs, order, spec.block_rows)
        if data.n_inputs:  # poles, B, D on the segment's free run (a short segment's
            rows = np.arange(b - a)  # subspace poles can sit outside the unit circle)
            y_s, u_s = yc[a:b], ue[a:b]
            ar, cr, t, _ = refine_poles(
                m.A, m.C, y_s, rows, lambda _, v=u_s: (v, v), np.zeros(0), None, REFINE_EVALUATIONS
            )
            m = _to_basis(m, ar, cr, t)
            oe = fit_output_error(LinearDynamics.build(ar, cr, b - a), y_s, u_s, rows)
            m = replace(m, B=oe.B, D=oe.D)
        local.append((p, m))
    fm.locals = local
    fm.lpv = LpvModel.from_locals(local)
    fm.order = local[0][1].order


def fit_simulation(
    fm: FittedModel,
    data: ValidationData,
    phi: np.ndarray | None,
    split: Split,
    refine: bool = True,
) -> None:
    """B, D, x0 (and theta) by least squares on the free-run error, A and C fixed
    (:mod:`.simulation`). With a cubic spring, its stiffness and the poles are refined by output
    error (variable projection), the force from the prior model's predicted states."""
    m = fm.model
    rows = split.est
    u = shift(data.u, fm.spec.delay)
    sp = fm.spec
    if sp.cubic_channel is None:
        if spectral_radius(m.A) >= 1.0:
            return  # no bounded free run: keep the (A4) B, D; baseline selection refits it
        if REFINE_LINEAR and refine:
            a, c, t, _ = refine_poles(
                m.A, m.C, data.y, rows, lambda _: (u, u), np.zeros(0), phi, REFINE_EVALUATIONS
            )
            m = _to_basis(m, a, c, t)
            fm._dyn = None
        fm.model = m
        oe = fit_output_error(fm.dynamics(data.n), data.y, u, rows, additive=phi)
        fm.model = replace(m, B=oe.B, D=oe.D)
        fm.x0, fm.theta = oe.x0, oe.theta
        fm.simulation_fit = True
        return
    q = measured_spring_force(fm, data)
    j = sp.cubic_input
    best = None
    forms = ("input",) if sp.cubic_force == "input" else ("input", "free")
    for m0, form in itertools.product(_spring_starts(fm, m), forms):
        a, c, t, x, v, w = _refine_spring(m0, data, u, q, j, rows, phi, form)
        m = _to_basis(m0, a, c, t)
        oe = fit_output_error(LinearDynamics.build(a, c, data.n), data.y, v, rows, phi, w)
        b_all, d_all = oe.B, oe.D
        if form == "input":  # the force acts where input j acts: b_q = -k B_j, d_q = -k D_j
            b_all = np.column_stack([oe.B, -x * oe.B[:, j]])
            d_all = np.column_stack([oe.D, -x * oe.D[:, j]])
        row = cubic_coordinate(a, c[sp.cubic_channel], data.fs, sp.cubic_integrals)
        cz = row / fm.cubic_scale
        dyn = LinearDynamics.build(a, np.vstack([c, cz]), data.n)
        with np.errstate(all="ignore"):
            ys, _ = simulate_cubic(dyn, b_all, d_all, u, oe.x0)
        add = 0.0 if phi is None or oe.theta is None else phi @ oe.theta
        err = (data.y - ys - add)[rows]
        cost = float(np.mean(err**2)) if np.all(np.isfinite(err)) else np.inf
        if best is None or cost < best[0]:
            best = (cost, replace(m, B=b_all, D=d_all), oe.x0, oe.theta, cz, form)
    _, fm.model, fm.x0, fm.theta, fm.cubic_c, fm.cubic_form = best
    fm._dyn = None
    fm.simulation_fit = True


def _spring_starts(fm: FittedModel, m: IdentifiedModel) -> list[IdentifiedModel]:
    """Starting dynamics of the spring's refinement: the realization with the measured force
    as an input (``m``) and, when that realization has fewer oscillatory modes than the
    linear prior (it traded one of the structure's modes for the force's own spectrum), the
    prior's stable poles too. The refinement keeps the start that fits the estimation samples
    best."""
    out = [m]
    prior = fm.cubic_prior.model if fm.cubic_prior is not None else None
    if (
        prior is not None
        and prior.order == m.order
        and spectral_radius(prior.A) < 1.0
        and prior.B.shape[1] + 1 == m.B.shape[1]
        and len(modes_of(m.A, m.fs)) < len(modes_of(prior.A, prior.fs))
    ):
        zb, zd = np.zeros((prior.order, 1)), np.zeros((prior.C.shape[0], 1))
        out.append(replace(prior, B=np.hstack([prior.B, zb]), D=np.hstack([prior.D, zd])))
    return out


def _refine_spring(m, data, u, q, j, rows, phi, form):
    """Poles (and the stiffness k of the "input" form) by output error with the force q
    given: "input" form: the force acts where input j acts (u_j - k q, one parameter);
    "free" form: the force is one more input with its own b_q, d_q (a discrete model of a
    spring whose force does not enter exactly like the input). Returns (A, C, T, k, v, w)."""
    if form == "input":
        k0 = -(m.B[:, -1] @ m.B[:, j]) / max(m.B[:, j] @ m.B[:, j], 1e-300)

        def signals(extra: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
            v, w = u.copy(), u.copy()
            v[:, j] -= extra[0] * 0.5 * (q + next_sample(q))
            w[:, j] -= extra[0] * q
            return v, w

        a, c, t, x = refine_poles(
            m.A, m.C, data.y, rows, signals, np.array([k0]), phi, REFINE_EVALUATIONS
        )
        return (a, c, t, float(x[0]), *signals(x))
    v, w = spring_inputs(u, q)
    a, c, t, _ = refine_poles(
        m.A, m.C, data.y, rows, lambda _: (v, w), np.zeros(0), phi, REFINE_EVALUATIONS
    )
    return a, c, t, 0.0, v, w


def _to_basis(m: IdentifiedModel, a: np.ndarray, c: np.ndarray, t: np.ndarray) -> IdentifiedModel:
    """The model in the modal basis T with new dynamics A (C = C_old T); noise covariances
    transformed, the Kalman gain re-solved and the modes recomputed for the new A."""
    ti = np.linalg.inv(t)
    q, s = ti @ m.Q @ ti.T, ti @ m.S
    k, re = kalman_gain(a, c, q, s, m.R)
    return replace(
        m, A=a, C=c, B=ti @ m.B, K=k, Q=q, S=s, innovation_covariance=re, modes=modes_of(a, m.fs)
    )


def modes_of(a: np.ndarray, fs: float) -> list[ModalParameters]:
    """Frequency and damping of every complex pole pair of A, by frequency."""
    lam = np.linalg.eigvals(a)
    out = []
    for z in lam[lam.imag > 1e-10]:
        sc = fs * np.log(z)
        rad = abs(sc)
        out.append(
            ModalParameters(
                frequency_hz=float(rad / (2 * np.pi)),
                damping_ratio=float(-sc.real / rad),
                pole_discrete=complex(z),
                pole_continuous=complex(sc),
            )
        )
    return sorted(out, key=lambda md: md.frequency_hz)


def block_power(
    a: np.ndarray, c: np.ndarray, kinds: list[int], y: np.ndarray, u: np.ndarray,
    rows: np.ndarray,
) -> tuple[list[float], OutputErrorFit]:
    """Output power on ``rows`` of each modal block of the block-diagonal ``a`` (sizes
    ``kinds``: 2 a complex pair, 1 a real pole) in the free run from ``u``, with B, D and the
    initial state by output error on ``rows`` (returned too)."""
    dyn = LinearDynamics.build(a, c, y.shape[0])
    oe = fit_output_error(dyn, y, u, rows)
    offsets = np.cumsum([0, *kinds])[:-1]
    power = []
    for k, kind in enumerate(kinds):
        blk = slice(offsets[k], offsets[k] + kind)
        sub = LinearDynamics(a[blk, blk], c[:, blk], dyn.kernel[:, :, blk])
        power.append(float(np.sum(sub.simulate(oe.B[blk], u)[rows] ** 2)))
    return power, oe


def discrete_pole(f: float, z: float, fs: float) -> complex:
    """The discrete pole exp(s / fs) of a mode of frequency ``f`` [Hz] and damping ``z``."""
    w = 2 * np.pi * f
    return complex(np.exp((-z * w + 1j * w * np.sqrt(1 - z * z)) / fs))


def dominant_modes(
    m: IdentifiedModel, y: np.ndarray, u: np.ndarray, rows: np.ndarray, order: int
) -> IdentifiedModel:
    """The order-``order`` model keeping the modal blocks of ``m`` (complex pairs, real poles)
    that carry most of the free run's output power (B by output error on ``rows``): a
    subspace realization of higher order finds the structure's modes among noise modes more
    reliably than one at the nominal order."""
    t, eig, kinds = real_modal_basis(m.A)
    r = np.maximum(np.abs(eig), 1e-300)
    eig = np.where(r >= 1.0, eig / r * 0.999, eig)  # an unstable pole: pulled inside
    ti = np.linalg.inv(t)
    a, c = block_matrix(eig, kinds), m.C @ t
    energy, oe = block_power(a, c, kinds, y, u, rows)
    offsets = np.cumsum([0, *kinds])[:-1]
    keep, room = [], order
    for k in np.argsort(energy)[::-1]:
        if kinds[k] <= room:
            keep.append(k)
            room -= kinds[k]
    if not keep:  # an odd order below every block: order 1 against complex pairs only
        raise ValidationError(f"no modal block of the order-{m.order} realization fits {order}")
    idx = np.concatenate([np.arange(offsets[k], offsets[k] + kinds[k]) for k in sorted(keep)])
    ar, cr = a[np.ix_(idx, idx)], c[:, idx]
    q, s = (ti @ m.Q @ ti.T)[np.ix_(idx, idx)], (ti @ m.S)[idx]
    kg, re = kalman_gain(ar, cr, q, s, m.R)
    return replace(
        m, A=ar, B=oe.B[idx], C=cr, D=oe.D, K=kg, Q=q, S=s, innovation_covariance=re,
        order=int(idx.size), modes=modes_of(ar, m.fs),
    )


def _refine_theta(
    fm: FittedModel,
    data: ValidationData,
    phi: np.ndarray,
    yc: np.ndarray,
    ue: np.ndarray,
    split: Split,
) -> None:
    """theta += argmin || e - F(Phi) dtheta || on the estimation part, F the innovation filter
    (one-step prediction error: output-only data, LPV and closed-loop structures)."""
    l = data.n_outputs
    e = (yc - fm._core_predict(data, yc, ue))[split.est]
    zero_u = np.zeros_like(ue)
    cols = []
    for j in range(phi.shape[1]):
        for c in range(l):
            x = np.zeros((data.n, l))
            x[:, c] = phi[:, j]
            cols.append((x - fm._core_predict(data, x, zero_u))[split.est].ravel())
    design = np.column_stack(cols)
    d = lstsq(design, e.ravel())
    fm.theta = fm.theta + d.reshape(phi.shape[1], l)
