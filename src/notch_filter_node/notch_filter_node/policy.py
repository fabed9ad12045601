"""Retuning policy of the adaptive notch bank (pure): which notch sits where, how wide, how deep.

Input is plain data (:class:`ModeInput`, :class:`EstimateInput`), output the section parameters of
the bank (:class:`~notch_filter_node.sections.SectionParams`), a status per notch and the bank's
state with its transitions.

Which modes get a notch: a mode is notched once its status is ``tracked``, its frequency lies in
``[freq_min, freq_max]``, its damping is at most ``damping_max`` and low enough that its resonance
stands ``peak_reduction`` above its static gain, and its amplitude is at least
``min_relative_amplitude`` times the largest such mode's (a mode that small hardly reaches the
feedback signal, and is often a noise mode with a wide uncertainty). When there are more such modes
than sections, the modes that already have a notch keep it and the largest come next.

The mode's model (frequency, damping, drift and their uncertainties) comes from its recent
estimates (:mod:`notch_filter_node.smoothing`). Width from the resonance it must suppress
(:mod:`notch_filter_node.resonance`): each notch is the narrowest (at ``depth``) whose peak
reduction of the mode ``G = 1 / (1 - r^2 + 2 j zeta r)`` is at least ``peak_reduction`` for every
mode in its uncertainty region: frequency ``f +- h``, ``h = sigma_k sigma_f + max(|drift rate| +
sigma_k se, drift_rate_min f) age``, damping from ``zeta`` up to ``zeta + damping_sigma_k
sigma_zeta`` (at most ``damping_max``), an ellipse, the notch sitting at its (hysteresis-held)
centre. The drift rate is the slope of the mode's recent estimates (``drift_window``) with its
standard error ``se``;
``age`` is the estimate's age, so a late estimate widens the notch by the drift the mode could have
made since. A box is designed ahead, for the age plus ``max(design_horizon, half the time since the
estimate arrived)``, and re-designed when the age outgrows it (a few times over a long gap, not at
every block). Where no notch up to ``bandwidth_max`` (0: the centre frequency) reaches the
requirement (a well-damped mode:
its peak is less than that above its static gain), the notch is the narrowest within 1 dB of the
best such notch, and says so. With ``notch_pairs`` a notch is a pair of sections at
``centre -+ spread`` (``resonance.design_pair``: a flat-bottomed stop band) where that lags
:data:`PAIR_HYSTERESIS` less at the crossover than the single notch, and single again where the
single notch lags that much less; each slot of the bank has two sections, the second bypassed
for a single notch, and a change of form fades it in or out over ``fade_time``. A notch widens
at once and narrows at ``slew_rate``. Then the phase budget: when the adaptive notches together
lag more than ``phase_lag_budget`` at ``crossover_frequency``, either they are narrowed by a
common factor (a pair's spread with its sections; ``budget_priority: phase_lag``; their
guaranteed peak reduction drops and each says so) or they keep their width and the bank says
the budget is exceeded (``peak_reduction``).

Bank states (sysid_msgs/NotchBank), in order of degradation:

- TRACKING: a fresh (age <= ``stale_timeout``), converged, healthy estimate; the notches follow
  it (centre at most at ``slew_rate`` beyond the hysteresis ``max(hysteresis, hysteresis_sigma
  sigma_f)``).
- HOLDING: the estimate is late, degraded (``health`` DEGRADED, or not converged) or the
  estimator reports a FAULT (for at most ``hold_time``): the notches that were tracking keep their
  centre and widen with the estimate's age as above; a degraded estimate never retunes them.
- PREDICTED: the identification is not to be trusted (it would HOLD or FALL BACK: late,
  degraded - e.g. starved of excitation -, unconverged or faulty), but the estimate carries the
  modes an LPV model predicts from the scheduling signal (``EstimateInput.predicted``,
  sysid_msgs/ModalEstimate.predicted_modes) and it is fresh (age <= ``stale_timeout``): the
  notches follow the predicted modes (notch state PREDICTED) with widths from their frequency
  stds, drift and age like tracked ones; a notch that followed an identified mode hands over to
  the predicted mode next to it (no fade out and in). Back to TRACKING as soon as the
  identification is good again (the notches hand back the same way). A better fallback than a
  preset notch: the prediction moves with the operating point.
- FALLBACK: nothing was tracking and the estimate is late (``stale_timeout``), or the estimate is
  older than ``fallback_timeout``, or a FAULT lasted ``hold_time``, or there was never a usable
  estimate: the configured static notch fades in over ``fallback_ramp`` (full depth at the
  timeout) and the adaptive notches fade out over ``fade_time``.

The age of an estimate is the larger of ``now - stamp`` and ``now - received`` (data time at
arrival), so a stamp from the future cannot keep an estimate fresh; a stamp more than
``future_tolerance`` ahead of the data is rejected (and counted). One stamped ahead by less
arrives while this node's input is behind (queued on a busy machine): it counts from its stamp,
so the node's own backlog does not age it (a wrong clock gains at most ``future_tolerance``).
A lost mode's notch holds for ``hold_time``, then fades its depth out over ``fade_time`` and
frees its slot. Every parameter moves at a bounded rate per second of data (centre, and
bandwidth and spread as they narrow, ``slew_rate``; depth ``depth / fade_time``; a widening at
once, spread by the bank over the block), whatever the block size.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field, replace

import numpy as np

from notch_filter_node import resonance as R
from notch_filter_node import sections as S
from notch_filter_node import smoothing as SM

# Notch states (constants of sysid_msgs/Notch)
TRACKING, HOLDING, PARKED, DISABLED, PREDICTED = 0, 1, 2, 3, 4
STATE_NAMES = {TRACKING: "tracking", HOLDING: "holding", PARKED: "parked", DISABLED: "disabled",
               PREDICTED: "predicted"}
# Bank states (constants of sysid_msgs/NotchBank), in order of degradation
BANK_TRACKING, BANK_HOLDING, BANK_PREDICTED, BANK_FALLBACK = 0, 1, 2, 3
BANK_NAMES = {BANK_TRACKING: "tracking", BANK_HOLDING: "holding", BANK_PREDICTED: "predicted",
              BANK_FALLBACK: "fallback"}
# Estimate health (constants of sysid_msgs/ModalEstimate)
HEALTH_OK, HEALTH_DEGRADED, HEALTH_FAULT = 0, 1, 2
BUDGET_PRIORITIES = ("phase_lag", "peak_reduction")
#: Relative bandwidth change below which a notch keeps a narrower-than-before target.
BANDWIDTH_HYSTERESIS = 0.1
#: A notch becomes a pair when the pair lags this fraction less than the single notch, and a
#: single notch again when that lags this fraction less than the pair (no flapping).
PAIR_HYSTERESIS = 0.1
#: A box within this relative difference of the one a pair's spread was searched for keeps it.
PAIR_BOX_TOLERANCE = 0.05
#: Where the requirement cannot be met: the narrowest notch within this of the best one [dB].
SHORTFALL_SLACK_DB = 1.0
#: A box is re-designed narrower once it has shrunk below this fraction of the designed one.
NARROW_FRACTION = 0.6
#: The designs are checked against the growing estimate age at most this often [s of data]
#: (a design looks ``design_horizon`` ahead, so a check per block would only cost time).
DESIGN_CHECK_S = 0.05
#: A late bank tracks again once the estimate is younger than this fraction of stale_timeout;
#: a bank that fell back on age holds again once it is younger than this fraction of the limit.
RECOVER_FRACTION = 0.5
AGED_OUT = " (aged out)"
#: Predicted mode k is followed as mode PREDICTED_ID_BASE + k (no clash with tracker ids).
PREDICTED_ID_BASE = 1_000_000
#: A notch hands over between an identified and a predicted mode within this relative distance
#: (or sigma_k combined stds, whichever is larger).
HANDOVER_GATE = 0.02
#: A design looks ahead by this fraction of the time since its estimate arrived (at least
#: ``design_horizon``), so a long gap is re-designed a few times, not at every block.
GAP_GROWTH = 0.5
#: The drift is fitted over at least this many memories of the identifier (its estimates are
#: correlated over one: a shorter window holds too few independent ones for a slope).
DRIFT_MEMORIES = 4.0


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
    """A modal estimate: stamp [s] (data time of the last sample it used), converged flag, modes,
    health (HEALTH_*) and ``received``: the data time (signal clock) when it arrived, NaN when
    unknown."""

    stamp: float
    converged: bool
    modes: Sequence[ModeInput] = ()
    health: int = HEALTH_OK
    health_reason: str = ""
    received: float = math.nan
    predicted: Sequence[ModeInput] = ()  # modes an LPV model predicts at the estimate's stamp
    memory: float = math.nan  # [s] identifier's memory time constant (smoothing.estimator_memory)
    lag: float = 0.0  # [s] how far its estimate of a drifting mode lags the stamp (0 = unknown)


@dataclass(frozen=True)
class PolicyConfig:
    """Tuning of the policy (SI units; the node parameters of the same names)."""

    slew_rate: float = 1.0  # [Hz/s] centre and bandwidth
    hysteresis: float = 0.005  # [Hz]
    hysteresis_sigma: float = 0.5  # [-] hysteresis in units of the frequency std
    freq_min: float = 2.0  # [Hz]
    freq_max: float = 0.0  # [Hz], 0 = 0.4 fs
    depth: float = 30.0  # [dB] at the centre
    peak_reduction: float = 15.0  # [dB] required reduction of the mode's resonance peak
    sigma_k: float = 3.0  # [-] frequency interval half-width in frequency stds
    damping_sigma_k: float = 2.0  # [-] damping taken up to zeta + this * zeta_std
    drift_window: float = 2.0  # [s] recent estimates the drift rate is fitted over
    drift_rate_min: float = 0.01  # [1/s] drift assumed at least (fraction of f per second)
    design_horizon: float = 0.2  # [s] least look-ahead of a design beyond the current age
    damping_max: float = 0.15  # [-] better damped modes get no notch
    min_relative_amplitude: float = 0.05  # [-] of the largest usable mode's amplitude
    bandwidth_min: float = 0.05  # [Hz]
    bandwidth_max: float = 0.0  # [Hz], 0 = the notch's centre frequency
    phase_lag_budget: float = 10.0  # [deg] total of the adaptive notches at the crossover
    budget_priority: str = "phase_lag"  # or "peak_reduction": which gives way
    crossover_frequency: float = 0.5  # [Hz]
    stale_timeout: float = 1.0  # [s] estimate age beyond which the bank holds
    fallback_timeout: float = 10.0  # [s] estimate age at which the fallback is at full depth
    fallback_ramp: float = 0.25  # [s]
    future_tolerance: float = 2.0  # [s] estimates stamped further ahead of the data: rejected
    hold_time: float = 1.0  # [s] lost mode's notch hold; longest hold on an estimator fault
    fade_time: float = 1.0  # [s]
    fallback_center: float = 2.79  # [Hz]
    fallback_bandwidth: float = 2.56  # [Hz]
    fallback_depth: float = 30.0  # [dB], 0 = no fallback notch
    max_notches: int = 5  # adaptive notches (two sections each; the fallback has its own)
    notch_pairs: bool = True  # a staggered pair where it lags less than a single notch


def check_config(c: PolicyConfig, fs: float = math.nan) -> str:
    """Cross checks of a configuration; '' if valid, else the reason."""
    if c.freq_max > 0 and c.freq_min >= c.freq_max:
        return f"freq_min={c.freq_min:g} Hz must be below freq_max={c.freq_max:g} Hz"
    if 0 < c.bandwidth_max < c.bandwidth_min:
        return (f"bandwidth_min={c.bandwidth_min:g} Hz must not exceed "
                f"bandwidth_max={c.bandwidth_max:g} Hz")
    if c.depth <= c.peak_reduction:
        return f"depth={c.depth:g} dB must exceed peak_reduction={c.peak_reduction:g} dB"
    if c.fallback_ramp >= c.stale_timeout:
        return (f"fallback_ramp={c.fallback_ramp:g} s must be shorter than "
                f"stale_timeout={c.stale_timeout:g} s")
    if c.stale_timeout >= c.fallback_timeout:
        return (f"stale_timeout={c.stale_timeout:g} s must be shorter than "
                f"fallback_timeout={c.fallback_timeout:g} s")
    if c.budget_priority not in BUDGET_PRIORITIES:
        return f"budget_priority='{c.budget_priority}' is not one of {', '.join(BUDGET_PRIORITIES)}"
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
    """One section of the bank, what it follows and the box it was designed for."""

    mode_id: int = 0
    state: int = DISABLED
    late: bool = False  # HOLDING because the estimate is late or degraded (not a lost mode)
    center: float = 1.0
    bandwidth: float = 0.1
    depth: float = 0.0
    shape_depth: float = 30.0
    target_center: float = 1.0
    target_bandwidth: float = 0.1
    target_depth: float = 0.0
    desired_bandwidth: float = 0.1  # before the phase-lag budget
    # form: one section at the centre, or a pair at ``center -+ spread`` (split fades between)
    spread: float = 0.0  # [Hz]
    target_spread: float = 0.0
    split: float = 0.0  # [-] 0: a single notch, 1: a pair
    target_split: float = 0.0
    pair_depth: float = 0.0  # [dB] each section of the pair
    target_pair_depth: float = 0.0
    desired_spread: float = 0.0  # the design's form, before the phase-lag budget
    desired_pair_depth: float = 0.0  # 0: the design is a single notch
    pair_factor: float = math.nan  # the pair spread the last search found (resonance.design_pair)
    pair_box: tuple[float, ...] = ()  # for a box of this shape: h/f, zeta_hi, zeta_c, offset/f
    hold_since: float = math.nan
    # the mode model: estimate, drift bound [Hz/s], stamp and arrival of its estimate
    f: float = math.nan
    f_std: float = math.nan
    zeta: float = math.nan
    zeta_hi: float = math.nan
    drift: float = 0.0
    stamp: float = math.nan
    received: float = math.nan
    # the box the desired bandwidth was designed for, and what it guarantees there
    design: tuple[float, ...] = (math.nan,) * 5  # f_lo, f_hi, zeta_hi, centre, zeta_c
    guaranteed: float = math.nan  # [dB] peak reduction over the box, this notch alone
    limit: str = ""  # why ``guaranteed`` is below the requirement ('' when it is not)


@dataclass(frozen=True)
class NotchStatus:
    """What one active section does now (for sysid_msgs/Notch)."""

    mode_id: int
    state: int
    center: float
    bandwidth: float
    depth: float
    limit: str = ""
    shape_depth: float = math.nan  # [dB] depth whose poles (and bandwidth) the section has


@dataclass(frozen=True)
class Transition:
    """A change of the bank state at data time ``t`` (estimate ``age`` [s] then)."""

    t: float
    old: int
    new: int
    age: float
    reason: str

    def text(self) -> str:
        age = f"{self.age:.2f} s" if math.isfinite(self.age) else "none"
        why = f": {self.reason}" if self.reason else ""
        return (f"notch bank {BANK_NAMES[self.old]} -> {BANK_NAMES[self.new]} "
                f"(estimate age {age}){why}")


@dataclass
class PolicyStatus:
    """Summary for the node's NotchBank and diagnostics."""

    notches: list[NotchStatus] = field(default_factory=list)
    fallback_active: bool = True
    estimate_age: float = math.nan
    budget_limited: bool = False
    phase_lag_deg: float = 0.0  # adaptive notches at their target bandwidths
    bank_state: int = BANK_FALLBACK
    reason: str = ""


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
        self.estimate: EstimateInput | None = None  # latest accepted, any health
        self.good: EstimateInput | None = None  # latest converged and healthy
        self.predicted: EstimateInput | None = None  # latest LPV prediction, as an estimate
        self.now = math.nan
        self.bank_state = BANK_FALLBACK
        self.reason = "no estimate yet"
        self.fallback_active = True
        self.budget_limited = False
        self.lag_deg = 0.0
        self.revision = 0  # incremented on every discrete change (state, target)
        self.transitions: list[Transition] = []  # drained by the caller
        self.counts: dict[str, int] = {}
        self._fault_since = math.nan
        self._history: dict[int, list[tuple[float, ...]]] = {}  # (t, f, f_std, zeta, zeta_std)
        self._memory: dict[int, tuple[float, float]] = {}  # mode id: (memory, lag) [s]
        self._params: S.SectionParams | None = None  # returned again while nothing moves
        self._budget_key: tuple = ()
        self._checked = -math.inf  # data time the designs were last checked against the age

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
        for s in self.slots[:-1]:
            s.design = (math.nan,) * 5  # re-design every notch under the new rules
        if self.good is not None and self.bank_state in (BANK_TRACKING, BANK_HOLDING):
            self._match(self.good)
        else:
            self._redesign(self._budgeted(), force=True)
            self._apply_budget()
        self.revision += 1

    def set_rate(self, fs: float) -> None:
        """The sample rate changed: same notches in Hz, sections re-designed at ``fs``."""
        self.fs = float(fs)
        self._params = None
        for s in self.slots[:-1]:
            s.design = (math.nan,) * 5
        self._redesign(self._budgeted(), force=True)
        self._apply_budget()
        self.revision += 1

    # ---- estimates ----
    def _count(self, key: str) -> None:
        self.counts[key] = self.counts.get(key, 0) + 1

    def age(self, now: float | None = None) -> float:
        """Age [s] of the latest good estimate at data time ``now``: the larger of the stamp's
        age and the arrival's; NaN without one."""
        now = self.now if now is None else now
        e = self.good
        if e is None or not math.isfinite(now):
            return math.nan
        a = now - e.stamp
        if math.isfinite(e.received):
            a = max(a, now - e.received)
        return max(a, 0.0)

    def set_estimate(self, est: EstimateInput) -> str:
        """Take a new estimate; returns '' when taken, else why it was rejected (also counted).
        Rejected: stamped more than ``future_tolerance`` ahead of the data; older than the
        current one by less than ``stale_timeout`` (out of order); the same stamp again. Older
        by more is an estimator restart and taken. DEGRADED or unconverged estimates hold the
        bank and never retune it; a FAULT holds it, then falls back."""
        c = self.config
        ref = max((t for t in (self.now, est.received) if math.isfinite(t)), default=math.nan)
        if math.isfinite(ref) and est.stamp > ref + c.future_tolerance:
            self._count("future_stamp")
            return f"estimate stamped {est.stamp - ref:.3g} s ahead of the data: rejected"
        if math.isfinite(est.received) and est.stamp > est.received:
            # ahead of the data when it arrived (within the tolerance): this node's input is
            # behind (a queue on a loaded machine), not the estimate; it is no older than its
            # stamp, so its arrival counts from there (else the node's own backlog would age it)
            est = replace(est, received=est.stamp)
        cur = self.estimate
        if cur is not None and est.stamp == cur.stamp:
            self._count("duplicate_estimate")
            return "estimate with the same stamp again: ignored"
        if cur is not None and 0 < cur.stamp - est.stamp < c.stale_timeout:
            self._count("out_of_order_estimate")
            return f"estimate {cur.stamp - est.stamp:.3g} s older than the current one: ignored"
        restart = cur is not None and est.stamp < cur.stamp
        self.estimate = est
        if restart:
            self._history.clear()
            self._memory.clear()
            if self.good is not None and self.good.stamp > est.stamp:
                self.good = None
        if est.health == HEALTH_FAULT:
            if not math.isfinite(self._fault_since):
                self._fault_since = ref if math.isfinite(ref) else est.stamp
        else:
            self._fault_since = math.nan
        if est.health == HEALTH_OK and est.converged:
            self._remember(est)
            self.good = est
        self.predicted = self._prediction(est)
        if self.predicted is not None:
            self._remember(self.predicted)  # the predicted modes' drift, like tracked ones
        now = self.now if math.isfinite(self.now) else est.stamp
        self._update_state(now)
        if self.bank_state == BANK_PREDICTED and self.predicted is not None:
            self._match(self.predicted, PREDICTED)
            return ""
        if self.good is not est:
            return ""  # degraded, unconverged or fault: hold, never retune on it
        age = self.age(now)
        if self.bank_state in (BANK_TRACKING, BANK_HOLDING):
            self._match(est)  # a late but newer estimate still knows more than the last one
        elif age <= RECOVER_FRACTION * c.fallback_timeout and self._usable(est):
            # late from the start, or back after a fallback: late modes are held, not lost
            self._match(est, TRACKING if age <= c.stale_timeout else HOLDING)
            self._update_state(now)
        return ""

    def _remember(self, est: EstimateInput) -> None:
        """Keep the recent estimates of tracked modes (the mode models' window) and the
        identifier's memory and lag they came with."""
        for m in est.modes:
            if m.status == "tracked" and math.isfinite(m.frequency_hz):
                mid = int(m.id)
                self._history.setdefault(mid, []).append(
                    (est.stamp, m.frequency_hz, m.frequency_std_hz, m.damping_ratio,
                     m.damping_std))
                self._memory[mid] = (est.memory, est.lag)
        for mid in list(self._history):
            keep = est.stamp - self._window(mid)
            h = [p for p in self._history[mid] if p[0] >= keep]
            if h:
                self._history[mid] = h
            else:
                del self._history[mid]
                self._memory.pop(mid, None)

    def _window(self, mid: int) -> float:
        """Span [s] a mode's model is fitted over: ``drift_window``, at least
        ``DRIFT_MEMORIES`` memories of the identifier that estimated it."""
        memory = self._memory.get(mid, (math.nan, 0.0))[0]
        w = self.config.drift_window
        return max(w, DRIFT_MEMORIES * memory) if math.isfinite(memory) else w

    @staticmethod
    def _prediction(est: EstimateInput) -> EstimateInput | None:
        """The estimate's LPV prediction as an estimate of its own (ids offset), or None."""
        if not est.predicted:
            return None
        modes = [replace(m, id=PREDICTED_ID_BASE + int(m.id), status="tracked")
                 for m in est.predicted]
        return EstimateInput(est.stamp, True, modes, HEALTH_OK, "", est.received)

    def _prediction_fresh(self, now: float) -> bool:
        p = self.predicted
        if p is None or not self._usable(p):
            return False
        age = now - p.stamp
        if math.isfinite(p.received):
            age = max(age, now - p.received)
        return age <= self.config.stale_timeout

    def _handover(self, modes: dict[int, ModeInput]) -> None:
        """A notch that follows another mode (identified <-> predicted) within the gate of one
        of ``modes`` without a notch of its own takes that mode over."""
        c = self.config
        active = [s for s in self.slots[:-1] if s.depth > 0 and s.state in (TRACKING, HOLDING,
                                                                             PREDICTED)]
        taken = {s.mode_id for s in active}
        for mid, m in modes.items():
            if mid in taken:
                continue
            free = [s for s in active if s.mode_id not in modes]
            if not free:
                return
            near = min(free, key=lambda s: abs(s.center - m.frequency_hz))
            sf = math.hypot(*(x if math.isfinite(x) else 0.0
                              for x in (m.frequency_std_hz, near.f_std)))
            if abs(near.center - m.frequency_hz) <= max(HANDOVER_GATE * m.frequency_hz,
                                                       c.sigma_k * sf):
                near.mode_id = mid
                taken.add(mid)
                self.revision += 1

    def mode_model(self, m: ModeInput) -> SM.ModeModel:
        """The mode's model from its estimates over its window (:meth:`_window`,
        :mod:`smoothing`, with the identifier's memory and lag); the estimate itself while the
        window is short."""
        h = self._history.get(int(m.id))
        if not h:
            return SM.ModeModel(m.frequency_hz, m.frequency_std_hz, m.damping_ratio,
                                m.damping_std)
        t, f, sf, z, sz = (np.array(v, dtype=float) for v in zip(*h, strict=True))
        memory, lag = self._memory.get(int(m.id), (math.nan, 0.0))
        return SM.model(t, f, sf, z, sz, self._window(int(m.id)), memory, lag)

    def _usable(self, est: EstimateInput) -> dict[int, ModeInput]:
        c = self.config
        usable = {}
        # a resonance that stands less than the requirement above its static gain cannot be
        # brought down by it with any notch: no phase is spent on it
        z_most = min(c.damping_max, damping_for_peak(c.peak_reduction))
        for m in est.modes:
            f = m.frequency_hz
            z = m.damping_ratio
            if (m.status == "tracked" and math.isfinite(f) and c.freq_min <= f <= self.fmax
                    and not (math.isfinite(z) and z > z_most)):
                usable[int(m.id)] = m
        amps = [m.amplitude for m in usable.values() if math.isfinite(m.amplitude)]
        if amps and c.min_relative_amplitude > 0:
            floor = c.min_relative_amplitude * max(amps)
            usable = {k: m for k, m in usable.items()
                      if not (math.isfinite(m.amplitude) and m.amplitude < floor)}
        return usable

    def _one_per_resonance(self, usable: dict[int, ModeInput]) -> dict[int, ModeInput]:
        """Two tracks within one resonance (closer than the larger half-power half-width plus
        ``sigma_k`` frequency stds: a split track) get one notch, the first in ``usable``'s
        order (the one already notched, else the larger)."""
        k = self.config.sigma_k
        kept: dict[int, ModeInput] = {}
        for mid, m in usable.items():
            z = m.damping_ratio if math.isfinite(m.damping_ratio) else 0.0
            sf = m.frequency_std_hz if math.isfinite(m.frequency_std_hz) else 0.0
            if not any(abs(m.frequency_hz - o.frequency_hz) < max(
                    z * m.frequency_hz, (o.damping_ratio if math.isfinite(o.damping_ratio)
                                         else 0.0) * o.frequency_hz) + k * max(
                    sf, o.frequency_std_hz if math.isfinite(o.frequency_std_hz) else 0.0)
                    for o in kept.values()):
                kept[mid] = m
        return kept

    def _match(self, est: EstimateInput, following: int | None = None) -> None:
        """Notches onto the estimate's usable modes; ``following``: the notch state (TRACKING,
        HOLDING or PREDICTED), by default the bank's."""
        c = self.config
        adaptive = self.slots[:-1]
        usable = self._usable(est)
        self._handover(usable)  # identified <-> predicted: the notch next to a mode takes it
        # modes that already have a notch first, then the largest (unknown amplitude last)
        held = {s.mode_id for s in adaptive if s.state != DISABLED or s.depth > 0}
        usable = dict(sorted(usable.items(), key=lambda kv: (
            kv[0] not in held,
            -(kv[1].amplitude if math.isfinite(kv[1].amplitude) else -math.inf))))
        by_id = {s.mode_id: s for s in adaptive if s.state != DISABLED or s.depth > 0}
        usable = self._one_per_resonance(usable)
        new: list[Slot] = []
        touched: list[Slot] = []
        if following is None:
            following = TRACKING if self.bank_state == BANK_TRACKING else HOLDING
        for mid, m in usable.items():
            mm = self.mode_model(m)
            slot = by_id.get(mid)
            if slot is None:
                slot = next((s for s in adaptive if s.state == DISABLED and s.depth <= 0), None)
                if slot is None:
                    continue  # bank full: the mode waits for a free section
                slot.mode_id = mid
                slot.center = slot.target_center = mm.frequency
                slot.shape_depth = c.depth
                slot.design = (math.nan,) * 5
                new.append(slot)
                self.revision += 1
            if slot.state != following or slot.late != (following == HOLDING):
                slot.state = following
                slot.late = following == HOLDING
                slot.hold_since = est.stamp if following == HOLDING else math.nan
                self.revision += 1
            slot.target_depth = c.depth
            sf = mm.frequency_std if math.isfinite(mm.frequency_std) else 0.0
            if abs(mm.frequency - slot.target_center) > max(c.hysteresis,
                                                             c.hysteresis_sigma * sf):
                slot.target_center = mm.frequency
                self.revision += 1
            self._set_model(slot, mm, est)
            touched.append(slot)
        for slot in adaptive:
            if slot.mode_id not in usable and (slot.state in (TRACKING, PREDICTED)
                                               or (slot.state == HOLDING and slot.late)):
                self._hold(slot, est.stamp)
        self._redesign(touched)
        self._apply_budget()
        for slot in new:  # depth 0 yet: start at the budget-limited width, no sweep down
            slot.bandwidth = slot.target_bandwidth
            slot.spread, slot.split = slot.target_spread, slot.target_split
            slot.pair_depth = slot.target_pair_depth

    def _set_model(self, slot: Slot, mm: SM.ModeModel, est: EstimateInput) -> None:
        c = self.config
        slot.f = mm.frequency
        slot.f_std = mm.frequency_std
        slot.zeta = mm.damping
        if math.isfinite(mm.damping):
            zstd = mm.damping_std if math.isfinite(mm.damping_std) else 0.0
            slot.zeta_hi = min(mm.damping + c.damping_sigma_k * zstd, c.damping_max)
        else:
            slot.zeta_hi = c.damping_max
        slot.drift = abs(mm.drift) + c.sigma_k * mm.drift_std
        slot.stamp = est.stamp
        slot.received = est.received

    def _hold(self, slot: Slot, t: float) -> None:
        """A lost mode: the notch holds its centre and width for ``hold_time``, then fades."""
        slot.state = HOLDING
        slot.late = False
        slot.hold_since = t
        slot.target_center = slot.center
        slot.target_bandwidth = slot.bandwidth
        slot.target_spread, slot.target_split = slot.spread, slot.split
        slot.target_pair_depth = slot.pair_depth
        self.revision += 1

    # ---- width ----
    def _slot_age(self, s: Slot, now: float) -> float:
        if not (math.isfinite(now) and math.isfinite(s.stamp)):
            return 0.0
        a = now - s.stamp
        if math.isfinite(s.received):
            a = max(a, now - s.received)
        return max(a, 0.0)

    def half_width(self, s: Slot, age: float) -> float:
        """Half-width [Hz] of the frequency box of a slot's mode at estimate age ``age``."""
        c = self.config
        return c.sigma_k * s.f_std + max(s.drift, c.drift_rate_min * s.f) * max(age, 0.0)

    def _design_age(self, s: Slot, now: float) -> float:
        """Estimate age a design covers: the age now plus the look-ahead."""
        age = self._slot_age(s, now)
        since = now - s.received if math.isfinite(s.received) and math.isfinite(now) else age
        return age + max(self.config.design_horizon, GAP_GROWTH * max(since, 0.0))

    @staticmethod
    def _zeta_c(s: Slot) -> float:
        """Centre of the damping range of a slot's mode (the estimate, at most the top)."""
        return min(s.zeta, s.zeta_hi) if math.isfinite(s.zeta) else s.zeta_hi

    def _budgeted(self) -> list[Slot]:
        return [s for s in self.slots[:-1]
                if s.state in (TRACKING, PREDICTED) or (s.state == HOLDING and s.late)]

    def _needs_design(self, s: Slot, age: float) -> bool:
        lo, hi, zeta, centre, zeta_c = s.design
        if not math.isfinite(s.f_std):
            return centre != s.target_center
        h = self.half_width(s, age)
        # the new region lies inside the designed one (interval inside, damping centre and top
        # not higher): the design still holds
        if not (s.f - h >= lo and s.f + h <= hi and s.zeta_hi <= zeta
                and self._zeta_c(s) <= zeta_c and centre == s.target_center):
            return True  # outgrown (or never designed)
        h_ahead = self.half_width(s, age + self.config.design_horizon)
        return 2.0 * h_ahead < NARROW_FRACTION * (hi - lo)  # could be markedly narrower

    def _redesign(self, slots: Sequence[Slot], force: bool = False) -> bool:
        """Design the slots whose box outgrew (or undergrew) their design; True if any was
        (the caller then applies the budget)."""
        now = self.now if math.isfinite(self.now) else max(
            (s.stamp for s in slots if math.isfinite(s.stamp)), default=math.nan)
        todo = [s for s in slots if force or self._needs_design(s, self._slot_age(s, now))]
        if todo:
            unknown = [s for s in todo if not math.isfinite(s.f_std)]
            for s in unknown:  # no frequency std: the widest notch
                s.design = (math.nan, math.nan, math.nan, s.target_center, math.nan)
                s.guaranteed, s.limit = math.nan, "frequency std unknown"
                self._set_desired(s, float(self.widest(s.target_center)))
            known = [s for s in todo if math.isfinite(s.f_std)]
            if known:
                self._design(known, now)
        return bool(todo)

    def _design(self, slots: Sequence[Slot], now: float) -> None:
        c = self.config
        ages = np.array([self._design_age(s, now) for s in slots])
        f = np.array([s.f for s in slots])
        h = np.array([self.half_width(s, a) for s, a in zip(slots, ages, strict=True)])
        zeta = np.array([s.zeta_hi for s in slots])
        zc = np.array([self._zeta_c(s) for s in slots])
        tc = np.array([s.target_center for s in slots])
        lo, hi = f - h, f + h
        widest = self.widest(tc)
        zp_min, _ = S.pole_zero_damping(tc, np.minimum(c.bandwidth_min, widest), c.depth,
                                        self.fs)
        zp_max, _ = S.pole_zero_damping(tc, widest, c.depth, self.fs)
        zp, worst = R.design_zp(tc, lo, hi, zeta, c.peak_reduction, c.depth, self.fs,
                                zp_min, zp_max, zeta_c=zc)
        short = worst < c.peak_reduction - R.DECISION_MARGIN_DB
        if short.any():  # unattainable: the narrowest within SHORTFALL_SLACK_DB of the best
            k = np.flatnonzero(short)
            zp_k, worst_k = R.design_zp(tc[k], lo[k], hi[k], zeta[k],
                                        float(np.min(worst[k])) - SHORTFALL_SLACK_DB,
                                        c.depth, self.fs, zp_min[k], zp_max[k], zeta_c=zc[k])
            zp[k], worst[k] = zp_k, worst_k
        bw = S.bandwidth_from_zp(tc, zp, c.depth, self.fs)
        pair = np.zeros(len(slots), dtype=bool)
        if c.notch_pairs and not short.all():
            pr = self._design_pairs(slots, np.stack([h / f, zeta, zc, (tc - f) / f], axis=1),
                                    tc, lo, hi, zeta, zc, zp)
            g = 10.0 ** (-c.depth / 20.0)
            single = S.damping_lag_deg(c.crossover_frequency, tc, zp, g * zp, self.fs)
            was = np.array([s.desired_pair_depth > 0 for s in slots])
            pair = ~short & (pr.lag_deg < single * np.where(was, 1.0 + PAIR_HYSTERESIS,
                                                            1.0 - PAIR_HYSTERESIS))
        for i, s in enumerate(slots):
            s.design = (float(lo[i]), float(hi[i]), float(zeta[i]), float(tc[i]), float(zc[i]))
            s.limit = (f"at most {worst[i]:.1f} dB within the widest notch (bandwidth_max; damping "
                       f"{zeta[i]:.3f})" if short[i] else "")
            if pair[i]:
                b = S.bandwidth_from_zp(tc[i], pr.zp[i], float(pr.depth_db[i]), self.fs)
                if s.desired_pair_depth > 0 and self._keeps_pair(s, float(b), i, lo, hi, zeta,
                                                                 tc, zc):
                    continue  # the pair it has still holds the new box and is hardly wider
                s.guaranteed = float(pr.worst[i])
                s.desired_spread = float(pr.spread[i])
                s.desired_pair_depth = float(pr.depth_db[i])
                self._set_desired(s, float(b), exact=True)  # a new pair: its own width
            else:
                s.guaranteed = float(worst[i])
                flip = s.desired_pair_depth > 0  # a pair becomes a single notch
                s.desired_spread = s.desired_pair_depth = 0.0
                self._set_desired(s, float(bw[i]), exact=flip)

    def _keeps_pair(self, s: Slot, bw: float, i: int, lo: np.ndarray, hi: np.ndarray,
                    zeta: np.ndarray, tc: np.ndarray, zc: np.ndarray) -> bool:
        """A pair's new design only narrows it by less than BANDWIDTH_HYSTERESIS: it keeps the
        pair it has (no churn) if that still meets the requirement over the new box (its worst
        reduction there becomes the guarantee)."""
        if not ((1.0 - BANDWIDTH_HYSTERESIS) * s.desired_bandwidth <= bw <= s.desired_bandwidth):
            return False
        f, zp, zz = self._form(np.array([tc[i]]), np.array([s.desired_bandwidth]),
                               np.array([s.desired_spread]), np.array([s.desired_pair_depth]))
        worst = float(R.worst_peak_reduction_db(lo[i:i + 1], hi[i:i + 1], zeta[i:i + 1], f, zp,
                                                zz, self.fs, zeta_c=zc[i:i + 1])[0])
        if worst < self.config.peak_reduction - R.DECISION_MARGIN_DB:
            return False
        s.guaranteed = worst
        return True

    def _design_pairs(self, slots: Sequence[Slot], boxes: np.ndarray, tc: np.ndarray,
                      lo: np.ndarray, hi: np.ndarray, zeta: np.ndarray, zc: np.ndarray,
                      zp: np.ndarray) -> R.PairDesign:
        """The least lagging pair per slot (:func:`resonance.design_pair`). A box of the same
        shape as at the slot's last search (``boxes``: h/f, zeta_hi, zeta_c, centre offset/f,
        within :data:`PAIR_BOX_TOLERANCE`; e.g. one that only moved with its mode) tries the
        spread found then alone (its pole damping solved again); the others, or where that no
        longer meets the requirement, search all spreads."""
        c = self.config
        args = (c.peak_reduction, c.depth, self.fs)
        n = len(slots)
        factor = np.array([s.pair_factor for s in slots])
        same = np.array([len(s.pair_box) == 4 and np.allclose(
            boxes[i], s.pair_box, rtol=PAIR_BOX_TOLERANCE, atol=1e-4)
            for i, s in enumerate(slots)]) & np.isfinite(factor)
        out = {k: np.full(n, np.nan) for k in ("spread", "depth_db", "zp", "worst", "lag_deg",
                                                "factor")}

        def run(k: np.ndarray, factors: np.ndarray) -> None:
            d = R.design_pair(tc[k], lo[k], hi[k], zeta[k], *args, zp[k],
                              c.crossover_frequency, zeta_c=zc[k], factors=factors)
            for name in out:
                out[name][k] = getattr(d, name)

        for q in np.unique(factor[same]):
            run(np.flatnonzero(same & (factor == q)), np.array([q]))
        cold = ~same | ~np.isfinite(out["lag_deg"])
        if cold.any():
            run(np.flatnonzero(cold), R.PAIR_SPREADS)
            for i in np.flatnonzero(cold):
                slots[i].pair_box = tuple(float(v) for v in boxes[i])
                slots[i].pair_factor = float(out["factor"][i])
        return R.PairDesign(**out)

    def widest(self, center: np.ndarray | float) -> np.ndarray:
        """The widest notch [Hz] at ``center``: ``bandwidth_max``, or with 0 the centre
        frequency itself (a width that scales with the mode: a 1 %-damped mode at 40 Hz
        needs a notch about 4 Hz wide for 15 dB even when it is known exactly)."""
        c = self.config
        center = np.asarray(center, dtype=float)
        if c.bandwidth_max > 0:
            return np.full(center.shape, c.bandwidth_max)
        return np.maximum(center, c.bandwidth_min)

    def _set_desired(self, s: Slot, bw: float, exact: bool = False) -> None:
        """Widen at once; narrow only by more than BANDWIDTH_HYSTERESIS (no churn; a single
        notch at the same centre only gains from being wider); ``exact``: a new form (a pair's
        new spread, or a change of form) takes its own width."""
        bw = float(np.clip(bw, self.config.bandwidth_min, self.widest(s.target_center)))
        if (exact or bw > s.desired_bandwidth
                or bw < (1.0 - BANDWIDTH_HYSTERESIS) * s.desired_bandwidth):
            if exact or abs(bw - s.desired_bandwidth) > BANDWIDTH_HYSTERESIS * s.desired_bandwidth:
                self.revision += 1
            s.desired_bandwidth = bw

    def _form(self, centres: np.ndarray, bws: np.ndarray, spreads: np.ndarray,
              pair_depths: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Sections ``(centre, zp, zz)``, shape ``(..., n, 2)``, of notches of the given form
        (bandwidths ``(..., n)``; pair depth 0: one section of ``depth``, the second a unit)."""
        single = pair_depths <= 0
        shape = np.where(single, self.config.depth, pair_depths)[..., None]
        f = centres[..., None] + spreads[..., None] * np.array([-1.0, 1.0])
        zp, zz = S.pole_zero_damping(f, bws[..., None], shape, self.fs)
        return f, zp, np.where(single[..., None] & np.array([False, True]), zp, zz)

    def _lags(self, centres: np.ndarray, bws: np.ndarray, spreads: np.ndarray,
              pair_depths: np.ndarray) -> np.ndarray:
        """Summed phase lag [deg] at the crossover of notches (bandwidths ``(..., n)``)."""
        f, zp, zz = self._form(centres, bws, spreads, pair_depths)
        lag = S.damping_lag_deg(self.config.crossover_frequency, f, zp, zz, self.fs)
        return np.sum(lag, axis=(-2, -1))

    def _apply_budget(self) -> None:
        """Hold the adaptive notches' total phase lag at the crossover within the budget (a
        common narrowing factor), or report it exceeded (``budget_priority``)."""
        c = self.config
        tr = self._budgeted()
        key = (c, self.fs,
               tuple((id(s), s.target_center, s.desired_bandwidth, s.desired_spread,
                      s.desired_pair_depth, s.design) for s in tr))
        if key == self._budget_key:
            return  # nothing it depends on changed
        self._budget_key = key
        self.budget_limited = False
        if not tr:
            self.lag_deg = 0.0
            return
        f0 = np.array([s.target_center for s in tr])
        want = np.array([s.desired_bandwidth for s in tr])
        spreads = np.array([s.desired_spread for s in tr])
        pds = np.array([s.desired_pair_depth for s in tr])
        lo_bw = np.minimum(c.bandwidth_min, want)
        scale = 1.0
        total = float(self._lags(f0, want, spreads, pds))
        if total > c.phase_lag_budget and c.budget_priority == "phase_lag":
            self.budget_limited = True
            a, b = 0.0, 1.0
            for _ in range(3):  # three passes of 64 scales: about 1/250000 of the range
                q = np.linspace(a, b, 64)
                bws = lo_bw + q[:, None] * (want - lo_bw)
                lags = self._lags(f0, bws, spreads * bws / want, pds)
                k = int(np.searchsorted(lags, c.phase_lag_budget, side="right"))  # lag grows
                a, b = q[max(k - 1, 0)], q[min(k, 63)]
            scale = a
            bws = lo_bw + scale * (want - lo_bw)
            total = float(self._lags(f0, bws, spreads * bws / want, pds))
        self.lag_deg = total
        narrowed = []
        for s, w, lb in zip(tr, want, lo_bw, strict=True):
            s.target_bandwidth = float(lb + scale * (w - lb))
            s.target_spread = s.desired_spread * s.target_bandwidth / w  # a pair shrinks whole
            s.target_split = 1.0 if s.desired_pair_depth > 0 else 0.0
            if s.desired_pair_depth > 0:
                s.target_pair_depth = s.desired_pair_depth
            if scale < 1.0 and math.isfinite(s.design[0]):
                narrowed.append(s)
        if narrowed:  # what the narrowed notches still guarantee over their boxes
            f, zp, zz = self._form(*(np.array([getattr(s, a) for s in narrowed]) for a in (
                "target_center", "target_bandwidth", "target_spread", "desired_pair_depth")))
            worst = R.worst_peak_reduction_db(
                np.array([s.design[0] for s in narrowed]),
                np.array([s.design[1] for s in narrowed]),
                np.array([s.design[2] for s in narrowed]),
                f, zp, zz, self.fs,
                zeta_c=np.array([s.design[4] for s in narrowed]))  # (grid: up to the depth)
            for s, w in zip(narrowed, worst, strict=True):
                s.guaranteed = float(w)
                if w < c.peak_reduction - R.DECISION_MARGIN_DB:
                    s.limit = (f"phase budget {c.phase_lag_budget:g} deg: {w:.1f} dB < "
                               f"{c.peak_reduction:g} dB")
        elif total > c.phase_lag_budget:
            self.budget_limited = True

    # ---- bank state ----
    def _held(self) -> bool:
        return any(s.state in (TRACKING, PREDICTED) or (s.state == HOLDING and s.late)
                   for s in self.slots[:-1])

    def _evaluate(self, now: float) -> tuple[int, str]:
        """The identification's verdict, replaced by PREDICTED when it would hold or fall back
        and a fresh LPV prediction is at hand."""
        new, reason = self._evaluate_identification(now)
        if (new in (BANK_HOLDING, BANK_FALLBACK) and self.estimate is not None
                and self._prediction_fresh(now)):
            return BANK_PREDICTED, f"{reason or 'identification not usable'}: LPV prediction"
        return new, reason

    def _evaluate_identification(self, now: float) -> tuple[int, str]:
        c = self.config
        latest, good = self.estimate, self.good
        if latest is None:
            return BANK_FALLBACK, "no estimate yet"
        held = self._held()
        age = self.age(now)
        if latest.health == HEALTH_FAULT:
            why = f"estimator fault: {latest.health_reason or 'no reason given'}"
            if held and now - self._fault_since < c.hold_time:
                return BANK_HOLDING, why
            return BANK_FALLBACK, why
        if good is None:
            return BANK_FALLBACK, ("no converged estimate yet" if latest.health == HEALTH_OK
                                   else f"estimate degraded: {latest.health_reason}")
        limit = c.fallback_timeout if held else c.stale_timeout
        aged_out = self.bank_state == BANK_FALLBACK and self.reason.endswith(AGED_OUT)
        if age > limit - c.fallback_ramp or (aged_out and age > RECOVER_FRACTION * limit):
            what = ", no notch was tracking" if not held else ""
            return BANK_FALLBACK, f"estimate {age:.2f} s old{what}{AGED_OUT}"
        if latest is not good:
            why = (f"estimate degraded: {latest.health_reason or 'no reason given'}"
                   if latest.health == HEALTH_DEGRADED else "estimate not converged")
            return (BANK_HOLDING, why) if held else (BANK_FALLBACK, why + ", no notch tracking")
        back = RECOVER_FRACTION * c.stale_timeout  # hysteresis: no flapping at the limit
        if age > c.stale_timeout or (self.bank_state == BANK_HOLDING and age > back
                                     and self.reason.startswith("estimate late")):
            return BANK_HOLDING, f"estimate late ({age:.2f} s)"
        return BANK_TRACKING, ""

    def _update_state(self, now: float) -> None:
        new, reason = self._evaluate(now)
        self.reason = reason
        old = self.bank_state
        if new == old:
            return
        self.bank_state = new
        self.fallback_active = new == BANK_FALLBACK
        self.transitions.append(Transition(now, old, new, self.age(now), reason))
        self._count(f"to_{BANK_NAMES[new]}")
        self.revision += 1
        if new == BANK_HOLDING:
            for s in self.slots[:-1]:
                if s.state in (TRACKING, PREDICTED):
                    s.state, s.late, s.hold_since = HOLDING, True, now
        elif new == BANK_FALLBACK:
            for s in self.slots[:-1]:
                if s.state in (TRACKING, PREDICTED) or (s.state == HOLDING and s.late):
                    s.state, s.late, s.hold_since = HOLDING, False, now
                    s.target_depth = 0.0  # fade out now: the fallback takes over
            self._apply_budget()
        elif new == BANK_TRACKING and self.good is not None:
            self._match(self.good)
        elif new == BANK_PREDICTED and self.predicted is not None:
            self._match(self.predicted, PREDICTED)

    # ---- time ----
    def advance(self, now: float, dt: float) -> S.SectionParams:
        """Move every section towards its target over ``dt`` seconds of data ending at
        ``now``; returns the section parameters to reach at the end of the block."""
        c = self.config
        self.now = now
        dropped = set()
        for name in ("estimate", "good"):  # judged once the data clock is known
            e = getattr(self, name)
            if e is not None and e.stamp > now + c.future_tolerance:
                setattr(self, name, None)
                if id(e) not in dropped:
                    self._count("future_stamp")
                dropped.add(id(e))
        self._update_state(now)
        stale = self.bank_state == BANK_FALLBACK
        fb = self.slots[-1]
        if c.fallback_depth > 0:
            fb.state = PARKED if stale else (DISABLED if fb.depth <= 0 else PARKED)
            fb.target_depth = c.fallback_depth if stale else 0.0
            fb.shape_depth = c.fallback_depth
        else:
            fb.target_depth = 0.0
        for s in self.slots[:-1]:
            if s.state == HOLDING and not s.late and now - s.hold_since >= c.hold_time:
                s.target_depth = 0.0
            if s.state == HOLDING and s.depth <= 0.0 and s.target_depth <= 0.0:
                s.state = DISABLED
                s.mode_id = 0
                s.late = False
                self.revision += 1
        if (self.bank_state in (BANK_TRACKING, BANK_HOLDING, BANK_PREDICTED)
                and not 0.0 <= now - self._checked < DESIGN_CHECK_S):  # (or time went back)
            self._checked = now
            if self._redesign(self._budgeted()):
                self._apply_budget()  # widened with the age
        dt = max(float(dt), 0.0)
        lo, hi = c.freq_min, self.fmax
        last = len(self.slots) - 1
        changed = False
        for i, s in enumerate(self.slots):
            fallback = i == last
            want_shape = c.fallback_depth if fallback else c.depth
            form = (s.spread, s.split, s.pair_depth)
            if (s.depth <= 0 and s.target_depth <= 0 and s.center == s.target_center
                    and s.bandwidth == s.target_bandwidth and s.shape_depth == want_shape
                    and form == (s.target_spread, s.target_split, s.target_pair_depth)):
                continue  # idle slot
            before = (s.center, s.bandwidth, s.depth, s.shape_depth) + form
            step_f = c.slew_rate * dt
            if fallback:
                depth_rate = (c.fallback_depth / c.fallback_ramp if s.target_depth > s.depth
                              else c.fallback_depth / c.fade_time)
                step_f = math.inf if s.depth <= 0 else step_f
            else:
                depth_rate = c.depth / c.fade_time
            s.center = _toward(s.center, s.target_center, step_f)
            # a notch widens at once (the bank spreads the change over the block): it must cover
            # its mode's grown uncertainty now; it narrows at slew_rate
            s.bandwidth = _toward(s.bandwidth, s.target_bandwidth,
                                  math.inf if s.target_bandwidth > s.bandwidth else step_f)
            if s.depth <= 0:  # not in the signal: take the form at once
                s.spread, s.split = s.target_spread, s.target_split
                s.pair_depth = s.target_pair_depth
            else:  # a pair spreads like a bandwidth, fades in or out over fade_time
                s.spread = _toward(s.spread, s.target_spread,
                                   math.inf if s.target_spread > s.spread else step_f)
                if s.split <= 0.0:  # no pair yet: its sections' depth is free
                    s.pair_depth = s.target_pair_depth
                s.split = _toward(s.split, s.target_split, dt / c.fade_time)
                s.pair_depth = _toward(s.pair_depth, s.target_pair_depth,
                                       max(depth_rate, 1e-9) * dt)
            s.depth = _toward(s.depth, s.target_depth, max(depth_rate, 1e-9) * dt)
            if s.depth <= 0:
                s.shape_depth = want_shape
            else:
                s.shape_depth = _toward(s.shape_depth, want_shape,
                                        max(c.depth, 1.0) / c.fade_time * dt)
            if not fallback:
                s.center = min(max(s.center, lo), hi)
            changed = changed or before != (s.center, s.bandwidth, s.depth, s.shape_depth,
                                            s.spread, s.split, s.pair_depth)
        if changed or self._params is None:
            self._params = self.params()
        return self._params

    @property
    def n_sections(self) -> int:
        """Sections of the bank: two per adaptive notch (a pair), one for the fallback."""
        return 2 * self.config.max_notches + 1

    def sections(self, s: Slot) -> list[tuple[float, float, float, float]]:
        """A slot's sections ``(centre, bandwidth, depth, shape depth)``: a single notch is
        the first (the second bypassed, depth 0); a pair is two sections of ``pair_depth`` at
        ``center -+ spread``; ``split`` fades from one form to the other, the sections moving
        apart as the second deepens (at ``center -+ split spread``: the notch never leaves
        its centre uncovered); the fallback slot has one section."""
        if s is self.slots[-1]:
            return [(s.center, s.bandwidth, s.depth, s.shape_depth)]
        d = self.config.depth
        on = s.depth / d if d > 0 else 0.0
        a_depth = on * ((1.0 - s.split) * d + s.split * s.pair_depth)
        a_shape = (1.0 - s.split) * s.shape_depth + s.split * s.pair_depth
        b_shape = s.pair_depth if s.pair_depth > 0 else a_shape
        off = s.split * s.spread
        return [(s.center - off, s.bandwidth, a_depth, a_shape),
                (s.center + off, s.bandwidth, on * s.split * s.pair_depth, b_shape)]

    def params(self) -> S.SectionParams:
        """Current section parameters (two per adaptive slot, then the fallback)."""
        rows = np.array([r for s in self.slots for r in self.sections(s)], dtype=float)
        return S.SectionParams(rows[:, 0], rows[:, 1], rows[:, 2], np.maximum(rows[:, 3], 3.5))

    def _active(self) -> list[Slot]:
        return [s for s in self.slots if s.depth > 0 or s.state in (TRACKING, HOLDING,
                                                                     PREDICTED)]

    def _notches(self) -> list[tuple[Slot, tuple[float, float, float, float]]]:
        """The active slots' sections in the signal (a pair's second once it fades in)."""
        return [(s, r) for s in self._active() for i, r in enumerate(self.sections(s))
                if i == 0 or r[2] > S.DEPTH_OFF_DB]

    def status(self) -> PolicyStatus:
        """Active notches (sections) in cascade order, bank state, estimate age (cheap: every
        block); a pair is two notches following the same mode."""
        notches = [NotchStatus(s.mode_id, s.state, r[0], r[1], r[2], s.limit, max(r[3], 3.5))
                   for s, r in self._notches()]
        return PolicyStatus(notches, self.fallback_active, self.age(), self.budget_limited,
                            self.lag_deg, self.bank_state, self.reason)

    def peak_reductions(self) -> tuple[np.ndarray, np.ndarray]:
        """Per active notch (status order): the peak reduction [dB] the whole bank as it is now
        gives the notch's mode, guaranteed over the mode's box at the current estimate age, and
        nominal (the estimate itself); NaN for notches without a mode (fallback)."""
        act = [s for s, _ in self._notches()]
        guaranteed = np.full(len(act), np.nan)
        nominal = np.full(len(act), np.nan)
        k = [i for i, s in enumerate(act) if s.mode_id > 0 and math.isfinite(s.f)
             and math.isfinite(s.zeta_hi)]
        if not k:
            return guaranteed, nominal
        p = self.params()
        on = p.depth_db > S.DEPTH_OFF_DB
        zp, zz = S.pole_zero_damping(p.center[on], p.bandwidth[on], p.depth_db[on], self.fs,
                                     p.shape_depth_db[on])
        c = p.center[on]
        sl = [act[i] for i in k]
        f = np.array([s.f for s in sl])
        h = np.array([self.half_width(s, self._slot_age(s, self.now))
                      if math.isfinite(s.f_std) else 0.0 for s in sl])
        zeta = np.array([s.zeta_hi for s in sl])
        z0 = np.array([s.zeta if math.isfinite(s.zeta) else s.zeta_hi for s in sl])
        zc = np.array([self._zeta_c(s) for s in sl])
        fb, zb = R.box_modes(f - h, f + h, zeta, zc)  # the region's sample modes, the estimate
        fm = np.concatenate([fb, f[:, None]], axis=1)
        zm = np.concatenate([zb, z0[:, None]], axis=1)
        span = min(float(np.sum(p.depth_db[on])) + 6.0, 80.0)  # no more reduction possible
        pr = R.peak_reduction_db(fm, zm, c, zp, zz, self.fs, span)
        guaranteed[k], nominal[k] = pr[:, :-1].min(axis=1), pr[:, -1]
        return guaranteed, nominal

    def phase_lag(self) -> float:
        """Phase lag [deg] of the whole bank as it is now (fallback included) at the crossover."""
        p = self.params()
        on = p.depth_db > S.DEPTH_OFF_DB
        if not on.any():
            return 0.0
        zp, zz = S.pole_zero_damping(p.center[on], p.bandwidth[on], p.depth_db[on], self.fs,
                                     p.shape_depth_db[on])
        return float(np.sum(S.damping_lag_deg(self.config.crossover_frequency, p.center[on],
                                              zp, zz, self.fs)))


def damping_for_peak(peak_db: float) -> float:
    """Damping ratio whose resonance peak stands ``peak_db`` above the mode's static gain
    (``1 / (2 zeta sqrt(1 - zeta^2))``); 1/sqrt(2) for 0 dB."""
    g = 10.0 ** (-max(peak_db, 0.0) / 20.0)  # = 2 zeta sqrt(1 - zeta^2)
    return math.sqrt(max(0.5 * (1.0 - math.sqrt(max(1.0 - g * g, 0.0))), 0.0))


def _toward(x: float, target: float, step: float) -> float:
    if target > x:
        return min(x + step, target)
    return max(x - step, target)


def with_changes(config: PolicyConfig, **changes: float) -> PolicyConfig:
    """A copy of ``config`` with some fields changed."""
    return replace(config, **changes)
