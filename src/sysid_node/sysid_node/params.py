"""The sysid_node parameter table (pure, no rclpy).

One :class:`ParamSpec` per parameter: name, type, default, description, range or choices and
its kind. ``live`` parameters are applied without losing the estimate, ``structural`` ones reset
the estimator (the caller logs a line), ``read_only`` ones can only be set at start-up.
:func:`validate` checks a single value, :func:`validate_set` a whole set of values (cross
checks such as ``freq_min < freq_max``); both return a reason string, empty when valid.

Defaults serve a sensor nobody has configured for: the sample rate is measured from the stamps
(``sample_rate: 0``), the band is found from the data (``freq_max: 0``, ``core/band.py``), and
memory may be given as a time constant in seconds that is independent of the sample rate
(``memory_time_constant``).
"""

from __future__ import annotations

import math
from typing import Any

from sysid_node import node_params as NP
from sysid_node.decimation import auto_factor
from sysid_node.node_params import ParamSpec, check, check_imu_axes, parse_list
from sysid_node.topics import topic_name_error

RATE_POLICIES = ("resample", "reject")
#: Default upper band edge as a fraction of the sample rate (0.4 fs = 80 % of Nyquist).
NYQUIST_SAFE_FRACTION = 0.4
#: Smallest explicit forgetting factor (a memory of 10 samples).
MIN_FORGETTING_FACTOR = 0.9
#: Automatic block rows aim at this many rows of the stacked window 2 i (m + l).
AUTO_WINDOW_ROWS = 140
#: ... and reach up to this many to span half a period of the lowest mode (the automatic band's
#: lowest peak; the RLS costs the square of the rows per sample, a realization their cube).
MAX_AUTO_WINDOW_ROWS = 280
#: A configured band's window grown for its lowest lightly damped mode keeps at most this many
#: output rows l i in its future block: the eigendecomposition of that block's projection
#: (cube of l i) is the largest cost of a realization, and 70 is the automatic window's l i
#: for five outputs (14 block rows), so no grown window costs more than that one.
MAX_GROWN_FUTURE_ROWS = 70
#: Lowest mode assumed while the automatic band is being chosen [Hz]: a window of 0.35 s, the
#: seed example's 35 block rows at 100 Hz (Sec. II; its lowest mode is at 2 Hz).
INITIAL_LOW_HZ = 1.0 / 0.7


_p = ParamSpec  # _p(name, type, default, description, kind, lo=, hi=, choices=, unit=)

PARAMS: tuple[ParamSpec, ...] = (
    # -- sampling and channel layout (structural) --
    _p("sample_rate", float, 0.0,
       "Sample rate of the estimator [Hz]; 0 = measure it from the header stamps",
       "structural", lo=0.0, hi=100000.0, unit="Hz"),
    _p("rate_mismatch", str, "resample",
       "What to do with a stream whose measured rate differs from sample_rate: "
       "'resample' (linear interpolation onto the sample grid) or 'reject' (drop it)",
       "structural", choices=RATE_POLICIES),
    _p("output_only", bool, False,
       "true = ignore the excitation topic (stochastic, output-only identification); false = use "
       "the excitation when it is published (output-only while it is absent)", "structural"),
    _p("output_channels", int, 0,
       "Expected number of output channels; 0 = take it from the first message", "structural",
       lo=0, hi=64),
    _p("input_channels", int, 0,
       "Expected number of input channels; 0 = take it from the first message", "structural",
       lo=0, hi=16),
    _p("gap_fill_max_samples", int, 2,
       "Holes of at most this many missing samples are repaired by linear interpolation; longer "
       "gaps split the data and restart the Hankel window", "structural", lo=0, hi=100),
    _p("reorder_window", float, 0.02,
       "Data held back to put out-of-order samples in stamp order [s] (adds this latency)",
       "structural", lo=0.0, hi=5.0, unit="s"),
    _p("decimation", int, 0,
       "Identify at sample_rate / decimation after an anti-alias low-pass (inputs and outputs "
       "alike); 0 = auto: the largest factor keeping the identification rate >= 10 x freq_max "
       "(with freq_max 0: x the automatic band's edge); 1 = off", "structural", lo=0, hi=100),
    # -- estimator (structural) --
    _p("block_rows", int, 0,
       "Hankel block rows i of the recursive DSRA (A1) [-]; 0 = auto: about "
       f"{AUTO_WINDOW_ROWS} rows in the stacked window 2 i (m + l) (35 for 1 input + 1 output, "
       "10 for 1 + 6), enough for the model order, and with the automatic band (freq_max 0) "
       "enough to span half a period of its lowest peak (a full one output-only from one "
       "output; 0.35 s, there 0.7 s, until the band is chosen), "
       "with a configured band a full period of its lowest lightly damped (<= 5 %) confirmed "
       f"mode (checked every 2 s; it only grows; at most {MAX_GROWN_FUTURE_ROWS} / l block "
       f"rows); up to {MAX_AUTO_WINDOW_ROWS} rows",
       "structural", lo=0, hi=200),
    _p("max_order", int, 0,
       "Model order of the realization; 0 = auto: 2 x max_modes, and with a configured band "
       "(freq_max > 0) grown to 2 x the larger of max_modes and twice the confirmed mode "
       "tracks (counted every 2 s; it only grows) [-]",
       "structural", lo=0, hi=400),
    # -- estimator (live) --
    _p("forgetting_factor", float, 0.0,
       "RLS forgetting factor lambda [-]: 0.9 .. 1 sets it directly (memory 1/(1 - lambda) "
       "samples whatever the rate); 0 = from memory_time_constant", lo=0.0, hi=1.0),
    _p("memory_time_constant", float, 1.0,
       "Memory of the estimator as a time constant tau [s] (lambda = exp(-1/(tau fs)) at the "
       "identification rate, so the memory does not change with the sample rate); used when "
       "forgetting_factor is 0", lo=0.01, hi=3600.0, unit="s"),
    _p("memory_periods", float, 10.0,
       "With the automatic band (freq_max 0), the memory is at least this many periods of its "
       "lowest peak (a memory of a few periods cannot resolve a lightly damped low mode in "
       "noise, nor tell it from a neighbour 10 % away); 0 = memory_time_constant alone",
       lo=0.0, hi=1000.0),
    _p("max_modes", int, 10,
       "Largest number of modes reported as tracked (the strongest first) [-]; the model "
       "order defaults to twice this", lo=1, hi=50),
    _p("freq_min", float, 0.0,
       "Lower edge of the frequency band of reported modes [Hz]; with the automatic band "
       "(freq_max 0) the band is chosen from the structure above it, and a change chooses "
       "it again (estimator reset)", lo=0.0, hi=50000.0, unit="Hz"),
    _p("freq_max", float, 0.0,
       "Upper edge of the band [Hz]; 0 = automatic: after the first 4 s of data (0.4 x "
       "sample rate until then) the band reaches half an octave above the highest peak where "
       "the Welch spectrum of an output (or input) stands above its noise floor (at most "
       f"{NYQUIST_SAFE_FRACTION:g} x sample rate; core/band.py) and the data are decimated "
       "to match (decimation 0); rechecked every 2 s of data, it then only widens (structure "
       "twice in a row above 0.85 of it) and its lowest peak only moves down; a band change "
       "rebuilds the estimator from the last "
       "10 s of raw data, the tracks are kept", lo=0.0, hi=50000.0, unit="Hz"),
    _p("damping_min", float, 0.0, "Smallest damping ratio of a reported mode [-]",
       lo=0.0, hi=1.0),
    _p("damping_max", float, 0.5, "Largest damping ratio of a reported mode [-]",
       lo=0.0, hi=1.0),
    _p("realization_rate", float, 20.0,
       "Rate of the SVD-based realization of the model from the RLS factor [Hz of data time]",
       lo=0.1, hi=10000.0, unit="Hz"),
    _p("realization_budget", float, 0.5,
       "Share of one CPU core the live node's realizations (and the tracking after each) may "
       "use on average (CPU time, a stall capped at 3 x the recent median); a publication "
       "period that finds it used up is absorbed without realizing (counted as "
       "realizations_deferred), so a slow or busy machine gets current estimates at a lower "
       "realization rate [-]; 0 = no limit (the offline tool never limits)", lo=0.0, hi=1.0),
    _p("publish_rate", float, 10.0, "Rate of /modal_estimate [Hz of data time]",
       lo=0.1, hi=10000.0, unit="Hz"),
    _p("diagnostics_rate", float, 1.0, "Rate of /diagnostics [Hz, wall clock]",
       lo=0.1, hi=100.0, unit="Hz"),
    _p("backlog_warning", float, 0.5,
       "Backlog (data received but not yet identified) above which the node warns once and "
       "/diagnostics says WARN [s] (the estimates keep their health: their stamps tell how "
       "late they are); 0 = never", lo=0.0, hi=600.0, unit="s"),
    _p("max_backlog", float, 5.0,
       "Backlog above which the oldest waiting data are dropped (counted as *_shed, said in a "
       "warning) so the estimate stays current [s]; 0 = never drop", lo=0.0, hi=600.0,
       unit="s"),
    _p("catch_up", bool, True,
       "When the estimator falls behind, absorb the older waiting data without realizations so "
       "that only current estimates are made (the skipped ones are counted as "
       "estimates_skipped); false = make every estimate however late (as offline does)"),
    _p("residual_spectrum_rate", float, 0.2,
       "Rate of /residual_spectrum [Hz of data time]; 0 = off", lo=0.0, hi=10.0, unit="Hz"),
    # -- mode tracking gates (live) --
    _p("tracking_frequency_tolerance", float, 0.05,
       "Relative frequency gate for matching a mode to a tracked one [-]", lo=0.001, hi=0.5),
    _p("tracking_confirm_count", int, 6,
       "Successive matches before a tentative mode becomes tracked [-] (successive "
       "realizations share most of their data, so a noise mode recurs for a good part of "
       "the memory: 6 estimates at publish_rate 10 Hz = 0.6 memory_time_constant)",
       lo=1, hi=100),
    _p("tracking_lost_timeout", float, 2.0,
       "Time without a match before a tracked mode is marked lost [s] (with an input: time "
       "while the input excites its frequency; a sweep that moved on holds it)", lo=0.0,
       hi=600.0, unit="s"),
    _p("tracking_drop_timeout", float, 30.0,
       "Time without a match after which a lost mode leaves the estimate [s] (counted as "
       "tracking_lost_timeout)", lo=0.0, hi=3600.0, unit="s"),
    _p("tracking_median_count", int, 5,
       "A tracked mode's frequency and damping are the medians of its last N raw estimates "
       "(a burst in the data throws a realization or two off; 5 realizations at "
       "realization_rate 20 Hz lag a drift by 0.1 s) [-]; 1 = the latest estimate", lo=1,
       hi=20),
    _p("spurious_rejection", bool, True,
       "Track only modes that pass the spurious-mode tests of each realization (stable across "
       "model orders, above the noise peak and overfit levels, determined frequency; "
       "core/spurious.py); false = every mode in the band is a candidate"),
    # -- topics and QoS (structural: the node subscribes again) --
    _p("output_topic", str, "vibration",
       "Topic of the measured responses (outputs); relative names follow the node's namespace",
       "structural"),
    NP.signal_type_spec("output_type", "output_topic", "structural"),
    _p("input_topic", str, "excitation",
       "Topic of the measured excitation (inputs); empty = output-only; relative names follow "
       "the node's namespace", "structural"),
    NP.signal_type_spec("input_type", "input_topic", "structural"),
    NP.imu_axes_spec("structural"),
    _p("qos", str, "sensor_data",
       "QoS of the subscriptions: 'sensor_data' (best effort) or 'reliable'", "structural",
       choices=NP.QOS_CHOICES),
    _p("qos_depth", int, 1000, "History depth of the subscriptions [messages]", "structural",
       lo=1, hi=100000),
    # -- online LPV model (2) (read-only: set at start-up) --
    _p("scheduling_topic", str, "",
       "Topic of the scheduling signal (sysid_msgs/SignalSample, e.g. rotor_speed; QoS as the "
       "data topics: qos); each estimate carries its value at the estimate's stamp and, with "
       "lpv_model, the modes the LPV model predicts there; empty = off; relative names follow "
       "the node's namespace", "read_only"),
    _p("lpv_model", str, "",
       "LPV model file (.npz written by the envelope tool or LpvModel.save) whose predicted "
       "modes are published next to the identified ones; needs scheduling_topic; empty = off",
       "read_only"),
    _p("scheduling_timeout", float, 1.0,
       "A scheduling sample older than this at an estimate's stamp gives no value and no "
       "prediction [s]", "read_only", lo=0.001, hi=3600.0, unit="s"),
)

SPECS: dict[str, ParamSpec] = {s.name: s for s in PARAMS}


def defaults() -> dict[str, Any]:
    """Name -> default value of every parameter."""
    return {s.name: s.default for s in PARAMS}


def validate(name: str, value: Any) -> str:
    """Check one value against its spec; return '' if valid, else the reason."""
    return check(SPECS, name, value) or _check_sysid(name, value)


def _check_sysid(name: str, value: Any) -> str:
    """This node's own checks of a value of the right type ('' if valid)."""
    if name == "imu_axes":
        return check_imu_axes(value)
    if name == "forgetting_factor" and 0.0 < value < MIN_FORGETTING_FACTOR:
        return (f"forgetting_factor={value:g} is too small: use 0 (memory_time_constant) or "
                f"{MIN_FORGETTING_FACTOR:g} .. 1")
    if name == "block_rows" and value == 1:
        return "block_rows=1 is too small: use 0 (auto) or at least 2"
    if name == "lpv_model" and value:
        from sysid_node.scheduling import model_error

        return model_error(value)
    if name == "output_topic" or (name in ("input_topic", "scheduling_topic") and value):
        reason = topic_name_error(value)
        if reason:
            return f"{name}: {reason}"
    return ""


def validate_set(values: dict[str, Any], sample_rate: float = math.nan) -> str:
    """Check a complete set of parameter values, including cross checks.

    ``sample_rate`` is the effective (configured or measured) rate, NaN while unknown.
    """
    for name, value in values.items():
        reason = validate(name, value)
        if reason:
            return reason
    fmin, fmax = values.get("freq_min", 0.0), values.get("freq_max", 0.0)
    if fmax > 0 and fmin >= fmax:
        return f"freq_min={fmin:g} Hz must be below freq_max={fmax:g} Hz"
    dmin, dmax = values.get("damping_min", 0.0), values.get("damping_max", 0.5)
    if dmin >= dmax:
        return f"damping_min={dmin:g} must be below damping_max={dmax:g}"
    reason = band_error(values, values.get("sample_rate", 0.0) or sample_rate)
    if reason:
        return reason
    if values.get("output_topic") and values.get("output_topic") == values.get("input_topic"):
        return "input_topic and output_topic must differ"
    sched = values.get("scheduling_topic", "")
    if sched and sched in (values.get("output_topic"), values.get("input_topic")):
        return "scheduling_topic must differ from output_topic and input_topic"
    if values.get("lpv_model") and not sched:
        return "lpv_model needs scheduling_topic (the signal the model is scheduled on)"
    return ""


def band_error(values: dict[str, Any], fs: float) -> str:
    """Why ``freq_min``/``freq_max`` cannot be identified at sample rate ``fs`` [Hz] (above the
    Nyquist frequency, or above the safe fraction of the identification rate when decimating);
    empty when they can or ``fs`` is unknown (NaN)."""
    if not (math.isfinite(fs) and fs > 0):
        return ""
    fmin, fmax = values.get("freq_min", 0.0), values.get("freq_max", 0.0)
    k = int(values.get("decimation", 0))
    if k > 1 and fmax > NYQUIST_SAFE_FRACTION * fs / k:
        return (f"freq_max={fmax:g} Hz is above {NYQUIST_SAFE_FRACTION:g} x the "
                f"identification rate {fs / k:g} Hz (decimation {k})")
    if fmax > fs / 2:
        return f"freq_max={fmax:g} Hz is above the Nyquist frequency {fs / 2:g} Hz"
    if fmin >= fs / 2:
        return f"freq_min={fmin:g} Hz is not below the Nyquist frequency {fs / 2:g} Hz"
    if fmax <= 0 and fmin >= NYQUIST_SAFE_FRACTION * fs:
        return (f"freq_min={fmin:g} Hz is not below the automatic band's top "
                f"{NYQUIST_SAFE_FRACTION:g} x {fs:g} Hz")
    return ""


parse_axes = parse_list  # 'ax, az' -> ['ax', 'az']


def structural_changes(old: dict[str, Any], new: dict[str, Any]) -> list[str]:
    """Names of structural or read-only parameters whose value differs between two sets."""
    return [
        n for n, v in new.items()
        if n in SPECS and SPECS[n].kind != "live" and old.get(n) != v
    ]


def effective_lambda(values: dict[str, Any], fs: float, low_hz: float = math.nan) -> float:
    """lambda: ``forgetting_factor`` when set (> 0), else from ``memory_time_constant`` tau at
    the identification rate ``fs``: exp(-1/(tau fs)), a memory of about tau fs samples = tau
    seconds at any rate. (Before the rate is known: the 100-sample memory of lambda 0.99.)"""
    lam = float(values.get("forgetting_factor", 0.0))
    if lam > 0:
        return lam
    tau = float(values.get("memory_time_constant", 1.0))
    periods = float(values.get("memory_periods", 0.0))
    if periods > 0 and math.isfinite(low_hz) and low_hz > 0:
        tau = max(tau, periods / low_hz)  # the lowest mode's periods (automatic band)
    if tau > 0 and math.isfinite(fs) and fs > 0:
        return math.exp(-1.0 / (tau * fs))
    return 0.99


def effective_block_rows(values: dict[str, Any], n_outputs: int, n_inputs: int,
                         fs: float = math.nan, low_hz: float = math.nan) -> int:
    """``block_rows`` when > 0; else i with 2 i (m + l) close to AUTO_WINDOW_ROWS (the cost of
    a realization grows with the cube of that size), at most 35 (the seed example's value), at
    least enough block rows for the model order (l (i - 1) >= order + 2), and, when the lowest
    mode ``low_hz`` [Hz] is known (the automatic band's lowest peak, ``core/band.py``), enough
    for the Hankel window to span ``window_periods`` of its period at the identification rate
    ``fs`` [Hz] (half a period, a full one output-only from one output; up to
    MAX_AUTO_WINDOW_ROWS rows)."""
    i = int(values.get("block_rows", 0))
    if i > 0:
        return i
    order = int(values.get("max_order", 0)) or 2 * int(values.get("max_modes", 10))
    need = -(-(order + 2) // max(n_outputs, 1)) + 1
    width = 2 * (n_inputs + n_outputs)
    i = max(need, 2, min(35, round(AUTO_WINDOW_ROWS / width)))
    if math.isfinite(low_hz) and low_hz > 0 and math.isfinite(fs) and fs > 0:
        i = max(i, min(_period_rows(fs, low_hz, n_outputs, n_inputs),
                       max_auto_rows(n_outputs, n_inputs)))
    return int(min(i, SPECS["block_rows"].hi))


#: Modes of the automatic model order per clear structure peak of an estimator's band: a band
#: of many closely spaced modes (a frame's first bending and torsion modes) with an order of
#: 2 max_modes leaves its weakest ones out of the realization for seconds.
ORDER_PER_PEAK = 2


def effective_max_order(values: dict[str, Any], n_peaks: int, top: int) -> int:
    """``max_order`` when > 0; else 2 x the larger of ``max_modes`` and ORDER_PER_PEAK x
    ``n_peaks`` (the modes of the estimator's band: the automatic band's low group counts its
    clear structure peaks, ``core/band.py``, a configured band its confirmed mode tracks; 0
    while unknown); at most ``top`` (the largest order the block rows allow)."""
    k = int(values.get("max_order", 0))
    if k > 0:
        return min(k, top)
    return min(2 * max(int(values.get("max_modes", 10)), ORDER_PER_PEAK * int(n_peaks)), top)


def period_block_rows(values: dict[str, Any], n_outputs: int, n_inputs: int, fs: float,
                      mode_hz: float) -> int:
    """A configured band's block rows: ``effective_block_rows``, grown for the Hankel window to
    span a full period of ``mode_hz`` [Hz] (its lowest lightly damped confirmed mode; NaN: not
    grown) at the identification rate ``fs`` [Hz], up to MAX_AUTO_WINDOW_ROWS stacked rows and
    MAX_GROWN_FUTURE_ROWS output rows l i."""
    base = effective_block_rows(values, n_outputs, n_inputs)
    if int(values.get("block_rows", 0)) > 0 or not (math.isfinite(mode_hz) and mode_hz > 0):
        return base
    # the automatic rule spans window_periods of a period: of the mode over that share
    span = window_periods(n_outputs, n_inputs)
    want = effective_block_rows(values, n_outputs, n_inputs, fs, span * mode_hz)
    return max(base, min(want, MAX_GROWN_FUTURE_ROWS // max(n_outputs, 1)))


def max_auto_rows(n_outputs: int, n_inputs: int) -> int:
    """The most automatic block rows: MAX_AUTO_WINDOW_ROWS in the stacked window 2 i (m + l)."""
    return MAX_AUTO_WINDOW_ROWS // (2 * (n_inputs + n_outputs))


def _half_period_rows(fs: float, low_hz: float) -> int:
    """Block rows for the Hankel window to span half a period of ``low_hz`` at ``fs``."""
    return math.ceil(fs / (2.0 * low_hz) - 1e-9)


def window_periods(n_outputs: int, n_inputs: int) -> float:
    """Share of the lowest mode's period the automatic Hankel window spans: half, and at least
    enough for the m + l rows of a block row to hold one period's samples, i (m + l) >= fs /
    low_hz: a full period output-only from one output. There the window's lags are the only
    thing that tells neighbouring low modes apart (no shapes over outputs, no input to
    project on): with half a period, the random suite's one-output records lost a 5.8 Hz
    mode next to a 4.1 Hz one, or a 2.1 Hz mode next to a 3.8 Hz one, for 10-20 s."""
    return max(0.5, 1.0 / max(n_outputs + n_inputs, 1))


def _period_rows(fs: float, low_hz: float, n_outputs: int, n_inputs: int) -> int:
    """Block rows for the Hankel window to span ``window_periods`` of a period of ``low_hz``
    at ``fs``."""
    return math.ceil(window_periods(n_outputs, n_inputs) * fs / low_hz - 1e-9)


def window_capped(values: dict[str, Any], n_outputs: int, n_inputs: int, fs: float,
                  low_hz: float) -> bool:
    """The automatic Hankel window cannot span half a period of ``low_hz`` [Hz] at ``fs`` [Hz]
    within MAX_AUTO_WINDOW_ROWS (``effective_block_rows``; False with configured block rows).
    Half a period is what it needs: a window capped short of ``window_periods`` (a full
    period from one output) but spanning half of it does not split the band."""
    if int(values.get("block_rows", 0)) > 0 or not (math.isfinite(low_hz) and low_hz > 0):
        return False
    return _half_period_rows(fs, low_hz) > max_auto_rows(n_outputs, n_inputs)


def decimation_factor(values: dict[str, Any], fs: float, auto_edge: float = math.nan) -> int:
    """Decimation factor to the identification rate: ``decimation`` when > 0, else automatic
    (:func:`sysid_node.decimation.auto_factor`) for ``freq_max``, or with ``freq_max: 0`` for
    the automatic band's edge ``auto_edge`` [Hz] (NaN while it is being chosen: no decimation)."""
    k = int(values.get("decimation", 0))
    if k > 0:
        return k
    fmax = float(values.get("freq_max", 0.0))
    return auto_factor(fs, fmax if fmax > 0 else auto_edge)


def effective_band(values: dict[str, Any], fs: float,
                   auto_edge: float = math.nan) -> tuple[float, float]:
    """(fmin, fmax) [Hz] with ``freq_max = 0`` resolved to the automatic band's edge
    ``auto_edge`` [Hz] (``core/band.py``; NaN while unknown), never above the safe fraction of
    ``fs`` (pass the identification rate)."""
    fmax = float(values.get("freq_max", 0.0))
    if fmax <= 0:
        fmax = NYQUIST_SAFE_FRACTION * fs if math.isfinite(fs) and fs > 0 else math.inf
        if math.isfinite(auto_edge) and auto_edge > 0:
            fmax = min(fmax, auto_edge)
    return float(values.get("freq_min", 0.0)), fmax
