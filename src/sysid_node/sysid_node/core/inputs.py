"""Input validation shared by the batch and the recursive DSRA.

Bad data never produces a silently wrong estimate: shape errors, non-finite samples in batch data
and zero-variance channels raise :class:`InputError` (a ``ValueError``) with a one-line message;
the recursive estimator instead skips non-finite samples and counts them.
"""

from __future__ import annotations

import numpy as np


class InputError(ValueError):
    """Invalid identification data; ``str(err)`` is a one-line reason."""


def as_2d(x: np.ndarray, name: str, n_channels: int | None = None) -> np.ndarray:
    """``x`` as a float (N, channels) array; 1-D input is one channel."""
    try:
        a = np.asarray(x, dtype=float)
    except (TypeError, ValueError) as exc:
        raise InputError(f"{name} is not numeric: {exc}") from None
    if a.ndim == 1:
        a = a[:, None]
    if a.ndim != 2:
        raise InputError(f"{name} must be (N, channels), got shape {a.shape}")
    if n_channels is not None and a.shape[1] != n_channels:
        raise InputError(f"{name} must have {n_channels} channel(s), got {a.shape[1]}")
    return a


def check_rate(fs: float) -> float:
    fs = float(fs)
    if not np.isfinite(fs) or fs <= 0:
        raise InputError(f"sample rate must be a positive finite number, got {fs}")
    return fs


def validate_batch(
    y: np.ndarray, u: np.ndarray | None, block_rows: int
) -> tuple[np.ndarray, np.ndarray]:
    """Validated (y (N, l), u (N, m)) for batch identification; m = 0 when ``u`` is None."""
    y = as_2d(y, "y")
    u = np.zeros((y.shape[0], 0)) if u is None else as_2d(u, "u")
    if u.shape[0] != y.shape[0]:
        raise InputError(f"u has {u.shape[0]} samples but y has {y.shape[0]}")
    if y.shape[1] == 0:
        raise InputError("y has no channels")
    if block_rows < 1:
        raise InputError(f"block_rows must be >= 1, got {block_rows}")
    n_needed = 2 * block_rows + 2 * block_rows * (u.shape[1] + y.shape[1])
    if y.shape[0] < n_needed:
        raise InputError(
            f"need at least {n_needed} samples for block_rows={block_rows}, got {y.shape[0]}"
        )
    for name, a in (("y", y), ("u", u)):
        bad = ~np.isfinite(a)
        if bad.any():
            k, c = np.argwhere(bad)[0]
            raise InputError(
                f"{name} has {int(bad.sum())} NaN/Inf value(s), first at sample {k} channel {c}"
            )
        std = np.std(a, axis=0)
        flat = np.flatnonzero(std <= 1e-12 * np.maximum(1.0, np.abs(a).max(axis=0)))
        if flat.size:
            raise InputError(f"{name} channel(s) {flat.tolist()} have zero variance")
    return y, u


def finite_rows(*arrays: np.ndarray) -> np.ndarray:
    """Boolean mask of samples that are finite in every given (N, c) array."""
    ok = np.ones(arrays[0].shape[0], dtype=bool)
    for a in arrays:
        if a.shape[1]:
            ok &= np.isfinite(a).all(axis=1)
    return ok
