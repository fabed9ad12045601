"""Seeded random scenarios for the randomized test suites: a ``numpy.random.Generator`` in, a
dataclass out with the data and the truth (true modes over time, effect parameters).

* :func:`draw_modal_scenario`: 1-8 modes anywhere below 0.4 fs, 100-1000 Hz, 1-3 outputs,
  input-output or output-only, optionally a mode appearing or jumping mid-run;
* :func:`drifting_mode`: a lightly damped mode drifting in frequency plus a rigid-body mode below
  the band, with each component's noise-free response (for notch attenuation figures).

Hidden effects (``draw_hidden_effect``, ``draw_clean``) are in :mod:`.draw_effects`. Every
keyword left at ``None`` is drawn; pass a value to pin it. Simulation is per mode
(:meth:`ModalStructure.mode_responses`), time-varying modes piecewise constant over short
segments (:mod:`.timevarying`): no per-sample Python loop. Deterministic per seed on one machine;
compare results with tolerances.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..core.lti import simulate
from .excitations import ambient, excitation
from .structures import OUTPUT_KINDS, ModalStructure, scheduled_mode
from .timevarying import simulate_scheduled, simulate_switching
from .truth import TrueMode, modes_at


@dataclass
class ModalScenario:
    """A simulated record and its truth. ``u`` is None for output-only records (the ambient
    input that drove the structure is ``unmeasured_input``)."""

    fs: float
    t: np.ndarray  # (N,) [s from the start]
    u: np.ndarray | None  # (N, inputs) measured excitation
    y: np.ndarray  # (N, outputs) measured responses (noise included)
    modes: list[TrueMode]  # truth over time
    structure: ModalStructure  # at t = 0 (before any change)
    excitation: str  # white / coloured / multisine / sweep / ambient
    noise_fraction: float  # output noise std / noise-free output std
    levels: np.ndarray  # RMS of each mode's response on its largest output
    change: dict | None = None  # {"kind": "appear"|"jump", "time_s", "mode", ...}
    unmeasured_input: np.ndarray | None = None
    extra: dict = field(default_factory=dict)

    @property
    def output_only(self) -> bool:
        return self.u is None

    def stamps_ns(self, start_ns: int = 1_700_000_000_000_000_000) -> np.ndarray:
        """Header stamps [ns] of the samples from ``start_ns``."""
        return start_ns + np.round(self.t * 1e9).astype(np.int64)

    def modes_at(self, t: float, kind: str | None = "structural") -> list[tuple[float, float]]:
        """True (frequency_hz, damping_ratio) at time ``t`` [s], sorted by frequency."""
        return modes_at(self.modes, t, kind)


def draw_rate(rng: np.random.Generator, low: float = 100.0, high: float = 1000.0) -> float:
    """Sample rate [Hz], log-uniform in [low, high], rounded to 1 Hz."""
    return float(np.round(np.exp(rng.uniform(np.log(low), np.log(high)))))


def draw_frequencies(
    rng: np.random.Generator, band: tuple[float, float], damping: np.ndarray,
    min_separation: float = 0.05, tries: int = 2000,
) -> tuple[np.ndarray, np.ndarray]:
    """(frequencies, damping ratios) sorted by frequency: one frequency log-uniform in ``band``
    [Hz] per damping ratio, any two at least max(``min_separation``, 3 (zeta_i + zeta_j)) apart
    relative to their mean (distinct modes: several half-power bandwidths 2 zeta f apart)."""
    n = len(damping)
    lo, hi = np.log(band[0]), np.log(band[1])
    out: list[float] = []
    zs: list[float] = []
    for _ in range(tries):
        if len(out) == n:
            break
        f = float(np.exp(rng.uniform(lo, hi)))
        z = float(damping[len(out)])
        if all(abs(f - g) / (0.5 * (f + g)) >= max(min_separation, 3 * (z + zg))
               for g, zg in zip(out, zs, strict=True)):
            out.append(f)
            zs.append(z)
    if len(out) < n:
        raise ValueError(f"could not place {n} separated modes in {band[0]:.3g}-{band[1]:.3g} Hz")
    order = np.argsort(out)
    return np.asarray(out)[order], np.asarray(zs)[order]


def _log_uniform(rng: np.random.Generator, low: float, high: float, size=None):
    return np.exp(rng.uniform(np.log(low), np.log(high), size))


def _signed(rng: np.random.Generator, shape, low: float = 0.3) -> np.ndarray:
    """Magnitudes uniform in [low, 1] with random signs."""
    return rng.uniform(low, 1.0, shape) * rng.choice([-1.0, 1.0], shape)


def draw_structure(
    rng: np.random.Generator, fs: float, n_modes: int, n_outputs: int, n_inputs: int,
    band: tuple[float, float], damping: tuple[float, float], output: str,
) -> ModalStructure:
    """Random modal structure: separated modes in ``band``, damping log-uniform in ``damping``,
    shapes and input gains of magnitude 0.3-1 with random signs."""
    f, z = draw_frequencies(rng, band, _log_uniform(rng, *damping, size=n_modes))
    return ModalStructure(f, z, _signed(rng, (n_modes, n_inputs)),
                          _signed(rng, (n_outputs, n_modes)), output)


def _scale_modes(resp: np.ndarray, levels: np.ndarray, exists: np.ndarray) -> np.ndarray:
    """Scale each mode's response (N, l, k) so its RMS on its largest output (while it exists,
    ``exists`` (N, k)) is ``levels[i]``."""
    out = resp.copy()
    for i in range(resp.shape[2]):
        part = resp[exists[:, i], :, i]
        rms = np.sqrt(np.mean(part**2, axis=0)).max() if part.size else 0.0
        if rms > 0:
            out[:, :, i] *= levels[i] / rms
    return out


def draw_modal_scenario(
    rng: np.random.Generator,
    *,
    fs: float | None = None,
    n_modes: int | None = None,
    n_outputs: int | None = None,
    output_only: bool | None = None,
    change: str | None = "random",
    duration_s: float | None = None,
    excitation_kind: str | None = None,
    excitations: tuple[str, ...] = ("white", "coloured", "random_multisine"),
    output: str | None = None,
    damping: tuple[float, float] = (0.002, 0.05),
    noise: tuple[float, float] = (0.02, 0.10),
    min_frequency_hz: float | None = None,
    max_frequency_fraction: float = 0.4,
) -> ModalScenario:
    """A random modal record (issue #10's suite).

    Draws (unless given): ``fs`` 100-1000 Hz; ``n_modes`` 1-8 with frequencies log-uniform in
    [``min_frequency_hz`` (default max(2 Hz, fs / 200): cycles enough in a few seconds), 0.4 fs],
    separated (see :func:`draw_frequencies`); damping 0.2-5 %; ``n_outputs`` 1-3; output-only
    or one measured input (even odds); the sensor kind (``output``: displacement, velocity or
    acceleration); the excitation among ``excitations`` (output-only: ambient white or
    coloured; the suite scores every mode by 3 s of data, so its inputs excite every mode
    from the start: the multisine has random phases, not the Schroeder phases that make a
    record-long multisine a sweep, ``excitations.multisine``); each mode's level (RMS on its
    largest output) log-uniform in 0.3-1; output noise 2-10 % of each output's RMS.
    ``change`` ``"random"`` draws none (1/2), ``appear`` or ``jump`` (1/4 each); ``appear``: one
    mode (never the only one) starts from rest at 40-60 % of the record; ``jump``: one mode's
    frequency jumps by 5-20 % there (state carried). Default duration: 200 periods of the
    lowest mode, within 30-120 s.
    """
    fs = draw_rate(rng) if fs is None else float(fs)
    n_modes = int(rng.integers(1, 9)) if n_modes is None else n_modes
    n_outputs = int(rng.integers(1, 4)) if n_outputs is None else n_outputs
    output_only = bool(rng.random() < 0.5) if output_only is None else output_only
    output = OUTPUT_KINDS[int(rng.integers(3))] if output is None else output
    f_lo = max(2.0, fs / 200.0) if min_frequency_hz is None else min_frequency_hz
    band = (f_lo, max_frequency_fraction * fs)
    structure = draw_structure(rng, fs, n_modes, n_outputs, 1, band, damping, output)
    if change == "random":
        change = [None, "appear", "jump"][int(rng.choice(3, p=[0.5, 0.25, 0.25]))]
    if change == "appear" and n_modes < 2:
        change = None
    if duration_s is None:
        duration_s = float(np.clip(200.0 / structure.frequencies_hz[0], 30.0, 120.0))
    n = int(round(duration_s * fs))
    t = np.arange(n) / fs
    exc_band = (0.5 * band[0], min(1.25 * band[1], 0.45 * fs))
    if output_only:
        kind = "ambient"
        drive = ambient(n, 1, rng, fs, None if rng.random() < 0.5 else exc_band)
    else:
        kind = excitations[int(rng.integers(len(excitations)))] if excitation_kind is None \
            else excitation_kind
        drive = excitation(kind, n, 1, fs, rng, exc_band)

    resp = structure.mode_responses(drive, fs)
    exists = np.ones((n, n_modes), bool)
    modes = [TrueMode.constant(f"mode_{i + 1}", "structural", f, z, 0.0, duration_s)
             for i, (f, z) in enumerate(structure.modes())]
    info = None
    if change is not None:
        tc = float(np.round(rng.uniform(0.4, 0.6) * duration_s * fs) / fs)
        kc = int(round(tc * fs))
        i = int(rng.integers(n_modes))
        f0, z0 = structure.modes()[i]
        if change == "appear":
            resp[:, :, i] = 0.0
            resp[kc:, :, i] = simulate(structure.mode_system(i), drive[kc:], fs)
            exists[:kc, i] = False
            modes[i] = TrueMode.constant(modes[i].name, "structural", f0, z0, tc, duration_s)
            info = {"kind": "appear", "time_s": tc, "mode": modes[i].name}
        elif change == "jump":
            others = np.delete(structure.frequencies_hz, i)
            f1 = f0
            for _ in range(200):
                cand = f0 * (1 + rng.choice([-1.0, 1.0]) * rng.uniform(0.05, 0.2))
                if band[0] <= cand <= band[1] and all(
                        abs(cand - g) / (0.5 * (cand + g)) >= max(0.05, 6 * z0) for g in others):
                    f1 = float(cand)
                    break
            after = structure.with_mode(i, frequency_hz=f1)
            resp[:, :, i] = simulate_switching(
                [(0.0, structure.mode_system(i)), (tc, after.mode_system(i))], drive, fs)
            modes[i] = TrueMode(modes[i].name, "structural", (0.0, tc, tc, duration_s),
                                (f0, f0, f1, f1), (z0,) * 4)
            info = {"kind": "jump", "time_s": tc, "mode": modes[i].name,
                    "from_hz": f0, "to_hz": f1}
    levels = _log_uniform(rng, 0.3, 1.0, size=n_modes)
    y_clean = _scale_modes(resp, levels, exists).sum(axis=2)
    fraction = float(rng.uniform(*noise))
    y = y_clean + fraction * np.std(y_clean, axis=0) * rng.standard_normal(y_clean.shape)
    return ModalScenario(
        fs, t, None if output_only else drive, y, modes, structure, kind, fraction, levels,
        info, drive if output_only else None,
    )


@dataclass
class DriftingScenario:
    """A drifting structural mode and a rigid-body mode (issue #12's notch suites).

    ``structural`` and ``rigid`` are the two components' noise-free responses (N, outputs):
    ``y = structural + rigid + noise``; filter each with identically driven notch banks to
    measure what the notches do to each.
    """

    fs: float
    t: np.ndarray
    u: np.ndarray  # (N, 1) broadband excitation
    y: np.ndarray  # (N, outputs)
    structural: np.ndarray
    rigid: np.ndarray
    modes: list[TrueMode]  # the drifting mode (knots over time) and the rigid-body mode
    noise_fraction: float

    def mode_at(self, t) -> tuple[np.ndarray, np.ndarray]:
        """(frequency_hz, damping_ratio) of the drifting mode at times ``t``."""
        return self.modes[0].at(t)


def drifting_mode(
    rng: np.random.Generator,
    *,
    fs: float | None = None,
    duration_s: float = 60.0,
    frequency_hz: float | None = None,
    drift: float | None = None,
    damping: float | None = None,
    rigid_frequency_hz: float | None = None,
    n_outputs: int = 1,
    noise: tuple[float, float] = (0.02, 0.05),
    rigid_level: float | None = None,
    resolution: float = 0.05,
) -> DriftingScenario:
    """A lightly damped mode drifting in frequency, broadband-excited, plus a rigid-body
    response below the band.

    Draws (unless given): ``fs`` 100-1000 Hz; the mode's start frequency log-uniform in
    [max(2 Hz, fs / 100), 0.2 fs]; a relative ``drift`` of +-(5-20) %, a ramp between two
    random times (10-40 % and 60-90 % of the record); damping 1-3 % (constant); a rigid-body
    mode at 0.15-0.4 x the lowest frequency the structural mode takes, damped 5-30 %, at
    ``rigid_level`` 0.5-2 x the structural level; white excitation; output noise 2-5 %.
    The drift is simulated piecewise constant in frequency steps of ``resolution`` x the
    half-power half-bandwidth zeta f.
    """
    fs = draw_rate(rng) if fs is None else float(fs)
    f0 = float(_log_uniform(rng, max(2.0, fs / 100.0), 0.2 * fs)) if frequency_hz is None \
        else frequency_hz
    if drift is None:
        drift = float(rng.choice([-1.0, 1.0]) * rng.uniform(0.05, 0.2))
    zeta = float(rng.uniform(0.01, 0.03)) if damping is None else damping
    f1 = f0 * (1 + drift)
    ta, tb = rng.uniform(0.1, 0.4) * duration_s, rng.uniform(0.6, 0.9) * duration_s
    f_rb = float(rng.uniform(0.15, 0.4) * min(f0, f1)) if rigid_frequency_hz is None \
        else rigid_frequency_hz
    z_rb = float(rng.uniform(0.05, 0.3))
    n = int(round(duration_s * fs))
    t = np.arange(n) / fs
    u = rng.standard_normal((n, 1))
    shapes = _signed(rng, (n_outputs, 2), 0.5)
    mode = ModalStructure([f0], [zeta], [[1.0]], shapes[:, :1])
    rigid = ModalStructure([f_rb], [z_rb], [[1.0]], shapes[:, 1:], kinds=("rigid_body",))

    f_t = np.interp(t, [0.0, ta, tb, duration_s], [f0, f0, f1, f1])
    y_mode = simulate_scheduled(scheduled_mode(mode, 0, lambda f: f), f_t, u, fs,
                                resolution=resolution * zeta * min(f0, f1))
    y_rigid = rigid.simulate(u, fs)
    y_mode /= np.sqrt(np.mean(y_mode**2, axis=0)).max()
    level = float(_log_uniform(rng, 0.5, 2.0)) if rigid_level is None else rigid_level
    y_rigid *= level / np.sqrt(np.mean(y_rigid**2, axis=0)).max()
    clean = y_mode + y_rigid
    fraction = float(rng.uniform(*noise))
    y = clean + fraction * np.std(clean, axis=0) * rng.standard_normal(clean.shape)
    modes = [
        TrueMode("drifting_mode", "structural", (0.0, ta, tb, duration_s),
                 (f0, f0, f1, f1), (zeta,) * 4),
        TrueMode.constant("rigid_body", "rigid_body", f_rb, z_rb, 0.0, duration_s),
    ]
    return DriftingScenario(fs, t, u, y, y_mode, y_rigid, modes, fraction)


