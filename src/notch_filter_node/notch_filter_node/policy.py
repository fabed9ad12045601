"""Retuning policy of the adaptive notch bank (pure): which notch sits where, how wide, how deep.

Input is plain data (:class:`ModeInput`, :class:`EstimateInput`), output the section parameters of
the bank (:class:`~notch_filter_node.sections.SectionParams`) and a status per notch.

- A mode gets a notch only once its status is ``tracked``, its frequency lies in
  ``[freq_min, freq_max]``, its damping is at most ``damping_max`` and its amplitude is at least
  ``min_relative_amplitude`` times the largest such mode's (a mode that small hardly reaches the
  feedback signal, and is often a noise mode with a wide uncertainty); the new notch starts at
  the estimate with its budget-limited bandwidth and fades its depth in. When there are more
  such modes than sections, the modes that already have a notch keep it and the largest
  (``amplitude``) of the others come next.
- The centre follows the estimate at most at ``slew_rate`` [Hz/s], and only when the estimate has
  moved by more than the hysteresis ``max(hysteresis, hysteresis_sigma * sigma_f)``.
- Bandwidth: the narrowest notch that keeps ``min_attenuation`` over the uncertainty interval
  ``f +- (sigma_k sigma_f + hysteresis)`` (:func:`~notch_filter_node.sections.covering_zp`), and at
  least ``damping_gain * 2 (zeta + sigma_zeta) f`` (the mode's own half-power width), clipped to
  ``[bandwidth_min, bandwidth_max]``: a confident estimate gets a narrow notch. The total phase
  lag of the adaptive notches at ``crossover_frequency`` (scipy.signal.freqz) is then held within
  ``phase_lag_budget`` by narrowing all of them towards ``bandwidth_min`` by a common factor.
- A lost (or vanished, or out-of-band) mode's notch holds its centre for ``hold_time``, then fades
  its depth to 0 dB over ``fade_time`` (never switched off in one step), then frees its slot.
- Fallback: while there is no estimate, the estimate is older than ``stale_timeout - fallback_ramp``
  or not converged, the configured static notch fades in over ``fallback_ramp`` (so it is at full
  depth when the estimate is ``stale_timeout`` old) and the adaptive notches hold, then fade.
- Every parameter moves at a bounded rate per second of data (centre and bandwidth
  ``slew_rate``, depth ``depth / fade_time``), whatever the block size.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field, replace

import numpy as np

from notch_filter_node import sections as S

# Notch states (constants of sysid_msgs/Notch)
TRACKING, HOLDING, PARKED, DISABLED = 0, 1, 2, 3
STATE_NAMES = {TRACKING: "tracking", HOLDING: "holding", PARKED: "parked", DISABLED: "disabled"}
#: Relative bandwidth change below which a tracking notch keeps its bandwidth target.
BANDWIDTH_HYSTERESIS = 0.1


@dataclass(frozen=True)
class ModeInput:
    """One identified mode, as the policy needs it (NaN = unknown)."""

    id: int
    status: str  # "tentative", "tracked" or "lost"
    frequency_hz: float
    frequency_std_hz: float = math.nan
    damping_ratio: float = math.nan
    damping_std: float = math.nan
    amplitude: float = math.nan  # participation [output unit]; ranks modes when the bank is full


@dataclass(frozen=True)
class EstimateInput:
    """A modal estimate: stamp [s] (time of the last sample it used), converged flag, modes."""

    stamp: float
    converged: bool
    modes: Sequence[ModeInput] = ()


@dataclass(frozen=True)
class PolicyConfig:
    """Tuning of the policy (SI units; the node parameters of the same names)."""

    slew_rate: float = 1.0  # [Hz/s] centre and bandwidth
    hysteresis: float = 0.005  # [Hz]
    hysteresis_sigma: float = 0.5  # [-] hysteresis in units of the frequency std
    freq_min: float = 2.0  # [Hz]
    freq_max: float = 0.0  # [Hz], 0 = 0.4 fs
    depth: float = 30.0  # [dB] at the centre
    min_attenuation: float = 20.0  # [dB] kept over the uncertainty interval
    sigma_k: float = 3.0  # [-] uncertainty interval half-width in frequency stds
    damping_gain: float = 1.0  # [-] bandwidth >= damping_gain * 2 zeta f
    damping_max: float = 0.15  # [-] better damped modes get no notch
    min_relative_amplitude: float = 0.05  # [-] of the largest usable mode's amplitude
    bandwidth_min: float = 0.05  # [Hz]
    bandwidth_max: float = 5.0  # [Hz]
    phase_lag_budget: float = 10.0  # [deg] total of the adaptive notches at the crossover
    crossover_frequency: float = 0.5  # [Hz]
    stale_timeout: float = 2.0  # [s]
    fallback_ramp: float = 0.25  # [s]
    hold_time: float = 1.0  # [s]
    fade_time: float = 1.0  # [s]
    fallback_center: float = 2.79  # [Hz]
    fallback_bandwidth: float = 4.2  # [Hz]
    fallback_depth: float = 30.0  # [dB], 0 = no fallback notch
    max_notches: int = 5  # adaptive sections (the fallback has its own)


def check_config(c: PolicyConfig, fs: float = math.nan) -> str:
    """Cross checks of a configuration; '' if valid, else the reason."""
    if c.freq_max > 0 and c.freq_min >= c.freq_max:
        return f"freq_min={c.freq_min:g} Hz must be below freq_max={c.freq_max:g} Hz"
    if c.bandwidth_min > c.bandwidth_max:
        return (f"bandwidth_min={c.bandwidth_min:g} Hz must not exceed "
                f"bandwidth_max={c.bandwidth_max:g} Hz")
    if c.depth <= c.min_attenuation:
        return f"depth={c.depth:g} dB must exceed min_attenuation={c.min_attenuation:g} dB"
    if c.fallback_ramp >= c.stale_timeout:
        return (f"fallback_ramp={c.fallback_ramp:g} s must be shorter than "
                f"stale_timeout={c.stale_timeout:g} s")
    if math.isfinite(fs) and fs > 0:
        nyq = fs / 2
        if c.freq_max > nyq:
            return f"freq_max={c.freq_max:g} Hz is above the Nyquist frequency {nyq:g} Hz"
        if c.freq_min >= nyq:
            return f"freq_min={c.freq_min:g} Hz is not below the Nyquist frequency {nyq:g} Hz"
        if c.fallback_depth > 0 and c.fallback_center >= nyq:
            return (f"fallback_center={c.fallback_center:g} Hz is not below the Nyquist "
                    f"frequency {nyq:g} Hz")
        if c.crossover_frequency >= nyq:
            return (f"crossover_frequency={c.crossover_frequency:g} Hz is not below the "
                    f"Nyquist frequency {nyq:g} Hz")
    return ""


@dataclass
class Slot:
    """One section of the bank and what it follows."""

    mode_id: int = 0
    state: int = DISABLED
    center: float = 1.0
    bandwidth: float = 0.1
    depth: float = 0.0
    shape_depth: float = 30.0
    target_center: float = 1.0
    target_bandwidth: float = 0.1
    target_depth: float = 0.0
    desired_bandwidth: float = 0.1  # before the phase-lag budget
    hold_since: float = math.nan


@dataclass(frozen=True)
class NotchStatus:
    """What one active section does now (for sysid_msgs/Notch)."""

    mode_id: int
    state: int
    center: float
    bandwidth: float
    depth: float


@dataclass
class PolicyStatus:
    """Summary for the node's NotchBank and diagnostics."""

    notches: list[NotchStatus] = field(default_factory=list)
    fallback_active: bool = True
    estimate_age: float = math.nan
    budget_limited: bool = False
    phase_lag_deg: float = 0.0  # adaptive notches at their target bandwidths


class RetuningPolicy:
    """Turns modal estimates into bank parameters; call :meth:`set_estimate` on every estimate
    and :meth:`advance` once per block of data (``now`` = data time of its last sample)."""

    def __init__(self, config: PolicyConfig, fs: float) -> None:
        self.fs = float(fs)
        self.config = config
        n = config.max_notches + 1
        self.slots = [Slot(shape_depth=config.depth) for _ in range(n)]
        fb = self.slots[-1]
        fb.shape_depth = config.fallback_depth
        fb.state = PARKED if config.fallback_depth > 0 else DISABLED
        fb.center = fb.target_center = config.fallback_center
        fb.bandwidth = fb.target_bandwidth = config.fallback_bandwidth
        fb.depth = fb.target_depth = config.fallback_depth  # no estimate yet: fallback at once
        self.estimate: EstimateInput | None = None
        self.now = math.nan
        self.fallback_active = True
        self.budget_limited = False
        self.lag_deg = 0.0
        self.revision = 0  # incremented on every discrete change (state, target)
        self._params: S.SectionParams | None = None  # returned again while nothing moves

    # ---- configuration ----
    @property
    def fmax(self) -> float:
        c = self.config
        return c.freq_max if c.freq_max > 0 else 0.4 * self.fs

    def reconfigure(self, config: PolicyConfig) -> None:
        """Apply new tuning live; targets follow at the usual rates."""
        if config.max_notches != self.config.max_notches:
            raise ValueError("max_notches cannot change while running")
        self.config = config
        fb = self.slots[-1]
        fb.target_center = config.fallback_center
        fb.target_bandwidth = config.fallback_bandwidth
        if self.estimate is not None and not self._stale(self.now):
            self._match(self.estimate)
        self.revision += 1

    # ---- estimates ----
    def _stale(self, now: float) -> bool:
        c, e = self.config, self.estimate
        if e is None or not e.converged or not math.isfinite(now):
            return True
        return now - e.stamp > c.stale_timeout - c.fallback_ramp

    def _uncertainty_bandwidth(self, m: ModeInput) -> float:
        c = self.config
        f = m.frequency_hz
        sf = m.frequency_std_hz
        if not (math.isfinite(sf) and sf >= 0):
            return c.bandwidth_max
        half = c.sigma_k * sf + max(c.hysteresis, c.hysteresis_sigma * sf)
        zp = S.covering_zp(f, half, c.depth, c.min_attenuation, self.fs)
        bw = float(S.bandwidth_from_zp(f, zp, c.depth, self.fs))
        zeta = m.damping_ratio if math.isfinite(m.damping_ratio) else 0.0
        zstd = m.damping_std if math.isfinite(m.damping_std) else 0.0
        bw = max(bw, c.damping_gain * 2.0 * (zeta + zstd) * f)
        return float(np.clip(bw, c.bandwidth_min, c.bandwidth_max))

    def set_estimate(self, est: EstimateInput) -> None:
        """Take a new estimate. One older than the current is ignored (out of order), unless
        it is older by more than ``stale_timeout``: the estimator restarted (e.g. a replay)."""
        cur = self.estimate
        if cur is not None and 0 < cur.stamp - est.stamp < self.config.stale_timeout:
            return
        self.estimate = est
        if self._stale(est.stamp if not math.isfinite(self.now) else max(self.now, est.stamp)):
            return
        self._match(est)

    def _match(self, est: EstimateInput) -> None:
        c = self.config
        adaptive = self.slots[:-1]
        usable = {}
        for m in est.modes:
            f = m.frequency_hz
            z = m.damping_ratio
            if (m.status == "tracked" and math.isfinite(f) and c.freq_min <= f <= self.fmax
                    and not (math.isfinite(z) and z > c.damping_max)):
                usable[int(m.id)] = m
        amps = [m.amplitude for m in usable.values() if math.isfinite(m.amplitude)]
        if amps and c.min_relative_amplitude > 0:
            floor = c.min_relative_amplitude * max(amps)
            usable = {k: m for k, m in usable.items()
                      if not (math.isfinite(m.amplitude) and m.amplitude < floor)}
        # modes that already have a notch first, then the largest (unknown amplitude last)
        held = {s.mode_id for s in adaptive if s.state != DISABLED or s.depth > 0}
        usable = dict(sorted(usable.items(), key=lambda kv: (
            kv[0] not in held,
            -(kv[1].amplitude if math.isfinite(kv[1].amplitude) else -math.inf))))
        by_id = {s.mode_id: s for s in adaptive if s.state != DISABLED or s.depth > 0}
        new: list[Slot] = []
        for mid, m in usable.items():
            slot = by_id.get(mid)
            if slot is None:
                slot = next((s for s in adaptive if s.state == DISABLED and s.depth <= 0), None)
                if slot is None:
                    continue  # bank full: the mode waits for a free section
                slot.mode_id = mid
                slot.center = slot.target_center = m.frequency_hz
                slot.shape_depth = c.depth
                bw = self._uncertainty_bandwidth(m)
                slot.bandwidth = slot.target_bandwidth = slot.desired_bandwidth = bw
                new.append(slot)
                self.revision += 1
            if slot.state != TRACKING:
                slot.state = TRACKING
                slot.hold_since = math.nan
                self.revision += 1
            slot.target_depth = c.depth
            sf = m.frequency_std_hz if math.isfinite(m.frequency_std_hz) else 0.0
            if abs(m.frequency_hz - slot.target_center) > max(c.hysteresis,
                                                               c.hysteresis_sigma * sf):
                slot.target_center = m.frequency_hz
                self.revision += 1
            bw = self._uncertainty_bandwidth(m)
            if abs(bw - slot.desired_bandwidth) > BANDWIDTH_HYSTERESIS * slot.desired_bandwidth:
                slot.desired_bandwidth = bw
                self.revision += 1
        for slot in adaptive:
            if slot.state == TRACKING and slot.mode_id not in usable:
                self._hold(slot, est.stamp)
        self._apply_budget()
        for slot in new:  # depth 0 yet: start at the budget-limited width, no sweep down
            slot.bandwidth = slot.target_bandwidth

    def _hold(self, slot: Slot, t: float) -> None:
        slot.state = HOLDING
        slot.hold_since = t
        slot.target_center = slot.center
        slot.target_bandwidth = slot.bandwidth
        self.revision += 1

    def _apply_budget(self) -> None:
        """Narrow the tracking notches by a common factor until their total phase lag at the
        crossover fits the budget (bisection; lags from scipy.signal.freqz)."""
        c = self.config
        tr = [s for s in self.slots[:-1] if s.state == TRACKING]
        self.budget_limited = False
        if not tr:
            self.lag_deg = 0.0
            return
        f0 = np.array([s.target_center for s in tr])
        want = np.array([s.desired_bandwidth for s in tr])
        lo_bw = np.minimum(c.bandwidth_min, want)

        def lag(scale: float) -> float:
            bw = lo_bw + scale * (want - lo_bw)
            sos = S.notch_sos(f0, bw, np.full(len(tr), c.depth), self.fs)
            return float(np.sum(S.section_phase_lags_deg(sos, c.crossover_frequency, self.fs)))

        scale = 1.0
        total = lag(1.0)
        if total > c.phase_lag_budget:
            self.budget_limited = True
            lo, hi = 0.0, 1.0
            for _ in range(30):
                mid = 0.5 * (lo + hi)
                if lag(mid) > c.phase_lag_budget:
                    hi = mid
                else:
                    lo = mid
            scale = lo
            total = lag(scale)
        self.lag_deg = total
        for s, w, lb in zip(tr, want, lo_bw, strict=True):
            s.target_bandwidth = float(lb + scale * (w - lb))

    # ---- time ----
    def advance(self, now: float, dt: float) -> S.SectionParams:
        """Move every section towards its target over ``dt`` seconds of data ending at
        ``now``; returns the section parameters to reach at the end of the block."""
        c = self.config
        self.now = now
        stale = self._stale(now)
        if stale != self.fallback_active:
            self.fallback_active = stale
            self.revision += 1
            if not stale and self.estimate is not None:
                self._match(self.estimate)
        fb = self.slots[-1]
        if c.fallback_depth > 0:
            fb.state = PARKED if stale else (DISABLED if fb.depth <= 0 else PARKED)
            fb.target_depth = c.fallback_depth if stale else 0.0
            fb.shape_depth = c.fallback_depth
        else:
            fb.target_depth = 0.0
        for s in self.slots[:-1]:
            if stale and s.state == TRACKING:
                self._hold(s, now)
            if s.state == HOLDING and now - s.hold_since >= c.hold_time:
                s.target_depth = 0.0
            if s.state == HOLDING and s.depth <= 0.0 and s.target_depth <= 0.0:
                s.state = DISABLED
                s.mode_id = 0
                self.revision += 1
        dt = max(float(dt), 0.0)
        lo, hi = c.freq_min, self.fmax
        last = len(self.slots) - 1
        changed = False
        for i, s in enumerate(self.slots):
            fallback = i == last
            want_shape = c.fallback_depth if fallback else c.depth
            if (s.depth <= 0 and s.target_depth <= 0 and s.center == s.target_center
                    and s.bandwidth == s.target_bandwidth and s.shape_depth == want_shape):
                continue  # idle slot
            before = (s.center, s.bandwidth, s.depth, s.shape_depth)
            step_f = c.slew_rate * dt
            if fallback:
                depth_rate = (c.fallback_depth / c.fallback_ramp if s.target_depth > s.depth
                              else c.fallback_depth / c.fade_time)
                step_f = math.inf if s.depth <= 0 else step_f
            else:
                depth_rate = c.depth / c.fade_time
            s.center = _toward(s.center, s.target_center, step_f)
            s.bandwidth = _toward(s.bandwidth, s.target_bandwidth, step_f)
            s.depth = _toward(s.depth, s.target_depth, max(depth_rate, 1e-9) * dt)
            if s.depth <= 0:
                s.shape_depth = want_shape
            else:
                s.shape_depth = _toward(s.shape_depth, want_shape,
                                        max(c.depth, 1.0) / c.fade_time * dt)
            if not fallback:
                s.center = min(max(s.center, lo), hi)
            changed = changed or before != (s.center, s.bandwidth, s.depth, s.shape_depth)
        if changed or self._params is None:
            self._params = self.params()
        return self._params

    def params(self) -> S.SectionParams:
        """Current section parameters (adaptive slots, then the fallback)."""
        sl = self.slots
        return S.SectionParams(
            np.array([s.center for s in sl]),
            np.array([s.bandwidth for s in sl]),
            np.array([s.depth for s in sl]),
            np.maximum(np.array([s.shape_depth for s in sl]), 3.5),
        )

    def status(self) -> PolicyStatus:
        """Active notches in cascade order, fallback flag, estimate age."""
        age = math.nan
        if self.estimate is not None and math.isfinite(self.now):
            age = max(self.now - self.estimate.stamp, 0.0)
        notches = [
            NotchStatus(s.mode_id, s.state, s.center, s.bandwidth, s.depth)
            for s in self.slots
            if s.depth > 0 or s.state in (TRACKING, HOLDING)
        ]
        return PolicyStatus(notches, self.fallback_active, age, self.budget_limited, self.lag_deg)


def _toward(x: float, target: float, step: float) -> float:
    if target > x:
        return min(x + step, target)
    return max(x - step, target)


def with_changes(config: PolicyConfig, **changes: float) -> PolicyConfig:
    """A copy of ``config`` with some fields changed."""
    return replace(config, **changes)
