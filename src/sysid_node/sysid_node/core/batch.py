"""Batch DSRA (Appendix A of the paper): identify() -> IdentifiedModel."""

from __future__ import annotations

import numpy as np
from scipy import linalg

from .hankel import Layout, window_rows
from .inputs import InputError, check_rate, validate_batch
from .modal import extract_modes
from .model import IdentifiedModel
from .order import max_order, select_order
from .realization import Projection, kalman_gain, project, realize


def identify(
    y: np.ndarray,
    u: np.ndarray | None = None,
    fs: float = 1.0,
    order: int | None = None,
    block_rows: int = 20,
    order_method: str = "gap",
    band: tuple[float, float] | None = None,
    max_modes: int | None = None,
    damping_bounds: tuple[float, float] | None = (0.0, 0.5),
) -> IdentifiedModel:
    """Identify a discrete innovation-form model from outputs y (N, l) and inputs u (N, m).

    ``u=None`` is the output-only (stochastic) case. ``block_rows`` is i of (A1); ``order``
    fixes the model order, otherwise it is chosen by ``order_method`` (see
    :func:`~sysid_node.core.order.select_order`) up to 2 ``max_modes`` when that is given.
    Channels are scaled to unit variance before the projection (the model is returned in
    physical units). ``band`` [Hz], ``damping_bounds`` and ``max_modes`` select the reported
    modes. Raises :class:`~sysid_node.core.inputs.InputError` on bad data.
    """
    fs = check_rate(fs)
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
        cap = n_top if max_modes is None else min(n_top, 2 * max_modes)
        order = select_order(proj, order_method, cap)
    if not 1 <= order <= n_top:
        raise InputError(f"order must be in [1, {n_top}] for block_rows={block_rows}")
    return model_from_projection(proj, order, fs, su, sy, band, damping_bounds, max_modes)


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
) -> IdentifiedModel:
    """Realize order ``order`` from a projection of scaled data and undo the channel scaling.

    ``riccati`` selects the Kalman gain from the Riccati equation (else K = S R^{-1}, cheaper).
    """
    rz = realize(proj, order)
    k_s, re_s = kalman_gain(rz.A, rz.C, rz.Q, rz.S, rz.R, riccati)
    b_all = np.hstack([rz.B, k_s])
    m, l = rz.B.shape[1], rz.C.shape[0]
    drive = np.zeros((m + l, m + l))
    drive[:m, :m] = rz.u_cov
    drive[m:, m:] = re_s
    modes, real_poles = extract_modes(
        rz.A,
        rz.C * sy[:, None],
        fs,
        b_all=b_all,
        drive_cov=drive,
        a_cov_rows=rz.a_cov_rows,
        a_cov_cols=rz.a_cov_cols,
        band=band,
        damping_bounds=damping_bounds,
        max_modes=max_modes,
    )
    sy_m, su_inv = np.diag(sy), np.diag(1.0 / su) if m else np.zeros((0, 0))
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
