"""Automatic frequency band: where does the response have structure above its noise floor?

Used when no band is configured (``freq_max: 0``, issue #10 item 3). The recursive DSRA of
Mehra & Prasanth (2004) identifies every mode of the data in ``[0, 0.4 fs]``: a 256 Hz record
whose modes lie below 10 Hz is then identified over 0-100 Hz with a model order spent on noise,
and at a rate whose Hankel horizon (block rows i over fs, Eq. (A1)) is too short for the lowest
modes. This module finds the band from the data, with no model:

1. the Welch power spectral density of each output (Hann segments of ``nperseg`` samples,
   half overlap), normalised by that channel's robust *noise floor*: the ``FLOOR_QUANTILE``
   quantile of its PSD over the bins in ``(0, fs/2]`` (a measurement noise floor is the lowest
   level of a spectrum; structure only adds to it);
2. a bin has *structure* when it is a peak (not below its neighbours) of the largest ratio
   over the outputs and exceeds ``STRUCTURE_RATIO`` times the floor (with at least ``MIN_SEGMENTS``
   averaged segments a noise bin reaches half that ratio with a probability far below 1e-6
   per bin), or a line of a measured input (``INPUT_LINE`` above its surroundings: a
   broadband input's level says where it excites, not where the structure is);
3. the band reaches ``EDGE_MARGIN`` above the upper edge of the highest such bin,
   so that a mode may rise before the band has to widen, and never above ``0.4 fs``;
4. the lowest mode: the lower edge of the lowest bin of an *output* with structure that rises
   from below (``LOW_PROMINENCE`` above the lowest ratio within ``PEAK_SPAN`` below it: a
   drift's spectrum, falling from DC, does not; a mode's peak or its rising flank does - with
   the coarse bins of 4 s of data, closely spaced low modes need not make peaks of their own);
   that bin is a flank below the mode or the mode's own bin, so its lower edge is below it.
   The first bins have no bins below them: when they hold structure (a 2 Hz mode at 400 Hz
   is in the first 1.7 Hz bin of 4 s of data), the test runs again below them on a spectrum of
   ``FINE_SEGMENTS`` segments with ``FINE_PROMINENCE`` (:func:`_fine_low`). The
   pipeline gives the Hankel window half of its period (a full one output-only from one
   output; ``params.effective_block_rows``: block
   rows that span a few milliseconds see a mode of a period of hundreds as a slow trend, not
   as an oscillation) and the memory ``memory_periods`` of them (``params.effective_lambda``).

The test errs on the safe side: anything above the floor that is not a mode (a flat
accelerometer feed-through, rising sensor noise, an excitation's own peaks) only widens the
band back towards ``0.4 fs``, which is what a configured ``freq_max: 0`` gave before. The
pipeline (``pipeline.py``) decimates to match the band (``decimation.auto_factor``) and rechecks
it as data come (the band only widens, its lowest peak only moves down; see ``params.py``,
``freq_max``, and ``Pipeline._recheck_low``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy import signal

#: The band reaches this factor (half an octave) above the highest bin with structure.
EDGE_MARGIN = 1.5
#: Largest band edge as a fraction of the sample rate (80 % of Nyquist).
MAX_EDGE_FRACTION = 0.4
#: A bin has structure when its PSD exceeds the noise floor by this factor (about 9 dB).
STRUCTURE_RATIO = 8.0
#: Quantile of a channel's PSD over frequency taken as its noise floor.
FLOOR_QUANTILE = 0.05
#: Fewest Welch segments averaged (fewer: no band is chosen from these data).
MIN_SEGMENTS = 7
#: Span (relative frequency, at least PEAK_MIN_BINS bins) of the prominence test of a peak.
PEAK_SPAN = 0.1
PEAK_MIN_BINS = 3
#: Longest Welch segment [samples] (finer resolution than fs/1024 is not needed for the edge).
MAX_SEGMENT = 1024
#: The lowest mode's peak stands this factor above the lowest ratio beside it (see _peaks).
LOW_PROMINENCE = 2.0
#: A measured input counts where it has lines standing this factor above the lowest ratio
#: within PEAK_SPAN on both sides (a multisine's, a narrow-band excitation's): a broadband input
#: (white, coloured, swept) is above its own 5 % quantile almost everywhere below its cut-off
#: and would hold the band at 0.4 fs whatever the response shows (a Welch bin of >= 7 segments
#: reaches 8 x its neighbours' minimum by chance far below 1e-6).
INPUT_LINE = 8.0
#: Fewest segments of the fine spectrum that looks below the coarse bins for the lowest mode.
FINE_SEGMENTS = 3
#: Prominence of the lowest mode's rise in the fine spectrum (few averages: a noise bin stands
#: 16 x above the lowest of the bins below it with a probability of a few per mille).
FINE_PROMINENCE = 16.0
#: A peak that counts for the split stands this factor above the lowest ratio on both sides.
PEAK_PROMINENCE = 2.0
#: A band wider than this many times its lowest peak is split (``split_frequency``) ...
SPLIT_SPAN = 20.0
#: ... at the widest gap between successive structure peaks, when it is at least this ratio
#: and this many Welch bins.
SPLIT_GAP = 2.0
SPLIT_MIN_BINS = 4


@dataclass(frozen=True)
class BandChoice:
    """Result of :func:`structure_band`: ``fmax_hz`` the upper band edge [Hz] (``0.4 fs`` when
    no structure was found or the data are too short), ``top_hz`` the upper edge of the
    highest bin with structure (NaN if none), ``resolution_hz`` the Welch bin width,
    ``low_hz`` the lower edge of the lowest output bin with structure rising from below (NaN if
    none): about the lowest mode's frequency."""

    fmax_hz: float
    top_hz: float
    resolution_hz: float
    low_hz: float = math.nan
    #: centres of the output bins with structure that are clear peaks (``PEAK_PROMINENCE``) [Hz]
    peaks_hz: tuple[float, ...] = ()

    @property
    def found(self) -> bool:
        return bool(math.isfinite(self.top_hz))


def segment_length(n_samples: int) -> int:
    """Welch segment length for ``n_samples``: the largest power of two with at least
    ``MIN_SEGMENTS`` half-overlapping segments, at most ``MAX_SEGMENT``; 0 when shorter than
    16 samples per segment."""
    longest = 2 * n_samples // (MIN_SEGMENTS + 1)
    if longest < 16:
        return 0
    return int(min(MAX_SEGMENT, 1 << (longest.bit_length() - 1)))


def structure_ratio(y: np.ndarray, fs: float) -> tuple[np.ndarray, np.ndarray]:
    """(f, ratio): bin frequencies [Hz] and, per bin, the largest over the channels of the PSD
    over that channel's noise floor; empty arrays when the data are too short."""
    f, ratio = _channel_ratios(y, fs)
    return f, ratio.max(axis=1) if f.size else ratio


def _channel_ratios(y: np.ndarray, fs: float) -> tuple[np.ndarray, np.ndarray]:
    """(f, ratio (bins, channels)): each channel's PSD over its own noise floor."""
    y = np.asarray(y, dtype=float)
    y = y.reshape(len(y), -1)
    nseg = segment_length(y.shape[0])
    if nseg == 0 or not np.all(np.isfinite(y)):
        return np.zeros(0), np.zeros(0)
    f, p = signal.welch(y, fs=fs, nperseg=nseg, axis=0, detrend="constant")
    f, p = f[1:], p[1:]  # the DC bin holds offsets and drift, not structure
    floor = np.quantile(p, FLOOR_QUANTILE, axis=0)
    ok = floor > 0  # a constant channel has no floor and no structure
    ratio = np.zeros_like(p)
    ratio[:, ok] = p[:, ok] / floor[ok]
    return f, ratio


def structure_band(y: np.ndarray, u: np.ndarray | None, fs: float,
                   prominence: float = 1.0, ratio_factor: float = 1.0,
                   fmin_hz: float = 0.0) -> BandChoice:
    """The band ``[0, fmax]`` for the outputs ``y`` (N, l) and the inputs ``u`` (N, m) or None
    sampled at ``fs`` [Hz]. A measured input's lines count too (:data:`INPUT_LINE`): a
    multisine's lines are where the response is excited, so the band reaches above them; its
    broadband level does not (the response shows where a broadband input excites structure).
    ``prominence``: see :func:`_peaks`; ``ratio_factor`` multiplies ``STRUCTURE_RATIO`` (the
    pipeline's rechecks, which may widen the band and rebuild the estimator, ask for clear
    evidence: 2 and 4; the first choice takes every peak above the ratio). ``fmin_hz``: the
    user's lower band edge (``freq_min``); structure below it is not looked at (the band's top
    and lowest peak are those of what will be identified)."""
    full = MAX_EDGE_FRACTION * fs
    y = np.asarray(y, dtype=float).reshape(len(y), -1)
    n_out = y.shape[1]
    if u is not None and np.size(u):
        y = np.hstack([y, np.asarray(u, dtype=float).reshape(len(y), -1)])
    f, ratios = _channel_ratios(y, fs)
    if f.size == 0:
        return BandChoice(full, math.nan, math.nan)
    df = float(f[1] - f[0]) if f.size > 1 else float(f[0])
    ratios[f < fmin_hz] = 0.0  # excluded by the user: no structure there
    out = ratios[:, :n_out].max(axis=1)
    low = np.flatnonzero(_rising(out, LOW_PROMINENCE) & (out > ratio_factor * STRUCTURE_RATIO))
    low_hz = float(f[low[0]] - 0.5 * df) if low.size else math.nan  # the bin's lower edge
    if np.any(out[:PEAK_MIN_BINS] > ratio_factor * STRUCTURE_RATIO):
        fine = _fine_low(y[:, :n_out], fs, f[PEAK_MIN_BINS - 1] + 0.5 * df,
                         ratio_factor * STRUCTURE_RATIO, fmin_hz)
        if math.isfinite(fine) and not fine >= low_hz:
            low_hz = fine
    level = ratio_factor * STRUCTURE_RATIO
    hit = _peaks(out, prominence) & (out > level)
    clear = _peaks(out, PEAK_PROMINENCE)
    clear[:PEAK_MIN_BINS] = True  # the first bins have too few below for a prominence
    peaks = tuple(float(x) for x in f[clear & (out > level)])
    if ratios.shape[1] > n_out:  # an input's lines, not its broadband level (see INPUT_LINE)
        inp = ratios[:, n_out:].max(axis=1)
        hit |= _peaks(inp, max(prominence, INPUT_LINE)) & (inp > level)
    hit = np.flatnonzero(hit)
    if hit.size == 0:
        return BandChoice(full, math.nan, df, low_hz, peaks)
    top = float(f[hit[-1]] + df)  # upper edge of the bin: a mode inside it is below
    return BandChoice(min(EDGE_MARGIN * top, full), top, df, low_hz, peaks)


def split_frequency(choice: BandChoice, max_hz: float = math.inf) -> float:
    """Where a wide band splits in two [Hz], NaN for no split.

    One realization cannot serve modes two decades apart: its Hankel window (block rows over
    the rate, Eq. (A1)) must span half a period of the lowest (``params.effective_block_rows``)
    within a row budget, while the rate must stay above the highest; a 3 Hz mode at 750 Hz
    needs 125 block rows. When the band edge is more than ``SPLIT_SPAN`` times the lowest
    peak, the band splits at the geometric middle of the widest gap (at least ``SPLIT_GAP`` and
    ``SPLIT_MIN_BINS`` bins) between successive clear peaks (not the leakage or roll-off maxima
    beside a strong one; any bin with structure among the first, which have too few bins below
    them to stand out): the group below is identified by an estimator of its own at a rate of
    its own (``low_band.py``). When that group's window could span its lowest peak only with
    the split lower, at most ``max_hz`` (``low_band.max_split_hz``), the split goes down the gap
    to there, but no closer than the gap's ``sqrt(SPLIT_GAP)`` to the peak below it."""
    low, edge = choice.low_hz, choice.fmax_hz
    if not (choice.found and math.isfinite(low) and low > 0 and edge > SPLIT_SPAN * low):
        return math.nan
    points = np.array(sorted(p for p in choice.peaks_hz if p > low))
    if points.size < 2:
        return math.nan
    gaps = points[1:] / points[:-1]
    # bin centres a few bins apart: the ratio of neighbouring coarse bins (1 and 2 Hz) says
    # nothing about where the modes are
    gaps[np.diff(points) < SPLIT_MIN_BINS * choice.resolution_hz] = 0.0
    k = int(np.argmax(gaps))
    if gaps[k] < SPLIT_GAP:
        return math.nan
    middle = math.sqrt(points[k] * points[k + 1])
    return float(min(middle, max(max_hz, points[k] * math.sqrt(SPLIT_GAP))))


def _fine_low(y: np.ndarray, fs: float, below_hz: float, level: float,
              above_hz: float = 0.0) -> float:
    """The lowest mode when the coarse spectrum has structure in its first bins, which have too
    few bins below them for the rising test (a 2 Hz mode at 1.7 Hz bins sits in the first):
    the same test on a spectrum of ``FINE_SEGMENTS`` segments (4-8 x finer bins), below
    ``below_hz`` (and from ``above_hz`` on), with ``FINE_PROMINENCE`` for its few averages.
    Lower edge of the bin [Hz], NaN if none."""
    n = y.shape[0]
    nseg = 2 * n // (FINE_SEGMENTS + 1)
    if nseg < 16:
        return math.nan
    f, p = signal.welch(y, fs=fs, nperseg=nseg, axis=0, detrend="constant")
    f, p = f[1:], p[1:]
    floor = np.quantile(p, FLOOR_QUANTILE, axis=0)
    ratio = (p[:, floor > 0] / floor[floor > 0]).max(axis=1, initial=0.0)
    hit = np.flatnonzero(_rising(ratio, FINE_PROMINENCE) & (ratio > level) & (f < below_hz)
                         & (f >= above_hz))
    return float(f[hit[0]] - 0.5 * (f[1] - f[0])) if hit.size else math.nan


def _side_min(ratio: np.ndarray, side: int, clip: bool = True) -> np.ndarray:
    """Per bin, the lowest ratio within ``PEAK_SPAN`` of its frequency (at least
    ``PEAK_MIN_BINS`` bins) on one side (``side`` -1: below, +1: above); beyond the ends the end
    bin counts (``clip``) or nothing does (inf)."""
    n = ratio.size
    k = np.arange(n)
    j = np.maximum(PEAK_MIN_BINS, np.ceil(PEAK_SPAN * (k + 1))).astype(int)  # bin k: (k+1) df
    steps = np.arange(1, int(j.max(initial=1)) + 1)
    idx = k[:, None] + side * steps[None, :]
    ok = steps[None, :] <= j[:, None]
    if not clip:
        ok &= (idx >= 0) & (idx < n)
    return np.where(ok, ratio[np.clip(idx, 0, max(n - 1, 0))], np.inf).min(axis=1)


def _rising(ratio: np.ndarray, prominence: float) -> np.ndarray:
    """Bins standing ``prominence`` above the lowest ratio within ``PEAK_SPAN`` (at least
    ``PEAK_MIN_BINS`` bins) below them; the first bin has none below."""
    return (np.arange(ratio.size) > 0) & (ratio >= prominence * _side_min(ratio, -1, False))


def _peaks(ratio: np.ndarray, prominence: float = 1.0) -> np.ndarray:
    """Bins not below their neighbours: the window leakage of a lightly damped mode lifts the
    bins beside its peak above the floor too, and would move the edge by a few bins. The
    roll-off of a strong mode can still show local maxima from the estimate's scatter (the
    safe side for a first choice); with ``prominence`` > 1 a peak must also stand that factor
    above the lowest ratio within ``PEAK_SPAN`` of its frequency (and ``PEAK_MIN_BINS`` bins)
    on both sides, which a roll-off never does on its rising side and a new lightly damped
    mode does (one with 5 % damping falls four times 10 % away from its peak)."""
    n = ratio.size
    if n < 2:
        return np.ones(n, bool)
    left = np.r_[-np.inf, ratio[:-1]]
    right = np.r_[ratio[1:], -np.inf]
    peak = (ratio >= left) & (ratio >= right)
    if prominence <= 1.0:
        return peak
    dip = np.maximum(_side_min(ratio, -1), _side_min(ratio, 1))
    return peak & (ratio >= prominence * dip)
