"""Recursive DSRA (Appendix B of the paper): RecursiveDSRA.update(u, y), .modes().

The RLS of L_p with forgetting factor lambda is kept in information form: the exponentially
weighted product of the windowed data z_k = [u_p; y_p; u_f; y_f] (hankel.py),

    R_k = lambda_k R_{k-1} + z_k z_k' + (1 - lambda_k) Delta,

is updated per block with the per-sample weights prod_{s>k} lambda_s (one matrix product per
block, mathematically the per-sample RLS recursion). Its regressor block is the RLS information
matrix of [P; U_f], so [L_p T_d] = R_{yf,phi} R_{phi,phi}^{-1} is the RLS estimate of (A2); the
regularised forgetting keeps R >= Delta in steady state (Delta = delta I with input_delta on the
input rows, INPUT_REGULARISATION; covariance P = R^{-1} <= 1/delta, SPD
by construction, no wind-up without excitation). Start-up uses lambda_k = 1 (a growing window
of equal weights) until the memory 1/(1 - lambda) is filled.

At a configurable slower rate the model is realized from the Cholesky factor of R with the
same SVD-based algorithm as the batch (realization.py: (A2), SVD, Kalman states (A3), (A4)),
which the paper notes is more accurate than the per-sample RLS update of G. Channels are scaled
by their standard deviation over the first samples (or by given scales).
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np
from scipy import linalg
from scipy.signal import butter, lfilter, sosfilt, sosfilt_zi

from .batch import model_from_projection
from .hankel import Layout, window_order, window_rows_packed
from .inputs import InputError, as_2d, check_rate, finite_rows
from .modal import ModalParameters, select_modes
from .model import IdentifiedModel
from .order import select_order
from .realization import project
from .spurious import INPUT_RECENT_WINDOWS, check_orders

#: Regularisation of the input rows of the information matrix, R >= input_delta there (scaled
#: units: every input of unit variance, so a direction of the windowed inputs holds about one
#: unit per sample of memory): a direction the input excites less than a tenth of a sample of
#: its own level would is not estimated. A band-limited input (coloured noise, a multisine, a
#: sweep: nothing above its cut-off) leaves such directions; with the outputs' 1e-6 the (A2)
#: solve divided by them and put noise into the projection, whose poles were tracked as modes.
#: Randomized suite (benchmarks/random_suite.py, 52 draws), its 25 input-output draws with
#: 1e-6 / 0.1: false tracked per estimate mean 0.21 / 0.08, max 5 / 1; every mode by 3 s in
#: 72 / 84 % of them, settled 87 / 96 % (1 gave 88 % by 3 s but delayed the seed example's
#: first estimates; white inputs are alike with both). Outputs keep 1e-6: their noise floor may
#: lie far below their level (a lightly damped response in 1 % noise).
INPUT_REGULARISATION = 0.1
#: The configuration validated on the paper's Sec. II example (100 Hz, 1 input, 1 output; see
#: test_core_seed_example.py): i = 35 block rows (0.35 s of past), order 10 (at most five modes in
#: [0, 10] Hz as in the paper), lambda = 0.99 (1 s memory), a realization every 0.05 s.
SEED_EXAMPLE_SETTINGS: dict = {
    "block_rows": 35,
    "max_modes": 5,
    "max_order": 10,
    "forgetting_factor": 0.99,
    "realization_interval": 5,
    "band": (0.0, 10.0),
}


@dataclass(frozen=True)
class EstimatorStatus:
    """:meth:`RecursiveDSRA.status`: ``health`` 0 ok / 1 degraded (sysid_msgs/ModalEstimate
    HEALTH_*), ``reason`` (empty when ok) and the counters behind it."""

    health: int
    reason: str
    outliers_rejected: int
    level_restarts: int
    changes_detected: int


#: The outlier gate's reference mean squares are exponential means over this many change
#: windows of the accepted samples (the recent normal, not the whole memory).
GATE_REFERENCE_WINDOWS = 10
#: Smallest reference mean square of the outlier gate (scaled units: the channels' start-up RMS
#: is 1), (3 %)^2.
GATE_REFERENCE_FLOOR = 1e-3
#: A gate prediction this many times larger than the largest output sample of the block as it
#: came (or than the start-up RMS, scaled units) is wild: 0 is used instead.
GATE_WILD_FACTOR = 1e3
#: Change detection split at the band top (``_split_band``) when the band's top lies below this
#: fraction of the Nyquist frequency: there is room above the band for a change the
#: estimator's modes do not hold (in practice the automatic band's low group, whose band ends at
#: a third of its rate at most; the main estimator's ends at 0.4 of its rate, 0.8 Nyquist).
SPLIT_NYQUIST_FRACTION = 0.75
#: A rise of the a-priori error is a change for the estimator when the in-band part's
#: short/long mean-square ratio is at least this many times that of the part above the band
#: (per output): a change above the band (a mode there appearing or jumping, leaking through
#: the decimation filter) raises the part above more. Calibration on a white a-priori error
#: (no change; band top 0.2-0.33 fs, memories 100-1000 samples, 2e5 samples): the in-band
#: ratio over the part above's is 1.0 at the median and 2.2-2.7 at the 99th percentile, so 2
#: asks a rise to be mostly the band's, beyond most of the parts' own scatter; a change inside
#: the band raises the in-band ratio by the change threshold (3) or more. A change close below
#: the band top leaks into the part above (order 4: -13 dB at 0.7 of the top).
DETECTION_BAND_MARGIN = 2.0
#: Order of the Butterworth low / high pass pair that splits the a-priori error at the band top.
SPLIT_FILTER_ORDER = 4


def memory_samples(forgetting_factor: float) -> float:
    """The RLS memory 1 / (1 - lambda) [samples] of Appendix B's exponential window (finite,
    about 1e12, for lambda = 1: a growing window never fills)."""
    return 1.0 / max(1.0 - forgetting_factor, 1e-12)


class RecursiveDSRA:
    """Online DSRA over blocks of samples of any length (including 1).

    Parameters: ``n_outputs`` l, ``n_inputs`` m (0 = output-only), sample rate ``fs`` [Hz],
    ``block_rows`` i, ``max_order`` (model order of the realization; default
    2 ``max_modes``, else 10), ``forgetting_factor`` lambda, ``realization_interval`` [samples]
    between SVD realizations, ``band`` / ``damping_bounds`` / ``max_modes`` for mode selection,
    ``order_method`` None (fixed ``max_order``, the paper's choice) or "gap"/"aic"/"bic"/"mdl"
    up to ``max_order``, ``delta`` the regularisation (scaled units) and ``input_delta`` that of
    the input rows (:data:`INPUT_REGULARISATION`), ``min_excitation`` the
    mean weighted power (scaled units) below which no realization is attempted, ``input_scale``
    / ``output_scale`` fixed channel scales (default: std of the first ``scale_samples``),
    ``startup_memory`` equal weights (lambda_k = 1) until the memory 1/(1 - lambda) is filled.

    Change detection (beyond the paper, for abrupt changes such as its 6 Hz example): when the
    short-term (``change_window`` samples) mean square of the a-priori prediction error of any
    output exceeds ``change_threshold`` times its long-term (1 / (1 - lambda)) level (and,
    with a band ending below SPLIT_NYQUIST_FRACTION of Nyquist, the rise is the band's:
    :meth:`_in_band_rises`; a change above the band is none of this estimator's), the old
    information is discounted by ``change_discount`` (R <- c R + (1 - c) Delta), and once more
    2i samples later (the windows that straddle the change are inconsistent with any single
    LTI model); then no new detection for one memory length. ``change_count`` counts the detections.

    Outlier gate (``outlier_gate``, issue #13): see :meth:`_gate`; :meth:`status` reports the
    estimator's health. ``stabilize`` runs the multi-order spurious-mode tests of ``spurious.py``
    on every realization (``ModalParameters.stable``; with a measured input also test 5, the
    input's own, from a short-memory covariance of the windows' inputs; off by default: on
    the paper's example it delays the confirmation of a newly appeared mode beyond 1.5 s),
    without the batch's determined-frequency test (the tracker judges consistency over
    successive realizations).
    """

    #: Largest number of samples queued before they are absorbed (see :meth:`update`).
    MAX_QUEUED = 256

    def __init__(
        self,
        n_outputs: int,
        n_inputs: int = 0,
        fs: float = 1.0,
        block_rows: int = 20,
        max_order: int | None = None,
        forgetting_factor: float = 0.99,
        realization_interval: int = 10,
        band: tuple[float, float] | None = None,
        damping_bounds: tuple[float, float] | None = (0.0, 0.5),
        max_modes: int | None = None,
        order_method: str | None = None,
        delta: float = 1e-6,
        input_delta: float = INPUT_REGULARISATION,
        min_excitation: float = 1e-4,
        input_scale: np.ndarray | None = None,
        output_scale: np.ndarray | None = None,
        scale_samples: int | None = None,
        startup_memory: bool = True,
        change_detection: bool = True,
        change_threshold: float = 3.0,
        change_window: int = 20,
        change_discount: float = 0.3,
        stabilize: bool = False,
        outlier_gate: bool = True,
        outlier_alpha: float = 1e-4,
    ) -> None:
        if n_outputs < 1 or n_inputs < 0:
            raise InputError(f"need n_outputs >= 1 and n_inputs >= 0, got {n_outputs}, {n_inputs}")
        if block_rows < 2:
            raise InputError(f"block_rows must be >= 2, got {block_rows}")
        self.fs = check_rate(fs)
        self.layout = Layout(block_rows, n_inputs, n_outputs)
        self.n_inputs, self.n_outputs, self.block_rows = n_inputs, n_outputs, block_rows
        top = n_outputs * (block_rows - 1)
        if max_order is None:
            max_order = min(2 * max_modes if max_modes else 10, top)
        if not 1 <= max_order <= top:
            raise InputError(f"max_order must be in [1, {top}] for block_rows={block_rows}")
        if realization_interval < 1:
            raise InputError(f"realization_interval must be >= 1, got {realization_interval}")
        self.max_order = int(max_order)
        self.realization_interval = int(realization_interval)
        self.order_method = order_method
        self.max_modes = max_modes
        self.delta = float(delta)
        self.input_delta = float(input_delta)
        self.min_excitation = float(min_excitation)
        self.set_forgetting_factor(forgetting_factor)
        self.set_band(band, damping_bounds)
        self._fixed_su = None if input_scale is None else np.asarray(input_scale, float).ravel()
        self._fixed_sy = None if output_scale is None else np.asarray(output_scale, float).ravel()
        self.scale_samples = int(scale_samples or max(4 * block_rows, 50))
        self.startup_memory = bool(startup_memory)
        self.change_detection = bool(change_detection)
        self.change_threshold = float(change_threshold)
        self.change_window = int(change_window)
        self.change_discount = float(change_discount)
        self.stabilize = bool(stabilize)
        self.outlier_gate = bool(outlier_gate)
        # Markov's inequality on sum_c x_c^2 / E x_c^2: exceeded with probability <= l / t for
        # ANY distribution (heavy tails, bursts), so t = channels / alpha is distribution-free
        self._gate_q = (max(n_outputs, 1) / outlier_alpha, max(n_inputs, 1) / outlier_alpha)
        self.outliers_rejected = 0  # samples rejected by the gate (never reset)
        self.level_restarts = 0  # restarts after a sustained change of the signal level
        self.reset()

    # ------------------------------------------------------------------ configuration
    def set_forgetting_factor(self, lam: float) -> None:
        """Change lambda live (0 < lambda <= 1); the current estimate is kept."""
        lam = float(lam)
        if not 0.0 < lam <= 1.0:
            raise InputError(f"forgetting_factor must be in (0, 1], got {lam}")
        if getattr(self, "_queued", 0):
            self.flush()  # queued samples still get the old lambda
        self.forgetting_factor = lam

    def set_band(
        self,
        band: tuple[float, float] | None,
        damping_bounds: tuple[float, float] | None = (0.0, 0.5),
    ) -> None:
        """Change the frequency band [Hz] and damping bounds used to select modes (live)."""
        if band is not None and not (0.0 <= band[0] < band[1]):
            raise InputError(f"band must satisfy 0 <= fmin < fmax, got {band}")
        if damping_bounds is not None and not damping_bounds[0] < damping_bounds[1]:
            raise InputError(
                f"damping_bounds must be (low, high) with low < high, got {damping_bounds}"
            )
        old = getattr(self, "band", None)
        self.band, self.damping_bounds = band, damping_bounds
        if hasattr(self, "_split_sos") and (old and old[1]) != (band and band[1]):
            self._reset_split()  # a new band top: a new split

    def reset(self) -> None:
        """Forget all data and the model (configuration is kept)."""
        d = self.layout.dim
        lay = self.layout
        self._u_cols = np.r_[0 : lay.i * lay.m, lay.n_past : lay.n_past + lay.i * lay.m]
        #: the ridge kept on the diagonal of R: delta, input_delta on the input rows
        self._ridge = np.full(d, self.delta)
        self._ridge[self._u_cols] = max(self.delta, self.input_delta)
        self._info = np.diag(self._ridge)  # weighted information matrix R_k
        self._info_diag = np.einsum("ii->i", self._info)  # its diagonal (a writable view)
        # covariance of the recent windows' inputs [u_p; u_f] (spurious.py test 5)
        self._u_recent = np.zeros((self._u_cols.size, self._u_cols.size))
        self._sum_w = 0.0
        self._sum_w2 = 0.0
        self._k = 0  # number of windows absorbed
        self._tail = np.zeros((0, self.n_inputs + self.n_outputs))  # last 2i-1 scaled samples
        self._pending: list[np.ndarray] = []
        self._su = self._fixed_su
        self._sy = self._fixed_sy
        self._scale: np.ndarray | None = None  # [su, sy] once both are known
        self._since_realization = 0
        self._absorbing = False  # absorb(): accumulate without realizing
        self._theta1: np.ndarray | None = None
        self._pe_ms = np.full(self.n_outputs, np.nan)
        self._pe_short = np.full(self.n_outputs, np.nan)
        self._coef_of: np.ndarray | None = None  # theta_1 of _coef (_innovation_coefficients)
        self._coef = np.zeros((0, 0))
        self._holdoff = 0
        self._second_discount = 0
        self._reset_split()
        self._change_count = 0
        self.model: IdentifiedModel | None = None
        self.samples_seen = 0
        self._samples_skipped = 0
        self._weight_cache: dict = {}  # _weights
        self._ew_kernel_of: tuple | None = None  # lambdas of _ew_kernel (_ew_paths)
        self._queue: list[np.ndarray] = []  # validated samples not yet absorbed
        self._queued = 0
        self.realization_count = 0
        self.realizations_skipped = 0
        self.last_realization_time = float("nan")  # data time [s]
        self.last_realization_cost_s = float("nan")  # wall-clock seconds
        # CPU seconds of the calling thread spent realizing, attempts included (not wall-clock:
        # a process descheduled in the middle of a realization did not spend the stall)
        self.realization_seconds = 0.0
        self._excited = False
        # outlier gate: the last i samples (scaled, outliers replaced by their prediction),
        # reference mean squares of the inputs and outputs, current run of rejected samples
        self._gate_tail = np.zeros((0, self.n_inputs + self.n_outputs))
        self._gate_ref = np.ones(self.n_inputs + self.n_outputs)
        self._gate_run = 0
        self._gated = 0  # samples through the gate
        self._last_outlier = -(10**18)  # index (of the gated samples) of the latest outlier

    # ------------------------------------------------------------------ status
    @property
    def prediction_error_rms(self) -> np.ndarray:
        """Per-channel RMS of the a-priori one-step prediction error of the (A2) predictor
        (physical units, exponentially weighted); NaN until the first realization."""
        self.flush()
        if self._sy is None:
            return np.full(self.n_outputs, np.nan)
        return np.sqrt(self._pe_ms) * self._sy

    @property
    def converged(self) -> bool:
        """A model exists, the memory is filled and the data excite the estimator."""
        self.flush()
        mem = min(self.memory_samples, 10 * self.layout.dim)
        return self.model is not None and self._excited and self._k >= mem

    @property
    def memory_samples(self) -> float:
        """The memory 1 / (1 - lambda) [samples] (:func:`memory_samples`)."""
        return memory_samples(self.forgetting_factor)

    @property
    def information_matrix(self) -> np.ndarray:
        """Current weighted information matrix R_k (scaled units, SPD, >= delta I)."""
        self.flush()
        return 0.5 * (self._info + self._info.T)

    @property
    def samples_skipped(self) -> int:
        """Samples skipped because of NaN/Inf."""
        self.flush()
        return self._samples_skipped

    @property
    def change_count(self) -> int:
        """Abrupt changes detected (each discounted the old information)."""
        self.flush()
        return self._change_count

    def status(self) -> EstimatorStatus:
        """Health of the estimate for the ModalEstimate message (HEALTH_OK 0 / DEGRADED 1) with
        the reason: outliers rejected within the last reference window (GATE_REFERENCE_WINDOWS
        change windows), a restart after a new signal level until a model exists again, or an
        excitation too low to identify."""
        self.flush()
        recent = GATE_REFERENCE_WINDOWS * self.change_window
        reasons = []
        if self._gated - self._last_outlier <= recent:
            window = recent / self.fs
            reasons.append(f"outliers rejected ({self.outliers_rejected} samples so far; one "
                           f"within the last {window:g} s)")
        if self.level_restarts and self.model is None:
            reasons.append("signal level changed: estimator restarted")
        if self.realizations_skipped and not self._excited and self.samples_seen:
            reasons.append("excitation too low to identify")
        return EstimatorStatus(
            health=1 if reasons else 0,
            reason="; ".join(reasons),
            outliers_rejected=self.outliers_rejected,
            level_restarts=self.level_restarts,
            changes_detected=self._change_count,
        )

    def modes(self) -> list[ModalParameters]:
        """Modes of the latest realization, selected with the current band/damping/max_modes."""
        if self.model is None:
            return []
        return select_modes(self.model.modes, self.band, self.damping_bounds, self.max_modes)

    # ------------------------------------------------------------------ update
    def update(self, u_block: np.ndarray | None, y_block: np.ndarray) -> list[IdentifiedModel]:
        """Absorb a block of samples u (N, m) (None when m = 0) and y (N, l).

        Samples with NaN/Inf are skipped and counted (``samples_skipped``); the window restarts
        after them. Returns the models realized during this block (usually none or one).
        Samples are queued and absorbed as one block when a realization is due (or
        ``MAX_QUEUED`` are waiting, or the state is read): the same numbers as absorbing each
        block at once (the update is exact in blocks), at a fraction of the per-call cost.
        """
        y = as_2d(y_block, "y_block", self.n_outputs)
        if self.n_inputs == 0:
            if u_block is not None and np.asarray(u_block).size:
                raise InputError("estimator is output-only (n_inputs=0) but u_block was given")
            u = np.zeros((y.shape[0], 0))
        else:
            if u_block is None:
                raise InputError(f"u_block with {self.n_inputs} input(s) is required")
            u = as_2d(u_block, "u_block", self.n_inputs)
            if u.shape[0] != y.shape[0]:
                raise InputError(f"u_block has {u.shape[0]} samples but y_block {y.shape[0]}")
        self.samples_seen += y.shape[0]
        self._queue.append(np.hstack([u, y]))
        self._queued += y.shape[0]
        if (
            self._sy is None
            or self._queued >= self.MAX_QUEUED
            or self._since_realization + self._queued >= self.realization_interval
        ):
            return self._flush()
        return []

    def absorb(self, u_block: np.ndarray | None, y_block: np.ndarray) -> None:
        """Absorb a block as :meth:`update` does, without realizing a model (catching up on
        old data; a new estimator fed the recent past): the next realization is due at the
        next sample."""
        self._absorbing = True
        try:
            self.update(u_block, y_block)
            self.flush()
        finally:
            self._absorbing = False

    def flush(self) -> None:
        """Absorb the queued samples now (reads of the state do this themselves)."""
        if self._queued:
            self._flush()

    def _flush(self) -> list[IdentifiedModel]:
        data = self._queue[0] if len(self._queue) == 1 else np.vstack(self._queue)
        self._queue, self._queued = [], 0
        out: list[IdentifiedModel] = []
        ok = None if np.isfinite(data).all() else finite_rows(data)
        if ok is None:
            self._absorb(data, out)
            return out
        bad = np.flatnonzero(~ok)
        self._samples_skipped += bad.size
        start = 0
        for b in bad:  # rare path: split at bad samples, restart the window after each
            if b > start:
                self._absorb(data[start:b], out, end_offset=b - data.shape[0])
            self._tail = self._tail[:0]
            start = b + 1
        if start < data.shape[0]:
            self._absorb(data[start:], out)
        return out

    def _absorb(self, data: np.ndarray, out: list[IdentifiedModel], end_offset: int = 0) -> None:
        """Scale and accumulate ``data`` (its last sample is ``-end_offset`` samples before the
        newest one seen), realizing every ``realization_interval`` samples into ``out``."""
        if self._su is None or self._sy is None:
            self._pending.append(data)
            have = sum(p.shape[0] for p in self._pending)
            if have < self.scale_samples:
                return
            data = np.vstack(self._pending)
            self._pending = []
            std = np.std(data[: self.scale_samples], axis=0)
            std = np.where(std > 0, std, 1.0)
            m = self.n_inputs
            self._su = std[:m] if self._su is None else self._su
            self._sy = std[m:] if self._sy is None else self._sy
        if self._scale is None:
            self._scale = np.concatenate([self._su, self._sy])
        data = data / self._scale
        # split so that realizations happen every realization_interval samples
        pos = 0
        while pos < data.shape[0]:
            take = min(data.shape[0] - pos, self.realization_interval - self._since_realization)
            if self._absorbing:  # absorb(): no realization, the next one due at once
                take = data.shape[0] - pos
            self._accumulate(data[pos : pos + take])
            pos += take
            self._since_realization += take
            if self._absorbing:
                self._since_realization = min(self._since_realization,
                                              self.realization_interval - 1)
            elif self._since_realization >= self.realization_interval:
                self._since_realization = 0
                c0 = time.thread_time()
                mdl = self._realize(pos - data.shape[0] + end_offset)
                self.realization_seconds += time.thread_time() - c0
                if mdl is not None:
                    out.append(mdl)

    def _accumulate(self, data: np.ndarray) -> None:
        """Gate the outliers, then absorb the rest (the window restarts after each outlier).

        In steady state (a realization exists and the window tail is full) the gate's
        predictions and the change statistics' a-priori errors come from one product of the
        block's windows with :meth:`_innovation_coefficients` (:meth:`_shared_product`)."""
        shared = self._shared_product(data)
        bad = None
        if self.outlier_gate:
            bad = self._gate(data, None if shared is None else shared[2])
        if bad is None:
            self._accumulate_clean(data, shared)
            return
        start = 0
        for b in np.flatnonzero(bad):  # rare path
            if b > start:
                self._accumulate_clean(data[start:b])
            self._tail = self._tail[:0]
            start = b + 1
        if start < data.shape[0]:
            self._accumulate_clean(data[start:])

    def _shared_product(self, data: np.ndarray):
        """``(buf, z, p)`` for a block whose every sample ends a full window (the window tail
        holds 2i - 1 samples) once a realization exists, else None: ``buf`` the tail and the
        block, ``z`` its windows (one per sample of the block, (A1) layout) and
        ``p = z @ _innovation_coefficients()``, (n, 2l): columns :l the gate's causal
        one-step predictions of the block's outputs, columns l: the (A2) predictions of the
        first future output of each window (the change statistics).

        When the window tail is full the gate's own past (its last i samples) is the tail's
        last i samples: the tail restarts after an outlier (which the gate replaced in its
        past) or a NaN (which the gate never saw) and is only full again 2i - 1 clean samples
        later, all of them seen by the gate as they are."""
        if self._theta1 is None or self._tail.shape[0] != 2 * self.block_rows - 1:
            return None
        buf = np.concatenate((self._tail, data))
        z = window_rows_packed(buf, self.n_inputs, self.block_rows)
        return buf, z, z @ self._innovation_coefficients()

    def _innovation_coefficients(self) -> np.ndarray:
        """(dim, 2l) coefficients on a window z (A1 layout) of the two predictions of
        :meth:`_shared_product`, rebuilt when the realization's theta_1 changes.

        theta_1 (l x (i(m + l) + im)) is the first block row of [L_p T_d] of (A2), the RLS
        estimate of Appendix B: y_{f,1} ~ theta_1 [u_p; y_p; u_f]. Columns l: are theta_1'
        (zero on the y_f rows). Columns :l hold the gate's causal part of it applied to the
        window's last i + 1 samples: the past coefficients on samples t - i .. t - 1 and the
        first u_f coefficient on the input at t (:meth:`_gate_prediction`, t the window's last
        sample)."""
        th = self._theta1
        if self._coef_of is th:
            return self._coef
        m, l, i = self.n_inputs, self.n_outputs, self.block_rows
        npast = i * (m + l)
        per_sample = np.zeros((2 * i, m + l, l))  # sample-major window: sample, channel
        per_sample[i - 1 : 2 * i - 1, :m] = th[:, : i * m].reshape(l, i, m).transpose(1, 2, 0)
        per_sample[i - 1 : 2 * i - 1, m:] = th[:, i * m : npast].reshape(l, i, l).transpose(
            1, 2, 0)
        per_sample[2 * i - 1, :m] = th[:, npast : npast + m].T
        coef = np.zeros((self.layout.dim, 2 * l))
        coef[:, :l] = per_sample.reshape(-1, l)[window_order(i, m, l)]
        coef[: th.shape[1], l:] = th.T
        self._coef, self._coef_of = coef, th
        return coef

    def _gate(self, data: np.ndarray, shared: np.ndarray | None = None) -> np.ndarray | None:
        """Flag the outliers among the rows of ``data`` (scaled [u, y]); None when there is none.

        The a-priori innovation of each output sample, e_t = y_t minus its prediction from the
        i samples before and the input at t (the causal part of the (A2) predictor's first
        row; the sample itself before the first realization), is compared with its reference
        mean square, each input sample with the input's: sum_c e_c^2 / ref_c exceeds
        l / outlier_alpha with probability at most outlier_alpha whatever the distribution
        (Markov's inequality), so bursts of ambient excitation, heavy tails and changes of the
        structure pass (tens to hundreds of reference levels) while spikes and bursts of
        1e3 sigma and more are rejected. A rejected output sample is replaced by its
        prediction (an input by 0) for the predictions that follow, so one spike rejects one
        sample; the window restarts after it (as for NaN). References are exponential means
        over GATE_REFERENCE_WINDOWS change windows of the accepted samples. A run of rejected
        samples longer than that window is a new signal level, not an outlier: the estimator
        restarts (``level_restarts``). Rejected samples never reach the change detection: a
        spike is not a change of the structure.

        ``shared``: the predictions of the block from :meth:`_shared_product` (its first l
        columns; the same numbers as :meth:`_gate_prediction` up to rounding), else computed
        here.
        """
        m, l, i = self.n_inputs, self.n_outputs, self.block_rows
        n = data.shape[0]
        ref = self._gate_ref
        q_y, q_u = self._gate_q
        # the level of the block as it came (the replaced samples must not raise it)
        level = max(float(np.abs(data[:, m:]).max(initial=0.0)), 1.0)
        hist = None
        if shared is None:
            hist = np.concatenate((self._gate_tail, data))
            pred = self._gate_prediction(hist, self._gate_tail.shape[0], level)
        else:
            pred = self._tame(shared[:, :l], level)
        e2_all = (data[:, m:] - pred) ** 2
        over = (e2_all / ref[m:]).sum(axis=1) > q_y
        u2 = data[:, :m] ** 2
        if m:
            over |= (u2 / ref[:m]).sum(axis=1) > q_u
        hit = np.flatnonzero(over)
        bad = None
        if hit.size:  # rare path: replace each outlier, predict the rest of the block again
            if hist is None:
                hist = np.concatenate((self._gate_tail, data))
            n0 = hist.shape[0] - n
            bad = np.zeros(n, dtype=bool)
            k = 0
            while hit.size:
                j = k + int(hit[0])
                bad[j] = True
                hist[n0 + j, m:] = pred[hit[0]]  # outlier out of the predictor's past
                if m:
                    hist[n0 + j, :m] = 0.0
                k = j + 1
                if k >= n:
                    break
                pred = self._gate_prediction(hist, n0 + k, level)
                e2 = (hist[n0 + k :, m:] - pred) ** 2
                e2_all[k:] = e2
                over = (e2 / ref[m:]).sum(axis=1) > q_y
                if m:
                    over |= (hist[n0 + k :, :m] ** 2 / ref[:m]).sum(axis=1) > q_u
                hit = np.flatnonzero(over)
        good = np.concatenate((u2, e2_all), axis=1)  # [u^2, e^2]
        if bad is not None:
            good = good[~bad]
        if good.shape[0]:
            w, decay, _, _ = self._weights(good.shape[0], self._gate_lambda)
            # never below (3 % of the start-up RMS)^2: after a quiet or dead stretch the
            # signal's return is not an outlier
            lam = self._gate_lambda
            self._gate_ref = np.maximum(decay * ref + (1 - lam) * (w @ good),
                                        GATE_REFERENCE_FLOOR)
        if hist is None:
            hist = data if n >= i else np.concatenate((self._gate_tail, data))
        self._gate_tail = hist[-i:] if hist.shape[0] > i else hist
        self._gated += n
        if bad is None:
            self._gate_run = 0
            return None
        self.outliers_rejected += int(bad.sum())
        self._last_outlier = self._gated - n + int(np.flatnonzero(bad)[-1])
        trailing = n - 1 - int(np.flatnonzero(~bad)[-1]) if (~bad).any() else n
        self._gate_run = self._gate_run + n if trailing == n else trailing
        if self._gate_run > GATE_REFERENCE_WINDOWS * self.change_window:
            self._restart_level()
            return np.ones(n, dtype=bool)
        return bad

    def _restart_level(self) -> None:
        """A run of rejected samples longer than the reference window is a new signal level
        (a sensor gain, a unit change): start again from the new data, scales included."""
        self.level_restarts += 1
        seen, skipped, rejected = self.samples_seen, self._samples_skipped, self.outliers_rejected
        self.reset()
        self.samples_seen, self._samples_skipped = seen, skipped
        self.outliers_rejected = rejected
        self._su, self._sy = self._fixed_su, self._fixed_sy
        self._last_outlier = 0

    def _gate_prediction(self, hist: np.ndarray, start: int, level: float = 1.0) -> np.ndarray:
        """Causal one-step predictions of the outputs of rows ``start..`` of ``hist`` (zero
        where fewer than i samples precede, before the first realization, or where the
        prediction is wild: beyond GATE_WILD_FACTOR x ``level``, the block's largest output
        magnitude)."""
        m, l, i = self.n_inputs, self.n_outputs, self.block_rows
        rows = hist.shape[0] - start
        pred = np.zeros((rows, l))
        if self._theta1 is None or start + rows <= i:
            return pred
        first = max(start, i)
        past = np.lib.stride_tricks.sliding_window_view(hist[first - i : -1], i, axis=0)
        past = past[: hist.shape[0] - first]  # (rows', m + l, i): samples t-i .. t-1
        up = past[:, :m, :].transpose(0, 2, 1).reshape(past.shape[0], i * m)
        yp = past[:, m:, :].transpose(0, 2, 1).reshape(past.shape[0], i * l)
        th = self._theta1
        npast = i * (m + l)
        p = up @ th[:, : i * m].T + yp @ th[:, i * m : npast].T
        if m:
            p += hist[first:, :m] @ th[:, npast : npast + m].T
        pred[first - start :] = self._tame(p, level)
        return pred

    @staticmethod
    def _tame(p: np.ndarray, level: float) -> np.ndarray:
        """``p`` (in place) with the rows holding a wild prediction set to 0.

        A realization from few samples per dimension can have wild predictor coefficients: a
        prediction far beyond the data (GATE_WILD_FACTOR x ``level``; NaN too) is no
        reference (and must not replace a rejected sample: the next predictions would build
        on it and overflow)."""
        ok = np.abs(p) <= GATE_WILD_FACTOR * level
        if not ok.all():
            p[~ok.all(axis=1)] = 0.0
        return p

    def _accumulate_clean(self, data: np.ndarray, shared=None) -> None:
        """Absorb ``data`` (no outliers): the windows ending at its samples, split where the
        change statistics discount the old information (``shared``: see
        :meth:`_shared_product`)."""
        if shared is None:
            buf = np.concatenate((self._tail, data))
            z = window_rows_packed(buf, self.n_inputs, self.block_rows)
            err = None  # the a-priori errors, computed by _change_cuts
        else:
            buf, z, p = shared
            l = self.n_outputs
            yf1 = self.layout.yf.start
            err = z[:, yf1 : yf1 + l] - p[:, l:]
        self._tail = buf[-(2 * self.block_rows - 1) :]
        if z.shape[0] == 0:
            return
        start = 0
        for cut in self._change_cuts(z, err):  # discount the old information before `cut`
            self._add_windows(z[start:cut])
            self._discount(self.change_discount)
            start = cut
        self._add_windows(z[start:])

    def _change_cuts(self, z: np.ndarray, err: np.ndarray | None = None) -> list[int]:
        """Run the prediction-error statistics over the windows z sample by sample (vectorised,
        :meth:`_ew_paths`) and return the window indices before which the information is
        discounted.

        The a-priori error of window k is that of the first future output under the latest
        (A2) estimate, e_k = y_{f,1} - theta_1 [u_p; y_p; u_f] (``err`` when the caller has it
        from :meth:`_shared_product`). Per sample: the short- and long-term mean squares of the
        error are updated, a change is declared when the short one exceeds
        ``change_threshold`` times the long one of the sample before (outside the hold-off)
        in an output where the rise is the band's (:meth:`_in_band_rises`, when the band
        ends well below Nyquist), and a second discount follows 2i samples later. The result
        does not depend on how the data were split into blocks.
        """
        if self._theta1 is None:
            return []
        if err is None:
            r = self._theta1.shape[1]
            yf1 = self.layout.yf.start
            err = z[:, yf1 : yf1 + self.n_outputs] - z[:, :r] @ self._theta1.T
        e2 = err**2
        split = self._split_sos is not None
        if split:
            self._split_queue.append(err)
            self._split_queued += err.shape[0]
        in_band = None  # (n, l): rises that are the band's (computed on demand)
        cuts: list[int] = []
        pos, n = 0, e2.shape[0]
        thr = self.change_threshold
        while pos < n:
            seg = e2[pos:] if pos else e2
            ns = seg.shape[0]
            short, long_ = self._ew_paths(seg)
            event = ns
            free = max(self._holdoff - 1, 0)  # first sample outside the hold-off
            if self.change_detection and free < ns:
                # against the long-term level of the sample before: shifted by one (NaN
                # compares False: no detection before the statistics have started)
                first = short[free] > thr * (self._pe_ms if free == 0 else long_[free - 1])
                found = first.any()
                if found and split:  # a rise: is it the band's?
                    if in_band is None:
                        in_band = self._in_band_rises(n)
                    found = (first & in_band[pos + free]).any()
                if found:
                    event = free
                elif free + 1 < ns:
                    rise = short[free + 1 :] > thr * long_[free:-1]
                    hit = rise.any(axis=1)
                    if split and hit.any():
                        if in_band is None:
                            in_band = self._in_band_rises(n)
                        hit = (rise & in_band[pos + free + 1 :]).any(axis=1)
                    if hit.any():
                        event = free + 1 + int(np.argmax(hit))
            second = self._second_discount - 1 if self._second_discount > 0 else ns
            if event < ns and event <= second:  # a (new) change
                self._holdoff = self._holdoff_samples
                self._second_discount = 2 * self.block_rows
                self._change_count += 1
            elif second < ns:  # the second discount, 2i samples after a change
                event = second
                self._second_discount = 0
                self._holdoff = max(self._holdoff - (event + 1), 0)
            else:
                self._holdoff = max(self._holdoff - ns, 0)
                self._second_discount = max(self._second_discount - ns, 0)
            last = min(event, ns - 1)
            self._pe_short, self._pe_ms = short[last], long_[last]
            if event < ns:
                cuts.append(pos + event)
            pos += last + 1
        if split and self._split_queued >= self.MAX_QUEUED:
            self._split_paths()  # keep the queue short (the split states advance)
        return cuts

    # ------------------------------------------------------------------ band split

    def _reset_split(self) -> None:
        """Low / high pass (second-order sections) at the band top when the band ends below
        SPLIT_NYQUIST_FRACTION of Nyquist, else None; their states and the split parts'
        short- and long-term mean squares start afresh."""
        top = None if self.band is None else self.band[1]
        nyq = 0.5 * self.fs
        self._split_sos = None
        if top is not None and top < SPLIT_NYQUIST_FRACTION * nyq:
            wn = top / nyq
            self._split_sos = (butter(SPLIT_FILTER_ORDER, wn, "low", output="sos"),
                               butter(SPLIT_FILTER_ORDER, wn, "high", output="sos"))
        self._split_zi: tuple[np.ndarray, np.ndarray] | None = None
        nan = np.full(2 * self.n_outputs, np.nan)
        self._split_short, self._split_long = nan, nan.copy()
        self._split_queue: list[np.ndarray] = []  # a-priori errors not yet split
        self._split_queued = 0

    def _split_paths(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Split the queued a-priori errors at the band top and run the parts' mean squares
        over them: (short, long, long of the sample before), (n, 2l) each, columns :l the
        in-band part, l: the part above (exponential means as :meth:`_ew_paths`; filter and
        mean states carried: the result does not depend on when the queue is split)."""
        err = (self._split_queue[0] if len(self._split_queue) == 1
               else np.concatenate(self._split_queue))
        self._split_queue, self._split_queued = [], 0
        low, high = self._split_sos
        if self._split_zi is None:  # steady state of the first error held
            self._split_zi = tuple(sosfilt_zi(s)[:, :, None] * err[0] for s in (low, high))
        lo, zlo = sosfilt(low, err, axis=0, zi=self._split_zi[0])
        hi, zhi = sosfilt(high, err, axis=0, zi=self._split_zi[1])
        self._split_zi = (zlo, zhi)
        sq = np.concatenate((lo, hi), axis=1)
        sq *= sq
        short = self._ew_path(self._split_short, sq, 1.0 - 1.0 / self.change_window)
        long_ = self._ew_path(self._split_long, sq, self.forgetting_factor)
        before = np.concatenate((self._split_long[None, :], long_[:-1]))
        self._split_short, self._split_long = short[-1], long_[-1]
        return short, long_, before

    def _in_band_rises(self, n: int) -> np.ndarray:
        """(n, l) for the last n queued errors: the in-band part's short/long ratio (the
        short mean square over the long one of the sample before) is at least
        DETECTION_BAND_MARGIN times that of the part above the band (NaN: False)."""
        short, _, before = self._split_paths()
        l = self.n_outputs
        short, before = short[-n:], before[-n:]
        return short[:, :l] * before[:, l:] >= (
            DETECTION_BAND_MARGIN * short[:, l:] * before[:, :l])

    def _add_windows(self, z: np.ndarray) -> None:
        """R_k = lambda_k R_{k-1} + z_k z_k' + (1 - lambda_k) Delta over the rows of z (the RLS
        of Appendix B in information form, one product per block)."""
        n = z.shape[0]
        if n == 0:
            return
        lam_f = self.forgetting_factor
        memory = self.memory_samples
        first, last = self._k + 1, self._k + n
        if not self.startup_memory or first >= memory:  # steady state: lambda_k = lambda
            w, decay, w_sum, w_sq = self._weights(n, lam_f)  # w_t = prod_{s>t} lambda_s
        else:
            if last < memory:  # growing window: equal weights until the memory is filled
                w, decay = np.ones(n), 1.0
            else:  # the block where the memory fills
                lam = np.where(np.arange(first, last + 1) < memory, 1.0, lam_f)
                w = np.append(np.cumprod(lam[::-1])[::-1][1:], 1.0)
                decay = float(np.prod(lam))
            w_sum, w_sq = float(w.sum()), float(w @ w)
        info = self._info  # in place; symmetric up to rounding (symmetrised when read)
        if decay != 1.0:
            info *= decay
            self._info_diag += self._ridge * (1.0 - decay)
        info += (z * w[:, None]).T @ z
        if self._u_cols.size and self.stabilize:  # their inputs over a short memory (test 5)
            lam_u = min(lam_f, 1.0 - 1.0 / (INPUT_RECENT_WINDOWS * 2 * self.layout.i))
            zu = z[:, self._u_cols]
            wu, decay_u, _, _ = self._weights(n, lam_u)
            self._u_recent *= decay_u
            self._u_recent += (zu * wu[:, None]).T @ zu
        self._sum_w = decay * self._sum_w + w_sum
        self._sum_w2 = decay**2 * self._sum_w2 + w_sq
        self._k += n

    def _start_holdoff(self) -> None:
        """The first realization starts a hold-off of one memory, as a detected change does:
        a model realized from fewer windows than its memory predicts fresh data worse than the
        data it was fitted to, and that rise is no change (random suite draws 15, 25: the
        young low group's information was discounted twice in its first second)."""
        self._holdoff = max(self._holdoff, self._holdoff_samples)

    @property
    def _holdoff_samples(self) -> int:
        """The detection hold-off after a change or the first realization: one memory,
        1 / (1 - lambda) samples (at most 1000)."""
        return int(round(min(self.memory_samples, 1000.0)))

    def _discount(self, c: float) -> None:
        """Keep a fraction c of the old information (R >= Delta is preserved)."""
        self._info *= c
        self._info_diag += (1.0 - c) * self._ridge
        self._sum_w *= c
        self._sum_w2 *= c * c

    @property
    def _gate_lambda(self) -> float:
        """Forgetting of the outlier gate's reference levels: the estimator's memory, but at most
        GATE_REFERENCE_WINDOWS change windows."""
        lam_ref = 1.0 - 1.0 / (GATE_REFERENCE_WINDOWS * self.change_window)
        return min(self.forgetting_factor, lam_ref)

    def _weights(self, n: int, lam: float) -> tuple[np.ndarray, float, float, float]:
        """(w, lam^n, sum w, w'w) with w_t = lam^(n-1-t), t = 0..n-1: the weights of n samples
        of exponential forgetting (cached: the blocks have a handful of lengths)."""
        key = (n, lam)
        hit = self._weight_cache.get(key)
        if hit is None:
            w = lam ** np.arange(n - 1, -1, -1.0)
            hit = (w, lam**n, float(w.sum()), float(w @ w))
            if len(self._weight_cache) >= 64:
                self._weight_cache.clear()
            self._weight_cache[key] = hit
        return hit

    def _ew_paths(self, sq: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The short- and long-term paths p_t = lam p_{t-1} + (1 - lam) sq_t over the rows t of
        sq, lam = 1 - 1/change_window and the forgetting factor (p_{-1} = _pe_short, _pe_ms; a
        NaN start takes the first sample).

        Closed form p = K sq + v p_{-1} with K_ts = (1 - lam) lam^(t-s) (s <= t) and
        v_t = lam^(t+1), the two paths in one batched product with K cached per pair of
        lambdas (for blocks up to a realization interval; lfilter for longer ones)."""
        lams = (1.0 - 1.0 / self.change_window, self.forgetting_factor)
        n = sq.shape[0]
        size = min(self.MAX_QUEUED, self.realization_interval)
        if n > size:
            return (self._ew_path(self._pe_short, sq, lams[0]),
                    self._ew_path(self._pe_ms, sq, lams[1]))
        if self._ew_kernel_of != lams:
            t = np.arange(size, dtype=float)
            lag = t[:, None] - t[None, :]
            lam = np.array(lams)[:, None, None]
            self._ew_kernel = np.where(lag >= 0, (1.0 - lam) * lam ** np.maximum(lag, 0.0), 0.0)
            self._ew_start = lam[:, :, 0] ** (t + 1.0)  # (2, N)
            self._ew_kernel_of = lams
        prev = np.stack((self._pe_short, self._pe_ms))
        if not np.isfinite(prev).all():
            prev = np.where(np.isfinite(prev), prev, sq[0])
        paths = self._ew_kernel[:, :n, :n] @ sq
        paths += self._ew_start[:, :n, None] * prev[:, None, :]
        return paths[0], paths[1]

    @staticmethod
    def _ew_path(prev: np.ndarray, sq: np.ndarray, lam: float) -> np.ndarray:
        """p_t = lam p_{t-1} + (1 - lam) sq_t for every row t of sq (p_{-1} = prev; a NaN start
        takes the first sample)."""
        p0 = np.where(np.isfinite(prev), prev, sq[0])
        return lfilter([1.0 - lam], [1.0, -lam], sq, axis=0, zi=lam * p0[None, :])[0]

    def _realize(self, offset_from_end: int) -> IdentifiedModel | None:
        t0 = time.perf_counter()
        lay = self.layout
        if self._k < 2 * self.max_order + lay.dim // 4:
            return None
        power = float(np.trace(self._info)) / lay.dim / max(self._sum_w, 1e-300)
        self._excited = power >= self.min_excitation
        if not self._excited:
            self.realizations_skipped += 1
            return None
        try:
            # rounding asymmetry never builds up (in place: _info_diag stays its diagonal)
            self._info += self._info.T
            self._info *= 0.5
            chol = linalg.cholesky(self._info, lower=True, check_finite=False)
            proj = project(chol, lay, self._sum_w, self._sum_w2)
            n = self.max_order
            if self.order_method is not None:
                n = select_order(proj, self.order_method, self.max_order)
            t_now = (self.samples_seen + offset_from_end) / self.fs
            mdl = model_from_projection(
                proj,
                n,
                self.fs,
                self._su if lay.m else np.zeros(0),
                self._sy,
                self.band,
                self.damping_bounds,
                self.max_modes,
                time_s=t_now,
                riccati=False,
                check=check_orders(n, lay.l * (lay.i - 1)) if self.stabilize else None,
                frequency_gate=None,
                recent_input_cov=self._u_recent if self._u_cols.size else None,
                reflect_unstable=True,
                memory_input_cov=self._info[np.ix_(self._u_cols, self._u_cols)]
                if self._u_cols.size else None,
            )
        except (linalg.LinAlgError, np.linalg.LinAlgError, ValueError):
            self.realizations_skipped += 1
            return None
        if not (np.all(np.isfinite(mdl.A)) and np.all(np.isfinite(mdl.C))):
            self.realizations_skipped += 1
            return None
        if self._theta1 is None:
            self._start_holdoff()
        self._theta1 = proj.theta[: lay.l].copy()
        self.model = mdl
        self.realization_count += 1
        self.last_realization_time = mdl.time_s
        self.last_realization_cost_s = time.perf_counter() - t0
        return mdl
