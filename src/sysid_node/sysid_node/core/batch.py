"""Batch DSRA (Appendix A of the paper): identify() -> IdentifiedModel."""

from __future__ import annotations

import numpy as np
from scipy import linalg

from .hankel import Layout, window_rows
from .inputs import InputError, check_rate, validate_batch
from .modal import extract_modes, select_modes
from .model import IdentifiedModel
from .order import max_order, select_order
from .realization import Projection, ShiftBasis, kalman_gain, project, realize, shift_poles
from .spurious import (
    INPUT_EXCITED_LEVEL,
    check_orders,
    flag_spurious,
    input_concentration,
    input_own,
    noise_peak_threshold,
    overfit_threshold,
    pole_frequencies,
)


def identify(
    y: np.ndarray,
    u: np.ndarray | None = None,
    fs: float = 1.0,
    order: int | None = None,
    block_rows: int | None = None,
    order_method: str = "bic",
    band: tuple[float, float] | None = None,
    max_modes: int | None = None,
    damping_bounds: tuple[float, float] | None = (0.0, 0.5),
) -> IdentifiedModel:
    """Identify a discrete innovation-form model from outputs y (N, l) and inputs u (N, m).

    ``u=None`` is the output-only (stochastic) case. ``block_rows`` is i of (A1) (default
    :func:`auto_block_rows`); ``order`` fixes the model order, otherwise it is chosen by
    ``order_method`` (default BIC, see :func:`~sysid_node.core.order.select_order`) up to
    ORDER_PER_MODE x ``max_modes`` when that is given. The modes are flagged by the
    spurious-mode tests (``spurious.py``, check orders around the chosen one). Channels are
    scaled to unit variance before the projection (the model is returned in physical units).
    ``band`` [Hz], ``damping_bounds`` and ``max_modes`` select the reported modes (stable ones
    first). Raises :class:`~sysid_node.core.inputs.InputError` on bad data.

    Why BIC by default: the singular-value gap picks the largest drop, which in multi-channel
    ambient data is often after the first few dominant modes (the real steel frame, 5 outputs,
    8 modes: gap order 18 with 3 of 8 modes within 0.5 %; BIC order 79-85, all 8), and the
    randomized scenario suite finds more true modes with BIC (``benchmarks/random_suite_figures
    .py --batch``).
    """
    fs = check_rate(fs)
    if block_rows is None:
        n = np.asarray(y).shape[0]
        l = np.asarray(y).reshape(n, -1).shape[1]
        m = 0 if u is None else np.asarray(u).reshape(n, -1).shape[1]
        block_rows = auto_block_rows(n, m, l)
    y, u = validate_batch(y, u, block_rows)
    if block_rows < 2:
        raise InputError("block_rows must be >= 2")
    su, sy = np.std(u, axis=0), np.std(y, axis=0)
    z = window_rows(u / su, y / sy, block_rows)
    r_fac = linalg.qr(z, mode="r", check_finite=False)[0]  # Z' = Q R  ->  Z = L Q', L = R'
    lay = Layout(block_rows, u.shape[1], y.shape[1])
    proj = project(np.ascontiguousarray(r_fac[: lay.dim].T), lay, z.shape[0], z.shape[0])
    n_top = max_order(proj)
    if order is None:
        cap = n_top if max_modes is None else min(n_top, ORDER_PER_MODE * max_modes)
        order = select_order(proj, order_method, cap)
    if not 1 <= order <= n_top:
        raise InputError(f"order must be in [1, {n_top}] for block_rows={block_rows}")
    return model_from_projection(proj, order, fs, su, sy, band, damping_bounds, max_modes,
                                 check=check_orders(order, n_top))


#: Automatic block rows of the batch DSRA aim at this many rows of the stacked window 2 i (m + l)
#: (the past must span the slow modes: 40 rows of 5 channels at 256 Hz cover 0.16 s, a fifth of
#: the period of a 1.2 Hz mode; 20 rows did not hold it)...
BATCH_WINDOW_ROWS = 400
#: ...with at least this many windows (columns of (A1)) per row of the stacked window.
BATCH_WINDOWS_PER_ROW = 4
#: Largest automatic model order per reported mode when ``max_modes`` bounds the search.
ORDER_PER_MODE = 4


def auto_block_rows(n_samples: int, n_inputs: int, n_outputs: int) -> int:
    """Block rows i for the batch: about BATCH_WINDOW_ROWS rows in the stacked window, between
    10 and 50, fewer when the data do not hold BATCH_WINDOWS_PER_ROW windows per row."""
    width = 2 * (n_inputs + n_outputs)
    i = min(max(round(BATCH_WINDOW_ROWS / width), 10), 50)
    i_data = (n_samples + 1) // (2 + BATCH_WINDOWS_PER_ROW * width)
    return max(2, min(i, i_data))


def model_from_projection(
    proj: Projection,
    order: int,
    fs: float,
    su: np.ndarray,
    sy: np.ndarray,
    band: tuple[float, float] | None,
    damping_bounds: tuple[float, float] | None,
    max_modes: int | None,
    time_s: float = float("nan"),
    riccati: bool = True,
    check: list[int] | None = None,
    frequency_gate: float | None = 0.05,
    recent_input_cov: np.ndarray | None = None,
    reflect_unstable: bool = False,
    memory_input_cov: np.ndarray | None = None,
) -> IdentifiedModel:
    """Realize order ``order`` from a projection of scaled data and undo the channel scaling.

    ``riccati`` selects the Kalman gain from the Riccati equation (else K = S R^{-1}, cheaper).
    ``check``: model orders whose poles flag the spurious modes (``spurious.py``, with the
    tracking ``frequency_gate``, None: no determined-frequency test); the stable modes then
    come first when ``max_modes`` cuts. ``recent_input_cov``: the covariance of the recent
    windows' inputs, for the test that a pole pair is not the input's own
    (:func:`~sysid_node.core.spurious.input_own`; None: not run). ``memory_input_cov``: the
    same over the estimator's memory; a pole pair where that input did not excite the system
    is no candidate for lifting the overfit-level test (``spurious.py``; None: not checked).
    ``reflect_unstable``: see :func:`~sysid_node.core.modal.extract_modes`.
    """
    check = [c for c in (check or []) if 1 <= c <= max_order(proj) and c != order]
    basis = ShiftBasis(proj, max([order, *check]))
    rz = realize(proj, order, basis)
    k_s, re_s = kalman_gain(rz.A, rz.C, rz.Q, rz.S, rz.R, riccati)
    m, l = rz.B.shape[1], rz.C.shape[0]
    drive = np.zeros((m + l, m + l))
    drive[:m, :m] = rz.u_cov
    drive[m:, m:] = re_s
    sy_m, su_inv = np.diag(sy), np.diag(1.0 / su) if m else np.zeros((0, 0))
    modes, real_poles = extract_modes(
        rz.A,
        rz.C * sy[:, None],
        fs,
        b_all=np.hstack([rz.B, k_s]),
        drive_cov=drive,
        a_cov_rows=rz.a_cov_rows,
        a_cov_cols=rz.a_cov_cols,
        noise_cov=sy_m @ rz.R @ sy_m,
        band=band,
        damping_bounds=damping_bounds,
        reflect_unstable=reflect_unstable,
    )
    if check:
        freqs = [pole_frequencies(p, fs) for p in shift_poles(basis, check)]
        width = fs / 2 if band is None else min(band[1], fs / 2) - band[0]
        n_eff = proj.sum_w**2 / max(proj.sum_w2, 1e-300)  # effective number of windows
        lay = proj.layout
        f_modes = np.array([md.frequency_hz for md in modes])
        flag_spurious(
            modes,
            freqs,
            frequency_gate,
            noise_peak_threshold(width, n_eff / fs),
            overfit_threshold(lay.n_past + lay.i * lay.m, lay.l, n_eff),
            None if recent_input_cov is None else input_own(recent_input_cov, lay.m, f_modes, fs),
            fs / (2 * lay.i),
            None if memory_input_cov is None else (
                input_concentration(memory_input_cov, lay.m, f_modes, fs) >= INPUT_EXCITED_LEVEL),
        )
    modes = select_modes(modes, None, None, max_modes)
    return IdentifiedModel(
        A=rz.A,
        B=rz.B @ su_inv,
        C=sy_m @ rz.C,
        D=sy_m @ rz.D @ su_inv,
        K=k_s / sy[None, :],
        Q=rz.Q,
        R=sy_m @ rz.R @ sy_m,
        S=rz.S * sy[None, :],
        innovation_covariance=sy_m @ re_s @ sy_m,
        fs=fs,
        order=order,
        singular_values=proj.singular_values,
        n_inputs=m,
        n_outputs=l,
        modes=modes,
        real_poles=real_poles,
        input_covariance=np.diag(su) @ rz.u_cov @ np.diag(su) if m else np.zeros((0, 0)),
        time_s=time_s,
    )
