"""Anti-alias filtering and decimation of the sample stream to the identification rate (pure).

A 1 kHz IMU whose structural modes of interest lie below 40 Hz carries ten times more samples
than the identification needs, and the DSRA's cost grows with the rate (more samples) and with
the Hankel horizon needed to see the lowest mode (more block rows). The standard remedy is to
low-pass and decimate first. The paper's Sec. II example identifies 0-10 Hz modes at 100 Hz,
so the automatic factor keeps the identification rate at least ``RATE_PER_BAND_EDGE`` = 10
times the upper band edge.

Inputs and outputs pass through the same filter, so the input-output relation inside the band
is unchanged. The filter is a Butterworth low-pass of order 8 at 0.8 times the new Nyquist
frequency, run as second-order sections with its state kept across chunks. Kept samples are the
grid samples whose index from the first sample is a multiple of the factor, so the result does
not depend on how the stream was chunked.
"""

from __future__ import annotations

import math

import numpy as np
from scipy import signal

#: Automatic decimation keeps the identification rate >= this many times the band's upper edge.
RATE_PER_BAND_EDGE = 10.0
#: Largest automatic factor.
MAX_AUTO_FACTOR = 100


def auto_factor(fs: float, freq_max: float) -> int:
    """Largest integer factor k with fs / k >= RATE_PER_BAND_EDGE * freq_max; 1 when the band
    is not configured (``freq_max <= 0``) or the rate is unknown."""
    if not (math.isfinite(fs) and fs > 0 and math.isfinite(freq_max) and freq_max > 0):
        return 1
    return int(max(1, min(MAX_AUTO_FACTOR, math.floor(fs / (RATE_PER_BAND_EDGE * freq_max)))))


class Decimator:
    """Low-pass and keep every ``factor``-th sample of (stamps, y, u) chunks on a uniform grid.

    ``process(stamps_ns, y, u)`` returns the kept samples (filtered). ``restart()`` is called
    when the data are not contiguous (a gap): the filter restarts from the next sample's value
    (no start-up transient) while the sample phase stays on the same grid.
    """

    def __init__(self, factor: int, fs: float) -> None:
        if factor < 1:
            raise ValueError(f"decimation factor must be >= 1, got {factor}")
        self.factor = int(factor)
        self.fs = float(fs)
        self.period_ns = 1e9 / self.fs
        self._sos = signal.butter(8, 0.8 / self.factor, output="sos") if self.factor > 1 else None
        self._zi: np.ndarray | None = None
        self._t0_ns: int | None = None

    @property
    def rate(self) -> float:
        """Identification rate fs / factor [Hz]."""
        return self.fs / self.factor

    def restart(self) -> None:
        self._zi = None

    def process(
        self, stamps_ns: np.ndarray, y: np.ndarray, u: np.ndarray | None
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
        if self.factor == 1 or len(stamps_ns) == 0:
            return stamps_ns, y, u
        if self._t0_ns is None:
            self._t0_ns = int(stamps_ns[0])
        data = y if u is None else np.hstack([y, u])
        if self._zi is None:  # steady state for the first value: no start-up transient
            self._zi = signal.sosfilt_zi(self._sos)[:, :, None] * data[0][None, None, :]
        filtered, self._zi = signal.sosfilt(self._sos, data, axis=0, zi=self._zi)
        index = np.rint((stamps_ns - self._t0_ns) / self.period_ns).astype(np.int64)
        keep = index % self.factor == 0
        out = filtered[keep]
        ny = y.shape[1]
        return stamps_ns[keep], out[:, :ny], None if u is None else out[:, ny:]
