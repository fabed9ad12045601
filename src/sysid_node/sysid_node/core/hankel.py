"""Block Hankel matrices (A1) and the stacked past/future data used by (A2).

Column k of the stacked data matrix is the window of 2i consecutive samples
``z_k = [u_k..u_{k+i-1}; y_k..y_{k+i-1}; u_{k+i}..u_{k+2i-1}; y_{k+i}..y_{k+2i-1}]``, i.e. the
rows ``[U_{1|i}; Y_{1|i}; U_{i+1|2i}; Y_{i+1|2i}]`` of (A1)-(A2). Both the batch and the recursive
DSRA work on this one layout.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np
from numpy.lib.stride_tricks import as_strided, sliding_window_view


def block_hankel(x: np.ndarray, first: int, last: int, j: int) -> np.ndarray:
    """The block Hankel matrix Y_{first|last} of (A1) with j columns (1-based sample indices).

    ``x`` is (N, c); the result is ((last - first + 1) c, j), block row r holding
    samples first + r .. first + r + j - 1.
    """
    rows = last - first + 1
    win = sliding_window_view(x[first - 1 : last - 1 + j], rows, axis=0)  # (j, c, rows)
    return np.ascontiguousarray(win.transpose(2, 1, 0).reshape(rows * x.shape[1], j))


@dataclass(frozen=True)
class Layout:
    """Row layout of the stacked window z = [up; yp; uf; yf] for i block rows."""

    i: int
    m: int
    l: int

    @property
    def dim(self) -> int:
        return 2 * self.i * (self.m + self.l)

    @property
    def n_past(self) -> int:
        return self.i * (self.m + self.l)

    @property
    def up(self) -> slice:
        return slice(0, self.i * self.m)

    @property
    def yp(self) -> slice:
        return slice(self.i * self.m, self.n_past)

    @property
    def uf(self) -> slice:
        return slice(self.n_past, self.n_past + self.i * self.m)

    @property
    def yf(self) -> slice:
        return slice(self.n_past + self.i * self.m, self.dim)


@lru_cache(maxsize=64)
def window_order(i: int, m: int, l: int) -> np.ndarray:
    """Column permutation from a window in sample-major order (sample t, channel c at
    t (m + l) + c, channels [u; y]) to the (A1) order [u_p; y_p; u_f; y_f]."""
    idx = np.arange(2 * i * (m + l)).reshape(2 * i, m + l)
    return np.concatenate(
        [idx[:i, :m].ravel(), idx[:i, m:].ravel(), idx[i:, :m].ravel(), idx[i:, m:].ravel()]
    )


def window_rows(u: np.ndarray, y: np.ndarray, i: int) -> np.ndarray:
    """All windows z_k of 2i samples as rows: (N - 2i + 1, 2i(m + l)), the transpose of
    ``[U_{1|i}; Y_{1|i}; U_{i+1|2i}; Y_{i+1|2i}]`` of (A1)."""
    return window_rows_packed(np.hstack([u, y]), u.shape[1], i)


def window_rows_packed(data: np.ndarray, m: int, i: int) -> np.ndarray:
    """:func:`window_rows` of samples already packed as ``data = [u, y]`` (N, m + l): one
    strided view of the windows and one gather (cheap also for a single window)."""
    data = np.ascontiguousarray(data, dtype=float)
    n, width = data.shape
    j = n - 2 * i + 1
    if j <= 0:
        return np.zeros((0, 2 * i * width))
    step = data.strides[0]
    windows = as_strided(data, shape=(j, 2 * i * width), strides=(step, data.strides[1]),
                         writeable=False)
    return windows[:, window_order(i, m, width - m)]
