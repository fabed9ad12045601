"""Sensor and data faults as transformations of a :class:`Stream` (stamps, values, channel names).

Every function returns a new stream (the input is not modified) whose ``altered`` mask marks the
samples a fault touched or inserted, so a test can check that everything else came through.

* values: :func:`nonfinite` (NaN / Inf samples), :func:`spikes` (finite outliers of k sigma),
  :func:`burst` (a stretch scaled by 1e12), :func:`saturate` (clipping at rails),
  :func:`stuck` (a channel frozen at its last value), :func:`dead` (a channel at zero, e.g. a dead
  excitation);
* stamps: :func:`gap` (samples missing), :func:`duplicate`, :func:`out_of_order` (neighbours
  swapped), :func:`future_stamp` (one sample stamped far ahead), :func:`stamp_jump` (the clock
  jumps by a constant from some sample on), :func:`rate_change` (another sample spacing from some
  sample on);
* channels: :func:`reorder_channels`, :func:`rename_channels`, :func:`change_channel_count`
  (returns the stream before and after the change: a different width cannot share one array).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np


@dataclass(frozen=True)
class Stream:
    """Samples of one topic: ``stamps_ns`` (N,) int64, ``values`` (N, channels), ``names``."""

    stamps_ns: np.ndarray
    values: np.ndarray
    names: tuple[str, ...]
    altered: np.ndarray | None = None

    def __post_init__(self) -> None:
        stamps = np.asarray(self.stamps_ns, dtype=np.int64)
        values = np.asarray(self.values, dtype=float)
        values = values.reshape(len(values), -1)
        if stamps.shape != (values.shape[0],):
            raise ValueError(f"{stamps.shape[0]} stamps for {values.shape[0]} samples")
        names = tuple(self.names) or tuple(f"ch{i}" for i in range(values.shape[1]))
        if len(names) != values.shape[1]:
            raise ValueError(f"{len(names)} names for {values.shape[1]} channels")
        altered = (np.zeros(stamps.size, bool) if self.altered is None
                   else np.asarray(self.altered, bool))
        for key, val in (("stamps_ns", stamps), ("values", values), ("names", names),
                         ("altered", altered)):
            object.__setattr__(self, key, val)

    @classmethod
    def uniform(cls, values: np.ndarray, fs: float, start_ns: int = 1_700_000_000_000_000_000,
                names=()) -> Stream:
        """Samples at ``fs`` [Hz] from ``start_ns``."""
        values = np.asarray(values, dtype=float).reshape(len(values), -1)
        stamps = start_ns + np.round(np.arange(len(values)) * 1e9 / fs).astype(np.int64)
        return cls(stamps, values, tuple(names))

    def __len__(self) -> int:
        return self.stamps_ns.size

    def _with(self, mask: np.ndarray | None = None, **changes) -> Stream:
        altered = changes.pop("altered", self.altered.copy())
        if mask is not None:
            altered = altered | mask
        return replace(self, altered=altered, **changes)


def _pick(n: int, rng: np.random.Generator | None, count: int | None,
          indices=None) -> np.ndarray:
    if indices is not None:
        return np.asarray(indices, dtype=int)
    if rng is None or count is None:
        raise ValueError("give indices, or rng and count")
    return np.sort(rng.choice(n, size=min(count, n), replace=False))


def _mask(n: int, idx: np.ndarray) -> np.ndarray:
    m = np.zeros(n, bool)
    m[idx] = True
    return m


def nonfinite(s: Stream, rng=None, count: int | None = None, indices=None,
              value: float = np.nan, channel: int | None = None) -> Stream:
    """``value`` (NaN, +-Inf) at ``indices`` (or ``count`` random samples), on ``channel`` or
    all channels."""
    idx = _pick(len(s), rng, count, indices)
    v = s.values.copy()
    v[idx, slice(None) if channel is None else channel] = value
    return s._with(_mask(len(s), idx), values=v)


def spikes(s: Stream, rng: np.random.Generator, count: int, k_sigma: float = 10.0,
           indices=None) -> Stream:
    """Finite outliers: +-``k_sigma`` channel standard deviations added at ``count`` samples."""
    idx = _pick(len(s), rng, count, indices)
    v = s.values.copy()
    std = np.nanstd(np.where(np.isfinite(v), v, np.nan), axis=0)
    v[idx] += k_sigma * std * rng.choice([-1.0, 1.0], size=(idx.size, v.shape[1]))
    return s._with(_mask(len(s), idx), values=v)


def burst(s: Stream, start: int, length: int, scale: float = 1e12) -> Stream:
    """Samples ``start .. start + length`` multiplied by ``scale`` (finite garbage)."""
    v = s.values.copy()
    v[start : start + length] *= scale
    m = np.zeros(len(s), bool)
    m[start : start + length] = True
    return s._with(m, values=v)


def saturate(s: Stream, low: float, high: float) -> Stream:
    """Values clipped to the rails ``[low, high]``; clipped samples are marked."""
    v = np.clip(s.values, low, high)
    m = np.any((s.values < low) | (s.values > high), axis=1)
    return s._with(m, values=v)


def stuck(s: Stream, channel: int, start: int, value: float | None = None) -> Stream:
    """``channel`` frozen from sample ``start`` on (at ``value``, default its value there)."""
    v = s.values.copy()
    v[start:, channel] = v[start, channel] if value is None else value
    m = np.zeros(len(s), bool)
    m[start:] = True
    return s._with(m, values=v)


def dead(s: Stream, channel: int, start: int = 0) -> Stream:
    """``channel`` at zero from ``start`` on (e.g. an excitation channel that stopped)."""
    return stuck(s, channel, start, 0.0)


def gap(s: Stream, start: int, length: int) -> Stream:
    """Samples ``start .. start + length`` removed (a hole in the stamps)."""
    keep = np.ones(len(s), bool)
    keep[start : start + length] = False
    return s._with(None, stamps_ns=s.stamps_ns[keep], values=s.values[keep],
                   altered=s.altered[keep])


def duplicate(s: Stream, indices) -> Stream:
    """A second copy of each sample at ``indices`` right after it (copies marked)."""
    idx = np.asarray(indices, dtype=int)
    order = np.sort(np.concatenate([np.arange(len(s)), idx]), kind="stable")
    copy = np.r_[False, order[1:] == order[:-1]]
    return s._with(None, stamps_ns=s.stamps_ns[order], values=s.values[order],
                   altered=s.altered[order] | copy)


def out_of_order(s: Stream, indices) -> Stream:
    """Samples ``i`` and ``i + 1`` swapped (arrival order) for each ``i`` in ``indices``."""
    order = np.arange(len(s))
    for i in np.asarray(indices, dtype=int):
        order[[i, i + 1]] = order[[i + 1, i]]
    m = np.zeros(len(s), bool)
    m[np.asarray(indices, dtype=int)] = True
    m[np.asarray(indices, dtype=int) + 1] = True
    return s._with(None, stamps_ns=s.stamps_ns[order], values=s.values[order],
                   altered=s.altered[order] | m)


def future_stamp(s: Stream, index: int, ahead_s: float = 3600.0) -> Stream:
    """Sample ``index`` stamped ``ahead_s`` seconds in the future (a corrupt stamp)."""
    st = s.stamps_ns.copy()
    st[index] += int(round(ahead_s * 1e9))
    return s._with(_mask(len(s), np.array([index])), stamps_ns=st)


def stamp_jump(s: Stream, start: int, jump_s: float) -> Stream:
    """All stamps from sample ``start`` on shifted by ``jump_s`` [s] (negative: the clock goes
    back, e.g. a looped bag)."""
    st = s.stamps_ns.copy()
    st[start:] += int(round(jump_s * 1e9))
    m = np.zeros(len(s), bool)
    m[start] = True
    return s._with(m, stamps_ns=st)


def rate_change(s: Stream, start: int, fs_new: float) -> Stream:
    """From sample ``start`` on the samples are spaced 1 / ``fs_new`` (the values are kept: the
    sensor changed its rate mid-stream)."""
    st = s.stamps_ns.copy()
    k = np.arange(len(s) - start)
    st[start:] = st[start] + np.round(k * 1e9 / fs_new).astype(np.int64)
    return s._with(None, stamps_ns=st)


def reorder_channels(s: Stream, order) -> Stream:
    """Channels (and their names) in the order ``order``."""
    order = list(order)
    return s._with(None, values=s.values[:, order], names=tuple(s.names[i] for i in order))


def rename_channels(s: Stream, mapping: dict[str, str]) -> Stream:
    """Channel names replaced as in ``mapping``."""
    return s._with(None, names=tuple(mapping.get(n, n) for n in s.names))


def change_channel_count(s: Stream, start: int, channels: int) -> tuple[Stream, Stream]:
    """(stream before ``start``, stream from ``start`` on with ``channels`` channels: the first
    ones kept, extra ones zero)."""
    before = Stream(s.stamps_ns[:start], s.values[:start], s.names, s.altered[:start])
    v = np.zeros((len(s) - start, channels))
    keep = min(channels, s.values.shape[1])
    v[:, :keep] = s.values[start:, :keep]
    names = tuple(s.names[:keep]) + tuple(f"ch{i}" for i in range(keep, channels))
    return before, Stream(s.stamps_ns[start:], v, names, np.ones(len(s) - start, bool))
