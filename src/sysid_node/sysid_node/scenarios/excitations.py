"""Excitation signals, (N, inputs) arrays at sample rate ``fs`` [Hz], unit RMS per input unless
stated (scale them as needed). Random ones take an explicit ``numpy.random.Generator``.

* :func:`white`: Gaussian white noise (the paper's wideband input);
* :func:`coloured`: white noise through a Butterworth band-pass (or low-pass), e.g. turbulence;
* :func:`multisine`: sum of sines on the record's DFT grid with Schroeder phases (low crest
  factor; over one period the lines come in turn, as in a linear sweep) or random phases
  (every line at every instant: kind ``random_multisine``), inputs on interleaved lines so
  they are uncorrelated;
* :func:`sweep`: linear or logarithmic chirp;
* :func:`sine_dwell`: one sine;
* :func:`ambient`: an unmeasured input for output-only records (white or coloured; not recorded).

:func:`excitation` picks one by name (the randomized suites draw the name).
"""

from __future__ import annotations

import numpy as np
from scipy import signal

#: The input kinds the hidden-effect suite draws from (``draw_effects``); ``random_multisine``
#: is asked by name (the identification suite, ``draw_modal_scenario``).
KINDS = ("white", "coloured", "multisine", "sweep")


def _band(band: tuple[float, float] | None, fs: float) -> tuple[float, float]:
    lo, hi = (0.0, 0.45 * fs) if band is None else (float(band[0]), float(band[1]))
    if not 0.0 <= lo < hi <= 0.5 * fs:
        raise ValueError(f"band must satisfy 0 <= lo < hi <= fs/2 = {0.5 * fs}, got {band}")
    return lo, hi


def white(n: int, m: int, rng: np.random.Generator, std: float = 1.0) -> np.ndarray:
    """White Gaussian input (n, m) with standard deviation ``std``: excites every mode below
    Nyquist."""
    u = rng.standard_normal((n, m))
    return u if std == 1.0 else std * u


def coloured(
    n: int, m: int, rng: np.random.Generator, fs: float,
    band: tuple[float, float] | None = None, order: int = 4,
) -> np.ndarray:
    """White noise filtered by a Butterworth band-pass over ``band`` [Hz] (low-pass when the
    lower edge is 0), unit RMS per input; 2 s of filter start-up are discarded."""
    lo, hi = _band(band, fs)
    nyq = 0.5 * fs
    hi = min(hi, 0.999 * nyq)
    if lo > 0:
        sos = signal.butter(order, [lo / nyq, hi / nyq], btype="bandpass", output="sos")
    else:
        sos = signal.butter(order, hi / nyq, btype="lowpass", output="sos")
    warm = int(2 * fs)
    u = signal.sosfilt(sos, rng.standard_normal((n + warm, m)), axis=0)[warm:]
    return u / np.maximum(np.std(u, axis=0, keepdims=True), 1e-300)


def multisine(
    n: int, m: int, fs: float, band: tuple[float, float] | None = None,
    period_samples: int | None = None, rng: np.random.Generator | None = None,
) -> np.ndarray:
    """Periodic multisine on the DFT grid of ``period_samples`` (default: the whole record) with
    lines in ``band``; Schroeder phases phi_k = -pi k (k - 1) / K, or with ``rng`` phases
    uniform in [0, 2 pi) (a random-phase multisine, Pintelon & Schoukens: noise-like, every
    line present at every instant, where the Schroeder signal of a long period sweeps through
    the band and leaves a mode unexcited until its turn); input j takes every m-th line
    starting at the j-th (uncorrelated inputs); unit RMS per input."""
    lo, hi = _band(band, fs)
    p = int(period_samples or n)
    df = fs / p
    lines = np.arange(max(1, int(np.ceil(lo / df))), int(np.floor(hi / df)) + 1)
    lines = lines[lines < p / 2]
    if lines.size < m:
        raise ValueError(f"band {lo}-{hi} Hz holds {lines.size} lines at {df:.4g} Hz spacing, "
                         f"fewer than {m} inputs")
    u = np.empty((n, m))
    reps = -(-n // p)
    for j in range(m):
        own = lines[j::m]
        k = np.arange(1, own.size + 1)
        spectrum = np.zeros(p // 2 + 1, dtype=complex)
        phase = (-np.pi * k * (k - 1) / own.size if rng is None
                 else rng.uniform(0.0, 2.0 * np.pi, own.size))
        spectrum[own] = np.exp(1j * phase)
        u[:, j] = np.tile(np.fft.irfft(spectrum, p), reps)[:n]
    return u / np.std(u, axis=0, keepdims=True)


def sweep(
    n: int, fs: float, f0: float, f1: float, method: str = "linear", m: int = 1,
) -> np.ndarray:
    """Chirp from ``f0`` to ``f1`` [Hz] over the record (``method`` ``linear`` or
    ``logarithmic``), amplitude sqrt(2) (unit RMS), the same on all ``m`` inputs."""
    if method not in ("linear", "logarithmic"):
        raise ValueError(f"method must be linear or logarithmic, got {method!r}")
    t = np.arange(n) / fs
    u = np.sqrt(2.0) * signal.chirp(t, f0, max(t[-1], 1.0 / fs), f1, method=method, phi=-90)
    return np.repeat(u[:, None], m, axis=1)


def sine_dwell(
    n: int, fs: float, frequency_hz: float, amplitude: float = 1.0, phase: float = 0.0,
    m: int = 1,
) -> np.ndarray:
    """A sine of ``frequency_hz`` [Hz] and ``amplitude`` on ``m`` inputs."""
    u = amplitude * np.sin(2 * np.pi * frequency_hz * np.arange(n) / fs + phase)
    return np.repeat(u[:, None], m, axis=1)


def ambient(
    n: int, m: int, rng: np.random.Generator, fs: float, band: tuple[float, float] | None = None
) -> np.ndarray:
    """Unmeasured broadband input (turbulence, gusts) for output-only records: white when
    ``band`` is None, else :func:`coloured`. Drive the structure with it; do not record it."""
    return white(n, m, rng) if band is None else coloured(n, m, rng, fs, band)


def excitation(
    kind: str, n: int, m: int, fs: float, rng: np.random.Generator,
    band: tuple[float, float] | None = None,
) -> np.ndarray:
    """An input of kind ``white``, ``coloured``, ``multisine`` (Schroeder phases),
    ``random_multisine`` (random phases) or ``sweep`` covering ``band`` [Hz] (default
    0-0.45 fs), unit RMS per input. The multisines have the record as their period; the sweep is
    linear over the record, one per input with a random start (so several inputs are not
    identical)."""
    lo, hi = _band(band, fs)
    if kind == "white":
        return white(n, m, rng)
    if kind == "coloured":
        return coloured(n, m, rng, fs, (lo, hi))
    if kind in ("multisine", "random_multisine"):
        return multisine(n, m, fs, (max(lo, fs / n), hi),
                         rng=rng if kind == "random_multisine" else None)
    if kind == "sweep":
        u = sweep(n, fs, max(lo, 0.1), hi, "linear", 1)[:, 0]
        shifts = [0, *rng.integers(n, size=m - 1)]
        return np.column_stack([np.roll(u, int(k)) for k in shifts])
    raise ValueError(f"unknown excitation {kind!r}; one of {', '.join(KINDS)}, random_multisine")
