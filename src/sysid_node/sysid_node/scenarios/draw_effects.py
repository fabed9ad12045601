"""Seeded random records with one hidden effect (issue #11's suite): :func:`draw_hidden_effect`
and the control :func:`draw_clean`.

The nominal structure is drawn like :func:`.draw.draw_structure` (1-3 modes, one input, one
output by default), driven by a measured excitation (white, coloured, multisine or sweep) plus
an unmeasured disturbance at the input (``process_noise`` x its RMS). The effect's size is the
RMS of what it changes in the noise-free output, ``e = y_with - y_without``, over the RMS of the
output noise ``v``: everything in the output the measured input does not explain (Ljung's
``y = G u + v``), i.e. the response ``y_w`` to the unmeasured disturbance plus the measurement
noise, pooled over the outputs (:meth:`_Base.size`). That is the floor the validation error of
a perfect linear model sees; sized against the measurement noise alone (a median 2.6x smaller)
most effects sat near it. The size is drawn in 2-20 and reached by scaling the effect's
strength (exactly for the linear effects, by a few secant steps for the others:
``truth["size"]`` is the size reached, ``truth["target_size"]`` the size drawn; they can differ
when the strength hits its bounds, e.g. a slow LPV mode in a short record, a very stiff cubic
spring, or a delay that cannot change the output by more than about twice its RMS).
``truth["size_vs_measurement_noise"]`` is the reached size over the measurement noise alone.
Every record carries two slow candidate signals at 10 Hz, ``/airspeed`` [m/s] and
``/rotor_speed`` [Hz]: the scheduling / rotating-speed source when the effect has one, else
distractors.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..core.controller import DiscreteController
from ..core.lti import simulate
from . import effects as E
from .closedloop import loop_is_stable, simulate_closed_loop
from .draw import _log_uniform, draw_rate, draw_structure
from .excitations import KINDS, excitation
from .structures import ModalStructure, scheduled_mode
from .timevarying import simulate_scheduled
from .truth import TrueMode

SIGNAL_RATE = 10.0  # [Hz] of /airspeed and /rotor_speed


@dataclass
class EffectScenario:
    """A record with a hidden effect (``effect`` None: clean control) and its truth."""

    effect: str | None
    fs: float
    t: np.ndarray  # (N,) [s from the start]
    u: np.ndarray  # (N, 1) recorded excitation
    y: np.ndarray  # (N, outputs) measured responses (noise included)
    signals: dict[str, tuple[np.ndarray, np.ndarray]]  # topic -> (t, values (n,))
    modes: list[TrueMode]  # the nominal structure's modes
    structure: ModalStructure
    excitation: str
    noise_fraction: float
    truth: dict = field(default_factory=dict)  # effect parameters, "size" reached

    @property
    def nominal_order(self) -> int:
        """State dimension of the nominal linear model (2 per mode)."""
        return 2 * self.structure.n_modes


@dataclass
class _Base:
    fs: float
    t: np.ndarray
    u: np.ndarray
    w: np.ndarray
    structure: ModalStructure
    kind: str
    y_u: np.ndarray  # response to u
    y_w: np.ndarray  # response to w
    noise_std: np.ndarray  # (outputs,) of the measurement noise
    fraction: float
    band: tuple[float, float]
    against_measurement: bool = False  # size() against the measurement noise alone

    @property
    def y(self) -> np.ndarray:
        return self.y_u + self.y_w

    def output_noise_rms(self, y_w: np.ndarray | None = None) -> np.ndarray:
        """(outputs,) RMS of the output noise v = y_w + measurement noise (Ljung's v in
        y = G u + v; independent parts: their mean squares add); ``y_w``: the response to the
        record's own disturbance when it is not the base's (feedback's)."""
        y_w = self.y_w if y_w is None else y_w
        return np.sqrt(np.mean(y_w**2, axis=0) + self.noise_std**2)

    def size(self, e: np.ndarray, y_w: np.ndarray | None = None) -> float:
        """RMS of the change ``e`` over the RMS of the output noise (pooled over outputs)."""
        if self.against_measurement:
            return self.size_vs_measurement_noise(e)
        return _rms_ratio(e, self.output_noise_rms(y_w))

    def size_vs_measurement_noise(self, e: np.ndarray) -> float:
        """RMS of ``e`` over the measurement noise's alone (the suite's size before round 32)."""
        return _rms_ratio(e, self.noise_std)


def _rms_ratio(e: np.ndarray, noise_rms: np.ndarray) -> float:
    return float(np.sqrt(np.mean(e**2)) / np.sqrt(np.mean(noise_rms**2)))


def _draw_base(rng, fs, n_modes, n_outputs, excitation_kind, duration_s, noise, damping,
               output, process_noise) -> _Base:
    fs = draw_rate(rng) if fs is None else float(fs)
    n_modes = int(rng.integers(1, 4)) if n_modes is None else n_modes
    band = (max(0.5, fs / 200.0), 0.3 * fs)
    structure = draw_structure(rng, fs, n_modes, n_outputs, 1, band, damping, output)
    n = int(round(duration_s * fs))
    kind = KINDS[int(rng.integers(len(KINDS)))] if excitation_kind is None else excitation_kind
    u = excitation(kind, n, 1, fs, rng, (0.5 * band[0], min(0.45 * fs, 1.5 * band[1])))
    w = process_noise * rng.standard_normal((n, 1))
    y_u, y_w = structure.simulate(u, fs), structure.simulate(w, fs)
    fraction = float(rng.uniform(*noise))
    noise_std = fraction * np.std(y_u + y_w, axis=0)
    return _Base(fs, np.arange(n) / fs, u, w, structure, kind, y_u, y_w, noise_std, fraction,
                 band)


def _slow_times(t: np.ndarray) -> np.ndarray:
    return np.arange(0.0, t[-1] + 1e-9, 1.0 / SIGNAL_RATE)


def _distractors(rng, t: np.ndarray) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    ts = _slow_times(t)
    v0, s0 = rng.uniform(40.0, 120.0), rng.uniform(3.0, 30.0)
    pv, ps = rng.uniform(20.0, 60.0), rng.uniform(10.0, 40.0)
    return {
        "/airspeed": (ts, v0 * (1 + 0.15 * np.sin(2 * np.pi * ts / pv))),
        "/rotor_speed": (ts, s0 * (1 + 0.03 * np.sin(2 * np.pi * ts / ps))),
    }


def _separated(f: float, others, rel: float = 0.05) -> bool:
    return all(abs(f - g) / (0.5 * (f + g)) >= rel for g in others)


def _secant(size_of, p0: float, target: float, low: float, high: float, steps: int = 3):
    """Strength p with size_of(p) close to ``target``, assuming size roughly proportional to p;
    returns (p, size, extra) of the best step (size_of returns (size, extra))."""
    p = float(np.clip(p0, low, high))
    best = None

    def miss(size: float) -> float:
        return abs(np.log(max(size, 1e-12) / target)) if np.isfinite(size) else np.inf

    for _ in range(steps):
        size, extra = size_of(p)
        if best is None or miss(size) < miss(best[1]):
            best = (p, size, extra)
        if size <= 0 or abs(size / target - 1) < 0.05:
            break
        if np.isfinite(size):
            p = float(np.clip(p * target / size, low, high))
        else:  # a diverging simulation: halfway (in log) to the best finite strength, or weaker
            p = float(np.sqrt(p * best[0]) if np.isfinite(best[1]) else max(low, 0.25 * p))
    return best


def draw_clean(rng: np.random.Generator, **options) -> EffectScenario:
    """A record of a drawn nominal structure with no hidden effect (the control); ``options``
    as for :func:`draw_hidden_effect`."""
    return draw_hidden_effect(None, rng, **options)


def _finish(rng, b: _Base, effect, y_clean, u, signals, truth, add_noise: bool = True):
    y = y_clean + b.noise_std * rng.standard_normal(y_clean.shape) if add_noise else y_clean
    modes = [TrueMode.constant(f"mode_{i + 1}", "structural", f, z, 0.0, float(b.t[-1]))
             for i, (f, z) in enumerate(b.structure.modes())]
    return EffectScenario(effect, b.fs, b.t, u, y, signals, modes, b.structure, b.kind,
                          b.fraction, {"effect": effect, "fs": b.fs, **truth})


def draw_hidden_effect(
    effect: str | None,
    rng: np.random.Generator,
    *,
    fs: float | None = None,
    n_modes: int | None = None,
    n_outputs: int = 1,
    excitation_kind: str | None = None,
    size: float | None = None,
    duration_s: float = 40.0,
    noise: tuple[float, float] = (0.02, 0.05),
    damping: tuple[float, float] = (0.005, 0.05),
    output: str = "acceleration",
    process_noise: float = 0.1,
    min_delay_samples: float = 0.05,
    size_against: str = "output_noise",
) -> EffectScenario:
    """A record of a drawn structure with the hidden ``effect`` (one of ``effects.EFFECTS``;
    None: no effect, see :func:`draw_clean`).

    Draws (unless given): ``fs`` 100-1000 Hz, 1-3 modes in [max(0.5 Hz, fs / 200), 0.3 fs],
    damping 0.5-5 %, the excitation kind, measurement noise 2-5 % of the output's RMS, the
    effect ``size`` 2-20 (x the RMS of the output noise v = y_w + measurement noise, see the
    module) and the effect's parameters (``truth``):

    * missing_mode: ``frequency_hz``, ``damping`` of an extra mode in [band low / 2, 0.4 fs];
    * periodic_disturbance: ``source`` /rotor_speed, ``harmonics`` (1-2 of 1, 2, 3),
      ``frequency_hz`` (mean speed), speed varying +-1-5 %;
    * parameter_varying: ``signal`` /airspeed, ``mode`` index, ``frequency_hz`` at
      ``reference`` airspeed, ``slope_hz_per_unit``;
    * input_delay: ``delay_s`` (any value from ``min_delay_samples`` / fs on: a transport
      delay, by linear interpolation of the input between samples) and ``samples`` (its nearest
      whole number of samples); a delay under one sample is mostly absorbed by the B and D of
      a discrete model (validate's suite asks for at least one);
    * nonlinear_stiffness: ``channel`` 0, ``cubic`` k3 > 0 (hardening) on the sum of the modal
      displacements seen by output 0;
    * sensor_bias: ``offset``, ``drift_per_s`` (per output);
    * feedback: ``lag`` 1-3 samples, ``gain`` (u = r - gain y(t - lag)), ``gain_margin``
      (stable-gain limit / gain); the unmeasured disturbance is 1-5 x the reference, so the
      output noise is mostly its response and a stable loop (gain at most 0.7 of the limit)
      changes the output by about that much: most loops sit at that bound, size ~1.

    ``size_against="measurement_noise"``: the size against the measurement noise alone (the
    generator before round 32; the records some regression tests were written on).
    """
    if size_against not in ("output_noise", "measurement_noise"):
        raise ValueError(f"size_against: output_noise or measurement_noise, not {size_against!r}")
    if effect is not None and effect not in E.EFFECTS:
        raise ValueError(f"unknown effect {effect!r}; one of {', '.join(E.EFFECTS)}")
    b = _draw_base(rng, fs, n_modes, n_outputs, excitation_kind, duration_s, noise, damping,
                   output, process_noise)
    b.against_measurement = size_against == "measurement_noise"
    if effect is None:
        return _finish(rng, b, None, b.y, b.u, _distractors(rng, b.t), {})
    target = float(_log_uniform(rng, 2.0, 20.0)) if size is None else float(size)
    signals = _distractors(rng, b.t)
    fs, t, st = b.fs, b.t, b.structure
    truth: dict = {"target_size": target}
    u = b.u
    if effect == "missing_mode":
        z = float(_log_uniform(rng, 0.005, 0.05))
        f = None
        for _ in range(500):
            cand = float(_log_uniform(rng, 0.5 * b.band[0], 0.4 * fs))
            if _separated(cand, st.frequencies_hz, max(0.05, 6 * z)):
                f = cand
                break
        if f is None:
            raise ValueError("no room for a missing mode")
        extra = ModalStructure([f], [z], [[1.0]], np.ones((st.n_outputs, 1)), st.output)
        e = extra.simulate(b.u + b.w, fs)
        e *= target / b.size(e)
        y = b.y + e
        truth.update(frequency_hz=f, damping=z)
    elif effect == "periodic_disturbance":
        harmonics = sorted(rng.choice([1, 2, 3], size=int(rng.integers(1, 3)), replace=False))
        hmax = max(harmonics)
        s0 = None
        for _ in range(500):
            cand = float(_log_uniform(rng, 0.5 * b.band[0], 0.4 * fs / hmax))
            if all(_separated(h * cand, st.frequencies_hz, 0.05) for h in harmonics):
                s0 = cand
                break
        if s0 is None:
            raise ValueError("no room for a periodic disturbance")
        period = rng.uniform(10.0, 30.0)
        depth = rng.uniform(0.01, 0.05)
        speed = s0 * (1 + depth * np.sin(2 * np.pi * t / period))
        amps = {int(h): float(rng.uniform(0.3, 1.0)) for h in harmonics}
        phases = {int(h): float(rng.uniform(-np.pi, np.pi)) for h in harmonics}
        d = E.periodic_disturbance(t, speed, amps, phases)[:, None] * np.ones(st.n_outputs)
        scale = target / b.size(d)
        y = b.y + scale * d
        ts = _slow_times(t)
        signals["/rotor_speed"] = (ts, s0 * (1 + depth * np.sin(2 * np.pi * ts / period)))
        truth.update(source="/rotor_speed", harmonics=[int(h) for h in harmonics],
                     frequency_hz=float(speed.mean()),
                     amplitudes={h: a * scale for h, a in amps.items()})
    elif effect == "parameter_varying":
        i = int(rng.integers(st.n_modes))
        v_ref = float(rng.uniform(40.0, 120.0))
        knots_t = np.linspace(0.0, t[-1], 6)
        knots_v = v_ref * (1 + rng.uniform(-0.3, 0.3, size=6))
        v = np.interp(t, knots_t, knots_v)
        span = float(knots_v.max() - knots_v.min())
        f_i, zeta = float(st.frequencies_hz[i]), float(st.damping_ratios[i])
        mode = ModalStructure([f_i], [st.damping_ratios[i]], st.input_gains[i : i + 1],
                              st.shapes[:, i : i + 1], st.output)
        y_i = mode.simulate(b.u + b.w, fs)

        def size_of(rel: float):
            slope = rel * f_i / span
            freq = E.linear_schedule(f_i, slope, v_ref)
            y_lpv = simulate_scheduled(scheduled_mode(mode, 0, freq), v, b.u + b.w, fs,
                                       resolution=max(span / 400, 0.05 * zeta * f_i / slope))
            return b.size(y_lpv - y_i), (slope, y_lpv)

        _, _, (slope, y_lpv) = _secant(size_of, 0.05, target, 0.002, 0.3, steps=4)
        y = b.y - y_i + y_lpv
        ts = _slow_times(t)
        signals["/airspeed"] = (ts, np.interp(ts, knots_t, knots_v))
        truth.update(signal="/airspeed", mode=i, frequency_hz=f_i, reference=v_ref,
                     slope_hz_per_unit=slope)
    elif effect == "input_delay":
        def delayed(tau: float) -> np.ndarray:  # input delayed tau [s], linear interpolation
            k, frac = divmod(tau * fs, 1.0)
            k = int(k)
            return (1 - frac) * E.delay_input(b.y_u, k) + frac * E.delay_input(b.y_u, k + 1)

        def size_of(tau: float):
            return b.size(delayed(tau) - b.y_u), None

        lo = min_delay_samples / fs
        tau, _, _ = _secant(size_of, max(1.0 / fs, lo), target, lo, 0.05 + lo + 1.0 / fs, steps=6)
        y = delayed(tau) + b.y_w
        truth.update(samples=int(round(tau * fs)), delay_s=tau)
    elif effect == "nonlinear_stiffness":
        system = st.system()
        spring = np.zeros(system.order)
        spring[0::2] = st.shapes[0]  # output 0's sum of modal displacements
        drive = b.u + b.w
        deflection = simulate(
            ModalStructure(st.frequencies_hz, st.damping_ratios, st.input_gains, st.shapes,
                           "displacement").system(), drive, fs)[:, 0]
        first = simulate(system, deflection[:, None] ** 3, fs)  # first order in k3, per unit
        y_lin = simulate(system, drive, fs)

        def size_of(k3: float):
            # the hardening spring raises the frequency with the amplitude: a Runge-Kutta step
            # that diverges is refined; still diverging at 8x the linear step count: too stiff
            # (or unstable: the spring acts where the input does, not on its own deflection),
            # a weaker spring (_secant)
            for refine in (1, 2, 4, 8):
                with np.errstate(over="ignore", invalid="ignore"):
                    y_nl = E.simulate_cubic_stiffness(system, drive, fs, k3, spring,
                                                      refine * substeps)
                if np.all(np.isfinite(y_nl)):
                    return b.size(y_nl - y_lin), y_nl
            return np.inf, y_nl

        substeps = int(np.ceil(4 * np.pi * st.frequencies_hz.max() / fs))
        k0 = target / max(b.size(first), 1e-300)
        k3, _, y_nl = _secant(size_of, k0, target, k0 * 1e-3, k0 * 10, steps=4)
        y = y_nl
        truth.update(channel=0, cubic=k3)
    elif effect == "sensor_bias":
        offset = rng.choice([-1.0, 1.0], st.n_outputs) * rng.uniform(0.2, 1.0, st.n_outputs)
        drift = rng.choice([-1.0, 1.0], st.n_outputs) * rng.uniform(0.2, 1.0, st.n_outputs)
        drift /= t[-1]
        e = E.sensor_bias(t, offset, drift)
        scale = target / b.size(e)
        y = b.y + scale * e
        truth.update(offset=(scale * offset).tolist(), drift_per_s=(scale * drift).tolist())
    else:  # feedback
        lag = int(rng.integers(1, 4))
        system = st.system()
        w = b.w / max(np.std(b.w), 1e-300) * rng.uniform(1.0, 5.0)  # strong disturbance
        v = b.noise_std * rng.standard_normal((len(t), st.n_outputs))

        def negative(g: float) -> DiscreteController:  # u = r - g (y_1 + ... + y_l)(t - lag)
            return DiscreteController.static(np.full((1, st.n_outputs), -g), fs)

        lo, hi = 0.0, 1.0
        while loop_is_stable(system, negative(hi), lag) and hi < 1e9:
            lo, hi = hi, hi * 4
        for _ in range(30):  # the largest stable gain
            mid = 0.5 * (lo + hi)
            lo, hi = (mid, hi) if loop_is_stable(system, negative(mid), lag) else (lo, mid)
        g_max = lo
        y_open = simulate(system, b.u + w, fs) + v
        y_w = simulate(system, w, fs)  # the output noise is this record's: G w + v

        def size_of(g: float):
            yc, uc = simulate_closed_loop(system, negative(g), b.u, w=w, v=v, delay=lag)
            return b.size(yc - y_open, y_w), (yc, uc)

        gain, reached, (y, u) = _secant(size_of, 0.2 * g_max, target, 1e-6 * g_max, 0.7 * g_max,
                                        steps=6)
        truth.update(lag=lag, gain=gain, gain_margin=g_max / gain, size=reached,
                     size_vs_measurement_noise=b.size_vs_measurement_noise(y - y_open))
        return _finish(rng, b, effect, y, u, signals, truth, add_noise=False)
    truth["size"] = b.size(y - b.y)
    truth["size_vs_measurement_noise"] = b.size_vs_measurement_noise(y - b.y)
    return _finish(rng, b, effect, y, u, signals, truth)
