"""Which samples estimate the model and which validate it.

The default is chronological: the first ``fraction`` of the record estimates, the rest
validates. That assumes the input is stationary: a sine sweep puts different frequencies in the
two parts, and no model can predict a band its estimation data never excited. When the
validation part's input has a significant share of its power (:data:`UNCOVERED_SHARE`) in
bands where the estimation part's input is more than 20 dB below its peak, the split is
interleaved instead: the record is cut into blocks and each block's first ``fraction``
estimates, its rest validates, so both parts see every band the input covers.

Models are always run over the whole record (the free run from the first sample, the one-step
predictor everywhere); only the samples that are fitted or scored change.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import signal

from .data import ValidationData, ValidationError

UNCOVERED_DB = 20.0
UNCOVERED_SHARE = 0.1
MAX_BLOCKS = 20


def runs(idx: np.ndarray) -> list[tuple[int, int]]:
    """Contiguous runs [a, b) of sorted sample indices."""
    if idx.size == 0:
        return []
    cut = np.flatnonzero(np.diff(idx) > 1)
    starts = np.r_[idx[0], idx[cut + 1]]
    stops = np.r_[idx[cut] + 1, idx[-1] + 1]
    return [(int(a), int(b)) for a, b in zip(starts, stops, strict=True)]


@dataclass
class Split:
    """Estimation and validation samples (sorted indices) of a record of ``n`` samples."""

    n: int
    est: np.ndarray
    val: np.ndarray
    mode: str = "chronological"  # or "interleaved"
    reason: str = ""

    @property
    def n_est(self) -> int:
        return int(self.est.size)

    @property
    def n_val(self) -> int:
        return int(self.val.size)

    @property
    def est_segments(self) -> list[tuple[int, int]]:
        return runs(self.est)

    @property
    def val_segments(self) -> list[tuple[int, int]]:
        return runs(self.val)

    @property
    def est_mask(self) -> np.ndarray:
        m = np.zeros(self.n, bool)
        m[self.est] = True
        return m

    def inner(self, held_out: float) -> Split:
        """A split of the estimation samples alone: the last ``held_out`` of each estimation
        segment is held out (for choosing the order and horizon)."""
        fit, sel = [], []
        for a, b in self.est_segments:
            k = a + int(round((1.0 - held_out) * (b - a)))
            fit.append(np.arange(a, k))
            sel.append(np.arange(k, b))
        return Split(self.n, np.concatenate(fit), np.concatenate(sel), self.mode)

    def summary(self) -> dict:
        return {
            "mode": self.mode,
            "estimation_samples": self.n_est,
            "validation_samples": self.n_val,
            "blocks": len(self.val_segments),
            "reason": self.reason,
        }


def chronological(n: int, k: int, reason: str = "") -> Split:
    return Split(n, np.arange(k), np.arange(k, n), "chronological", reason)


def interleaved(n: int, fraction: float, blocks: int, reason: str = "") -> Split:
    """Blocks of n / ``blocks`` samples, each: first ``fraction`` estimation, rest validation."""
    edges = np.linspace(0, n, blocks + 1).round().astype(int)
    est, val = [], []
    for a, b in zip(edges[:-1], edges[1:], strict=True):
        k = a + int(round(fraction * (b - a)))
        est.append(np.arange(a, k))
        val.append(np.arange(k, b))
    return Split(n, np.concatenate(est), np.concatenate(val), "interleaved", reason)


def uncovered_share(u: np.ndarray, est: np.ndarray, val: np.ndarray, fs: float) -> float:
    """Share of the validation input's power in bins where the estimation input is more than
    :data:`UNCOVERED_DB` below its own peak (largest over input channels)."""
    if u.shape[1] == 0:
        return 0.0
    nper = int(min(256, max(16, est.size // 8), max(16, val.size // 4)))
    worst = 0.0
    for j in range(u.shape[1]):
        _, pe = signal.welch(u[est, j], fs=fs, nperseg=min(nper, est.size))
        _, pv = signal.welch(u[val, j], fs=fs, nperseg=min(nper, val.size))
        if pe.size != pv.size or pv.sum() <= 0 or pe.max() <= 0:
            continue
        low = pe < pe.max() * 10 ** (-UNCOVERED_DB / 10)
        worst = max(worst, float(pv[low].sum() / pv.sum()))
    return worst


def make_split(data: ValidationData, split: float, min_est: int, mode: str = "auto") -> Split:
    """The split of ``--split`` (a fraction, or the first validation sample when > 1) and
    ``--split-mode`` (auto / chronological / interleaved)."""
    n = data.n
    if split > 1:
        if split != int(split):
            raise ValidationError(f"--split above 1 is a sample index, got {split}")
        fraction = int(split) / n
    else:
        fraction = float(split)
    if not 0.05 <= fraction <= 0.95:
        raise ValidationError(f"--split must be in [0.05, 0.95] (or a sample index), got {split}")
    k = int(round(fraction * n))
    need_val = max(50, min_est // 4)
    if k < min_est or n - k < need_val:
        raise ValidationError(
            f"record too short to split: {n} samples, split {split} gives {k} for estimation "
            f"(need {min_est}) and {n - k} for validation (need {need_val})"
        )
    chrono = chronological(n, k)
    if mode == "chronological":
        return chrono
    blocks = int(max(2, min(MAX_BLOCKS, n // (4 * min_est) if min_est else MAX_BLOCKS)))
    if mode == "interleaved":
        return interleaved(n, fraction, blocks, "asked for (--split-mode interleaved)")
    share = uncovered_share(data.u, chrono.est, chrono.val, data.fs)
    if share <= UNCOVERED_SHARE or blocks < 2:
        return chrono
    return interleaved(
        n,
        fraction,
        blocks,
        f"{100 * share:.0f} % of the validation input's power lies where the first "
        f"{100 * fraction:.0f} % of the record has none (a sweep?): {blocks} interleaved blocks",
    )
