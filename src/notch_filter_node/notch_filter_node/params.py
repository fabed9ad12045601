"""The notch_filter_node parameter table (pure, no rclpy).

One :class:`ParamSpec` per parameter: type, default, description, range or choices, kind.
``live`` parameters retune the running bank (changes move at the policy's rates),
``structural`` ones rebuild the bank (filter memory restarts), ``read_only`` ones are set at
start-up (topics: remap them or pass them with --ros-args -p). :func:`validate` checks one value,
:func:`validate_set` a whole set (with the policy's cross checks); both return '' or a reason.
"""

from __future__ import annotations

import math
from dataclasses import fields
from typing import Any

from sysid_node.node_params import ParamSpec, check, check_imu_axes, parse_list
from sysid_node.topics import topic_name_error

from notch_filter_node.policy import BUDGET_PRIORITIES, PolicyConfig, check_config
from sysid_node import node_params as NP

MAX_CHANNELS = 64


_p = ParamSpec  # _p(name, type, default, description, kind, lo=, hi=, choices=, unit=)


_D = PolicyConfig()
PARAMS: tuple[ParamSpec, ...] = (
    # -- topics and QoS (read-only) --
    _p("signal_topic", str, "vibration", "Topic of the signal to filter", "read_only"),
    NP.signal_type_spec("signal_type", "signal_topic", "read_only"),
    NP.imu_axes_spec("read_only", "; the other fields are passed through"),
    _p("output_topic", str, "vibration_filtered",
       "Topic of the filtered signal (same type and header stamp as the input)", "read_only"),
    _p("estimate_topic", str, "modal_estimate", "Topic of sysid_msgs/ModalEstimate",
       "read_only"),
    _p("bank_topic", str, "notch_bank", "Topic of sysid_msgs/NotchBank", "read_only"),
    _p("qos_depth", int, 1000, "History depth of the signal subscription and publisher: "
       "it must hold the samples that arrive while the process is not scheduled (a busy "
       "or virtualised flight computer stalls a process for up to ~1 s; a sample lost "
       "is a gap in the filtered signal) [messages]", "read_only", lo=1, hi=100000),
    _p("output_qos", str, "reliable",
       "QoS of the filtered output: 'reliable' (matches reliable and best-effort subscribers) or "
       "'sensor_data' (best effort)", "read_only", choices=NP.QOS_CHOICES),
    _p("max_notches", int, _D.max_notches,
       "Number of adaptive notches (each one section, or two for a pair: notch_pairs; the "
       "fallback notch has its own) [-]", "read_only",
       lo=1, hi=20),
    # -- sampling (structural: rebuilds the bank) --
    _p("sample_rate", float, 0.0,
       "Sample rate of the signal [Hz]; 0 = from SignalBlock.sample_period or measured from the "
       "stamps of the first samples (passed through unfiltered until then)", "structural",
       lo=0.0, hi=100000.0, unit="Hz"),
    _p("substep", int, 8,
       "Sub-block length over which the coefficients are held while a notch moves [samples]",
       "structural", lo=1, hi=256),
    _p("rate_tolerance", float, 0.02,
       "Relative difference between the rate the stamps measure and the bank's rate beyond "
       "which the bank is re-designed at the measured rate [-]", lo=0.001, hi=1.0),
    _p("layout_confirm", int, 5,
       "Messages in a row a new channel layout (names or count) must come in before the bank "
       "adopts it; until then its known channels are filtered, new ones pass through [-]",
       lo=1, hi=10000),
    # -- retuning policy (live) --
    _p("slew_rate", float, _D.slew_rate,
       "Largest rate of change of a notch centre, and of its bandwidth (a pair's spread) as it "
       "narrows; a notch widens at once, spread over one block [Hz/s]", lo=0.001, hi=1000.0,
       unit="Hz/s"),
    _p("hysteresis", float, _D.hysteresis,
       "A notch centre moves only when the estimate differs from its target by more than "
       "max(hysteresis, hysteresis_sigma * frequency_std) [Hz]", lo=0.0, hi=100.0, unit="Hz"),
    _p("hysteresis_sigma", float, _D.hysteresis_sigma,
       "Hysteresis in units of the estimate's frequency std [-]", lo=0.0, hi=10.0),
    _p("freq_min", float, _D.freq_min,
       "Lowest centre frequency; modes below get no notch (keeps rigid-body modes) [Hz]",
       lo=0.0, hi=50000.0, unit="Hz"),
    _p("freq_max", float, _D.freq_max, "Highest centre frequency [Hz]; 0 = 0.4 x sample rate",
       lo=0.0, hi=50000.0, unit="Hz"),
    _p("depth", float, _D.depth, "Depth of the adaptive notches at their centre [dB]",
       lo=3.5, hi=80.0, unit="dB"),
    _p("peak_reduction", float, _D.peak_reduction,
       "Required reduction of each notched mode's resonance peak by the bank, over the mode's "
       "uncertainty (gain stabilization); sets each notch's width (must be below depth) [dB]",
       lo=0.5, hi=79.0, unit="dB"),
    _p("sigma_k", float, _D.sigma_k,
       "Half-width of the mode's frequency interval in frequency stds; with damping_sigma_k "
       "it sets the confidence of the peak_reduction guarantee: the region covers the true "
       "mode with probability 96.5 % for 3 and 2 (Gaussian, calibrated stds; "
       "resonance.region_confidence) [-]", lo=0.0, hi=10.0),
    _p("notch_pairs", bool, _D.notch_pairs,
       "Where a staggered pair of shallower sections (a flat-bottomed stop band) meets "
       "peak_reduction over the mode's uncertainty with less phase lag at crossover_frequency "
       "than one notch, use the pair (the two sections follow the same mode) [-]"),
    _p("damping_sigma_k", float, _D.damping_sigma_k,
       "The width is designed for a damping up to zeta + damping_sigma_k * zeta_std (an "
       "ellipse with the frequency interval; confidence: see sigma_k) [-]",
       lo=0.0, hi=10.0),
    _p("drift_window", float, _D.drift_window,
       "Span of recent estimates the drift rate of a mode is fitted over, at least 4 memory "
       "time constants of the identifier (its estimates are correlated over one) [s]", lo=0.1,
       hi=600.0, unit="s"),
    _p("drift_rate_min", float, _D.drift_rate_min,
       "Drift rate a mode is assumed capable of at least, as a fraction of its frequency per "
       "second, while its estimate ages [1/s]", lo=0.0, hi=10.0, unit="1/s"),
    _p("design_horizon", float, _D.design_horizon,
       "A width is designed for the estimate age 1.5 x now + design_horizon, re-designed when "
       "the age outgrows it [s]", lo=0.0, hi=60.0, unit="s"),
    _p("damping_max", float, _D.damping_max,
       "Modes with a larger damping ratio get no notch (well damped or spurious) [-]",
       lo=0.0, hi=1.0),
    _p("min_relative_amplitude", float, _D.min_relative_amplitude,
       "Modes whose amplitude is below this fraction of the largest notchable mode's get no "
       "notch (they hardly reach the feedback signal; often noise modes) [-]; 0 = all",
       lo=0.0, hi=1.0),
    _p("bandwidth_min", float, _D.bandwidth_min, "Narrowest adaptive notch (-3 dB) [Hz]",
       lo=0.001, hi=10000.0, unit="Hz"),
    _p("bandwidth_max", float, _D.bandwidth_max,
       "Widest adaptive notch (-3 dB); 0 = its centre frequency (the width a mode needs "
       "scales with its frequency); also used when the frequency std is unknown [Hz]",
       lo=0.0, hi=10000.0, unit="Hz"),
    _p("phase_lag_budget", float, _D.phase_lag_budget,
       "Largest total phase lag of the adaptive notches at crossover_frequency [deg]",
       lo=0.0, hi=180.0, unit="deg"),
    _p("budget_priority", str, _D.budget_priority,
       "What gives way when the notches' widths exceed phase_lag_budget: 'phase_lag' narrows "
       "them (peak reduction falls short, reported), 'peak_reduction' keeps them (budget "
       "exceeded, reported)", choices=BUDGET_PRIORITIES),
    _p("crossover_frequency", float, _D.crossover_frequency,
       "Crossover frequency of the loop the bank sits in [Hz]", lo=0.001, hi=10000.0, unit="Hz"),
    _p("stale_timeout", float, _D.stale_timeout,
       "Estimate age beyond which the bank holds the notches that were tracking, widening them "
       "by the drift their modes could have made (or falls back if none was tracking) [s]",
       lo=0.01, hi=3600.0, unit="s"),
    _p("fallback_timeout", float, _D.fallback_timeout,
       "Estimate age at which held notches give way to the static fallback notch (at full "
       "depth by then) [s]", lo=0.02, hi=36000.0, unit="s"),
    _p("fallback_ramp", float, _D.fallback_ramp,
       "Time the fallback notch takes to fade in (ends at the timeout) [s]",
       lo=0.001, hi=600.0, unit="s"),
    _p("future_tolerance", float, _D.future_tolerance,
       "Estimates stamped further ahead of the signal's data time are rejected (and counted) "
       "[s]", lo=0.0, hi=3600.0, unit="s"),
    _p("hold_time", float, _D.hold_time,
       "Time a lost mode's notch holds its centre before fading out; longest hold on an "
       "estimator FAULT before the fallback [s]", lo=0.0, hi=3600.0, unit="s"),
    _p("fade_time", float, _D.fade_time,
       "Time a notch takes to fade its depth in or out [s]", lo=0.001, hi=3600.0, unit="s"),
    _p("fallback_center", float, _D.fallback_center, "Centre of the static fallback notch [Hz]",
       lo=0.001, hi=50000.0, unit="Hz"),
    _p("fallback_bandwidth", float, _D.fallback_bandwidth,
       "-3 dB bandwidth of the static fallback notch [Hz]", lo=0.001, hi=10000.0, unit="Hz"),
    _p("fallback_depth", float, _D.fallback_depth,
       "Depth of the static fallback notch [dB]; 0 = no fallback notch", lo=0.0, hi=80.0,
       unit="dB"),
    _p("disabled_channels", str, "",
       "Comma-separated zero-based indices of channels passed through unfiltered ('' = filter "
       "all)"),
    # -- publishing (live) --
    _p("bank_rate", float, 1.0, "Rate at which /notch_bank is repeated when nothing changes "
       "[Hz, wall clock]", lo=0.01, hi=100.0, unit="Hz"),
    _p("bank_max_rate", float, 20.0, "Largest rate of /notch_bank while notches move "
       "[Hz, wall clock]", lo=0.1, hi=1000.0, unit="Hz"),
    _p("diagnostics_rate", float, 1.0, "Rate of /diagnostics [Hz, wall clock]", lo=0.1,
       hi=100.0, unit="Hz"),
)
SPECS: dict[str, ParamSpec] = {s.name: s for s in PARAMS}
POLICY_FIELDS = tuple(f.name for f in fields(PolicyConfig))


def defaults() -> dict[str, Any]:
    """Name -> default value of every parameter."""
    return {s.name: s.default for s in PARAMS}


def disabled_channels(text: str) -> list[int]:
    """'0, 3' -> [0, 3] (validated by :func:`validate`)."""
    return [int(a) for a in parse_list(text)]


def validate(name: str, value: Any) -> str:
    """Check one value against its spec; '' if valid, else the reason."""
    return check(SPECS, name, value) or _check_notch(name, value)


def _check_notch(name: str, value: Any) -> str:
    """This node's own checks of a value of the right type ('' if valid)."""
    if name == "imu_axes":
        return check_imu_axes(value)
    if name == "disabled_channels":
        items = parse_list(value)
        if not all(a.isdigit() and int(a) < MAX_CHANNELS for a in items):
            return (f"disabled_channels='{value}': use comma-separated channel indices "
                    f"0..{MAX_CHANNELS - 1}")
    if name.endswith("_topic"):
        reason = topic_name_error(value)
        if reason:
            return f"{name}: {reason}"
    return ""


#: Other nodes of the suite whose sections a shared parameter file may hold.
SUITE_NODES = ("sysid_node",)


def check_params_file(path: str, node_name: str) -> str:
    """A parameter file as this node reads it ('' or a one-line reason): see
    :func:`sysid_node.node_params.check_params_file`."""
    return NP.check_params_file(path, node_name, SPECS, SUITE_NODES)


def policy_config(values: dict[str, Any]) -> PolicyConfig:
    """The policy configuration held in a set of parameter values."""
    return PolicyConfig(**{k: type(getattr(_D, k))(values[k]) for k in POLICY_FIELDS})


def validate_set(values: dict[str, Any], fs: float = math.nan) -> str:
    """Check a complete set of values, with cross checks; ``fs`` is the sample rate in use (or
    NaN while unknown)."""
    for name, value in values.items():
        reason = validate(name, value)
        if reason:
            return reason
    rate = values.get("sample_rate", 0.0) or fs
    return check_config(policy_config(values), rate)
