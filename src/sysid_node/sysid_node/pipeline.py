"""ingest -> recursive DSRA -> mode tracker -> estimate records (pure, no rclpy).

The node and the offline tool both drive exactly this class, so a live replay and an offline run
over the same bag give the same numbers. Everything is timed by the sample stamps, never by the
wall clock: a record is made each time the data crosses a multiple of ``1/publish_rate`` seconds
(stamps since the epoch), from exactly the samples up to that instant, and the estimator is fed
in pieces cut at those instants only, so how the messages were chunked on the way in does not
change the numbers.

Parameters (see :mod:`sysid_node.params`): live ones are applied to the running estimator;
structural ones rebuild it (reported through ``log``).
"""

from __future__ import annotations

import dataclasses
import math
import time
from collections.abc import Callable
from typing import Any

import numpy as np
from scipy import signal

from sysid_node import params as P
from sysid_node.core.band import PEAK_MIN_BINS, split_frequency, structure_band
from sysid_node.core.recursive import memory_samples
from sysid_node.core.spurious import Persistence
from sysid_node.decimation import Decimator
from sysid_node.diagnostics import HEALTH_FAULT, merge_health
from sysid_node.ingest import Chunk, Ingest
from sysid_node.low_band import LowBand, max_split_hz
from sysid_node.realization_budget import RealizationBudget
from sysid_node.records import (
    STATUS_NAMES,
    EstimateRecord,
    ModeRecord,
    SpectrumRecord,
)
from sysid_node.scheduling import predictor_from
from sysid_node.sensor_checks import SensorChecks
from sysid_node.validation.residuals import residual_spectrum


def _import_core():
    from sysid_node.core.recursive import RecursiveDSRA
    from sysid_node.core.tracking import ModeTracker

    return RecursiveDSRA, ModeTracker


def _get(obj: Any, *names: str, default: Any = math.nan) -> Any:
    for n in names:
        if hasattr(obj, n):
            v = getattr(obj, n)
            return v() if callable(v) else v
    return default


class Pipeline:
    """The node's processing: feed message blocks in, get :class:`EstimateRecord` objects out.

    ``values`` overrides :func:`sysid_node.params.defaults`; ``log`` receives one line per event
    (rate measured, gaps, resets, parameter changes).
    """

    def __init__(
        self, values: dict[str, Any] | None = None, log: Callable[[str], None] | None = None
    ) -> None:
        self.values = P.defaults()
        if values:
            reason = P.validate_set({**self.values, **values})
            if reason:
                raise ValueError(reason)
            self.values.update(values)
        self.log = log or (lambda _msg: None)
        self._core = _import_core()  # fail at start-up, not at the first sample
        self.update_seconds = 0.0  # wall time in decimation, the estimator and the tracker
        self.update_samples = 0  # samples of the incoming stream
        self.last_update_cost = math.nan  # [s per sample] of the latest piece
        self.records_made = 0
        #: channel names per stream, from the signal messages (for ResidualSpectrum.channel_name)
        self.channel_names: dict[str, list[str]] = {"output": [], "input": []}
        #: the live node's wall clock and CPU share for realizations (None: offline, and
        #: unlimited; go_live)
        self._live_clock: Callable[[], float] | None = None
        self.budget: RealizationBudget | None = None
        self._build_ingest()
        #: online LPV (scheduling_topic, lpv_model): None when off
        self.scheduling = predictor_from(self.values)

    # ---- construction ----
    def _build_ingest(self) -> None:
        v = self.values
        self.ingest = Ingest(
            sample_rate=v["sample_rate"],
            use_input=not v["output_only"] and bool(v["input_topic"]),
            output_channels=v["output_channels"],
            input_channels=v["input_channels"],
            gap_fill_max_samples=v["gap_fill_max_samples"],
            reorder_window=v["reorder_window"],
            rate_mismatch=v["rate_mismatch"],
            clock=self._live_clock,
        )
        self.estimator = None
        self.tracker = None
        self.decimator: Decimator | None = None
        self._layout: tuple[int, int] | None = None
        self._pending: list[Chunk] = []
        self._last_bucket: int | None = None
        self.spectra: list[SpectrumRecord] = []
        self._next_spectrum_ns: int | None = None
        self._recent = _Recent(0)
        self._excited: tuple = (None, None)
        self._samples = 0
        self._sensors: SensorChecks | None = None
        self._band_key: tuple | None = None
        self._band_reason = ""
        #: automatic band (freq_max 0): its upper edge [Hz] (NaN until chosen) and the recent
        #: raw data for the checks and rebuilds
        self.band_edge = math.nan
        #: looks for a split done while the automatic band is being chosen (_early_split)
        self._early_looks = 0
        #: the automatic band's lowest peak [Hz] (NaN until chosen): the block rows span it
        self.band_low = math.nan
        #: a configured band with the automatic order: the modes its order has room for (0:
        #: 2 max_modes; ``_recount_modes``)
        self._band_modes = 0
        #: a configured band with automatic block rows: the lowest lightly damped confirmed
        #: mode [Hz] (NaN: none yet), a full period of which the Hankel window spans
        self._rows_low = math.nan
        #: the automatic band's split (core/band.split_frequency, NaN: none): the modes below
        #: it come from a second estimator (low_band.py)
        self.split_hz = math.nan
        self._split_peaks = 0  # clear structure peaks below the split
        self.low_band: LowBand | None = None
        self._absorbing = False
        self.estimator_band_max = math.inf
        self._raw: list[Chunk] = []
        self._next_check_ns: int | None = None
        self._widen_votes = 0
        self._low_votes = 0
        self._split_votes = 0
        self._order_votes = 0  # a configured band's order (``_recount_modes``)

    def _build_estimator(self, n_outputs: int, n_inputs: int, keep_tracks: bool = False) -> None:
        RecursiveDSRA, ModeTracker = self._core
        v = self.values
        self.decimator = Decimator(P.decimation_factor(v, self.sample_rate, self.band_edge),
                                   self.sample_rate)
        fs = self.identification_rate
        fmin, fmax = self.band
        if not fmin < fmax:  # freq_min at or above the band's top (band_warning says so)
            self.estimator = None
            return
        self.estimator_band_max = fmax
        if self.auto_band:
            # while the automatic band is being chosen the lowest mode is unknown: the window of
            # the seed example (P.INITIAL_LOW_HZ), within the row budget
            low = self.band_low if math.isfinite(self.band_edge) else P.INITIAL_LOW_HZ
            self.block_rows = P.effective_block_rows(v, n_outputs, n_inputs, fs, low)
        else:  # a configured band: grown for its lowest lightly damped mode (_recount_modes)
            self.block_rows = P.period_block_rows(v, n_outputs, n_inputs, fs, self._rows_low)
        top = n_outputs * (self.block_rows - 1)  # largest order the Hankel rows allow
        max_order = min(v["max_order"], top) if v["max_order"] else None
        if max_order is None and self._band_modes:  # a configured band's modes
            max_order = P.effective_max_order(v, self._band_modes, top)
        self.estimator = RecursiveDSRA(
            n_outputs,
            n_inputs=n_inputs,
            fs=fs,
            block_rows=self.block_rows,
            max_order=max_order,
            forgetting_factor=P.effective_lambda(v, fs, self.band_low),
            realization_interval=self._realization_interval(),
            band=(fmin, fmax),
            damping_bounds=(v["damping_min"], v["damping_max"]),
            max_modes=v["max_modes"],
            stabilize=v["spurious_rejection"],
        )
        self._layout = (n_outputs, n_inputs)
        self.low_band = self._new_low_band()
        self._persistence = Persistence()  # test 3 over successive realizations
        if not (keep_tracks and self.tracker is not None):
            self.tracker = ModeTracker(**self._tracker_kwargs(ModeTracker))
            self._tracked: list = []
        self._recent = _Recent(int(RESIDUAL_WINDOW_S * fs) if np.isfinite(fs) else 0)
        self._excited = (None, None)  # (samples seen, excitation test) of _excitation
        kind = f"{n_inputs} input(s)" if n_inputs else "output-only"
        rate = f"{fs:g} Hz"
        if self.decimator.factor > 1:
            rate += f" (decimated by {self.decimator.factor} from {self.sample_rate:g} Hz)"
        self.log(
            f"estimator started: {n_outputs} output(s), {kind}, {rate}, block rows "
            f"{self.block_rows}, lambda {P.effective_lambda(v, fs, self.band_low):.5f}, band "
            f"{fmin:g}-{fmax:g} Hz" + (f"; {self.low_band.describe()}" if self.low_band else "")
        )

    def _new_low_band(self, low_hz: float = math.nan) -> LowBand | None:
        """The estimator of the group below the automatic band's split (None: no split);
        ``low_hz``: the lowest peak while the band is being chosen (``_early_split``)."""
        if math.isfinite(self.band_edge):
            low_hz = self.band_low
        if not (self.auto_band and math.isfinite(self.split_hz) and math.isfinite(low_hz)):
            return None
        return LowBand(self._core[0], self.values, *self._layout, self.identification_rate,
                       self.split_hz, low_hz, self._split_peaks)

    def _tracker_kwargs(self, cls: type) -> dict[str, Any]:
        """Tracking gates of the ModeTracker from the parameters."""
        v = self.values
        return {
            "frequency_gate": v["tracking_frequency_tolerance"],
            "confirm_hits": v["tracking_confirm_count"],
            "lost_timeout_s": v["tracking_lost_timeout"],
            "drop_timeout_s": v["tracking_drop_timeout"],
            "max_tracked": v["max_modes"],
            "report_hits": v["tracking_median_count"],
            "consecutive": True,  # tracking_confirm_count: successive matches
        }

    def _realization_interval(self) -> int:
        return max(1, round(self.identification_rate / self.values["realization_rate"]))

    def reset(self) -> None:
        """Forget all data and the estimate (the parameters are kept)."""
        self._build_ingest()

    # ---- properties ----
    @property
    def sample_rate(self) -> float:
        """Configured or measured sample rate [Hz], NaN while unknown."""
        return self.ingest.fs

    @property
    def identification_rate(self) -> float:
        """Rate the estimator runs at [Hz]: the sample rate over the decimation factor (the
        factor is fixed when the estimator is built); NaN while unknown."""
        if self.decimator is not None:
            return self.decimator.rate
        return self.sample_rate / P.decimation_factor(self.values, self.sample_rate,
                                                      self.band_edge)

    @property
    def auto_band(self) -> bool:
        """The band is chosen from the data (``freq_max: 0``; ``core/band.py``)."""
        return self.values["freq_max"] <= 0

    @property
    def band(self) -> tuple[float, float]:
        """(fmin, fmax) [Hz] identified: the configured band, or the automatic one (0.4 x the
        identification rate until it is chosen)."""
        return P.effective_band(self.values, self.identification_rate, self.band_edge)

    @property
    def forgetting_factor(self) -> float:
        """lambda per identification sample."""
        return P.effective_lambda(self.values, self.identification_rate, self.band_low)

    @property
    def counters(self) -> dict[str, int]:
        return dict(self.ingest.counters)

    # ---- data in ----
    def push_output(self, stamps_ns: np.ndarray, values: np.ndarray,
                    names: tuple[str, ...] | None = None) -> None:
        """A block of output samples; ``names``: the channel names the messages carry."""
        self._names("output", names)
        self.ingest.push_output(stamps_ns, values, names)

    def push_input(self, stamps_ns: np.ndarray, values: np.ndarray,
                   names: tuple[str, ...] | None = None) -> None:
        self._names("input", names)
        self.ingest.push_input(stamps_ns, values, names)

    def _names(self, stream: str, names: tuple[str, ...] | None) -> None:
        if names and list(names) != self.channel_names.get(stream):
            self.set_channel_names(stream, list(names))

    def faults(self) -> list[tuple[int, str]]:
        """Input-side faults now: (HEALTH_* level, reason) of stuck, dead or clipped
        channels (sensor_checks.py)."""
        return self._sensors.faults() if self._sensors is not None else []

    def band_warning(self) -> str:
        """``freq_min``/``freq_max`` rechecked against the rate the data has now: measured
        from the stamps (``sample_rate`` 0) only once data arrives, and again after every time
        line or layout change, so a band accepted at start-up may not fit (#13 item 8). The
        reason, empty when it fits or the rate is unknown; logged (WARN) once per change. The
        estimates keep their health: the modes below the Nyquist frequency are still right."""
        v = self.values
        key = (self.sample_rate, v["sample_rate"], v["freq_min"], v["freq_max"],
               v["decimation"])
        if key != self._band_key:
            self._band_key = key
            reason = P.band_error(v, v["sample_rate"] or self.sample_rate)
            if reason and reason != self._band_reason:
                what = ("nothing is identified (set freq_min below it)"
                        if reason.startswith("freq_min") else
                        "modes above it cannot be identified (set freq_max below it)")
                self.log(f"WARN {reason} of the data's sample rate {self.sample_rate:g} Hz: "
                         + what)
            self._band_reason = reason
        return self._band_reason

    def _check_sensors(self, c: Chunk) -> None:
        if self._sensors is None or c.reset:
            self._sensors = SensorChecks(self.sample_rate)
        self._sensors.add(c.y, c.u)

    def _apply_health(self, records: list[EstimateRecord]) -> None:
        """Fold the input-side faults into the records' health (worst level wins); a record
        with a fault is never reported converged."""
        faults = self.faults()
        for r in records:
            r.health, r.health_reason = merge_health(r.health, r.health_reason, faults)
            if r.health >= HEALTH_FAULT:
                r.converged = False

    def set_channel_names(self, stream: str, names: list[str]) -> None:
        """Names of the channels of ``stream`` ('output' or 'input') as the messages give them;
        used only to label what is published per channel (residual spectra)."""
        self.channel_names[stream] = [str(n) for n in names]

    def channel_name(self, stream: str, k: int, count: int) -> str:
        """Name of channel ``k`` of ``count``: the message's, else ``y0``, ``y1``... (``u0``...
        for inputs) when the messages name none or not as many."""
        names = self.channel_names.get(stream, [])
        if len(names) == count and names[k]:
            return names[k]
        return f"{'y' if stream == 'output' else 'u'}{k}"

    def step(self, flush: bool = False, realize_from_ns: int | None = None
             ) -> list[EstimateRecord]:
        """Process what can be processed; return the records due (usually zero or one).

        ``flush``: the data has ended (offline): hand out the samples held for reordering.
        ``realize_from_ns``: catching up (the node fell behind): samples stamped before it are
        absorbed by the estimator without realizations or records (the expensive part), so
        only the newest data make estimates; the skipped records are counted
        (``estimates_skipped``). None (offline, and live when not behind) skips nothing.
        """
        chunks = self.ingest.pop(flush=flush)
        self._drain_events()
        self.band_warning()
        records: list[EstimateRecord] = []
        for c in chunks:
            self._check_sensors(c)
            if realize_from_ns is not None and len(c) and c.stamps_ns[0] < realize_from_ns:
                cut = int(np.searchsorted(c.stamps_ns, realize_from_ns))
                self._feed(_slice(c, 0, cut), realize=False)
                c = _slice(c, cut, len(c))
                if not len(c):
                    continue
            records += self._feed(c)
        self._apply_health(records)
        self._predict(records)
        return records

    # ---- online LPV (scheduling_topic, lpv_model; scheduling.py) ----
    def push_scheduling(self, stamps_ns: np.ndarray, values: np.ndarray,
                        names: tuple[str, ...] | None = None) -> None:
        """A block of scheduling-signal samples (ignored when scheduling_topic is off)."""
        if self.scheduling is not None:
            self.scheduling.push(stamps_ns, values, names)

    def _predict(self, records: list[EstimateRecord]) -> None:
        """Each record's scheduling value and LPV-predicted modes at its stamp."""
        if self.scheduling is not None:
            self.scheduling.annotate(records)

    def scheduling_status(self) -> dict[str, Any]:
        """/diagnostics keys of the online LPV ({} when off)."""
        return self.scheduling.status() if self.scheduling is not None else {}

    def _drain_events(self) -> None:
        while self.ingest.events:
            self.log(self.ingest.events.popleft())

    def _bucket_ns(self) -> int:
        return max(1, round(1e9 / self.values["publish_rate"]))

    def _feed(self, c: Chunk, realize: bool = True) -> list[EstimateRecord]:
        """Queue a chunk; feed the estimator up to each publication instant it crosses.
        ``realize=False``: absorb it without realizations or records (catching up). With the
        automatic band, the band is chosen once BAND_PROBE_S of data are in and rechecked as
        data come (a change rebuilds the estimator from the recent raw data)."""
        ny, nu = c.y.shape[1], 0 if c.u is None else c.u.shape[1]
        if c.reset or (self._layout is not None and self._layout != (ny, nu)):
            self._pending.clear()
            # the same outputs with an input stream that stopped or came back measure the same
            # structure: the tracker keeps its modes (ids, status) through the estimator reset
            # (a new time line, or other outputs, starts over)
            self._keep_tracks = (self._layout is not None and self._layout[0] == ny
                                 and self._layout[1] != nu)
            if self.estimator is not None:
                self.log("channel layout or time line changed: estimator reset")
            self.estimator = None
            self._raw = []
            if self._keep_tracks and math.isfinite(self.band_edge):
                # the same structure: its band and lowest peak hold (rechecked as data come)
                self._next_check_ns = int(c.stamps_ns[0]) + round(BAND_CHECK_PERIOD_S * 1e9)
            else:
                self.band_edge = math.nan
                self._early_looks = 0
                self.band_low = math.nan
                self._band_modes = 0  # a configured band's modes are counted again
                self._rows_low = math.nan
                self.split_hz = math.nan
                self._next_check_ns = None
        v = self.values
        if not self.auto_band and v["max_order"] > 0:
            return self._feed_estimator(c, realize)
        self._layout = (ny, nu)
        if not self.auto_band and self._next_check_ns is None:
            self._next_check_ns = int(c.stamps_ns[0]) + round(BAND_CHECK_PERIOD_S * 1e9)
        records: list[EstimateRecord] = []
        while len(c):  # cut at the sample a check is due: chunking changes nothing
            k = self._samples_to_check(c)
            part, c = _slice(c, 0, k), _slice(c, k, len(c))
            self._keep_raw(part)
            records += self._feed_estimator(part, realize)
            last = int(part.stamps_ns[-1])
            if self._probing:
                if self._raw_count() >= self._probe_samples():
                    self._choose_band()
                elif self._raw_count() >= self._early_samples():
                    self._early_split()
            elif self._next_check_ns is not None and last >= self._next_check_ns:
                self._recheck_band(last) if self.auto_band else self._recount_modes(last)
        return records

    @property
    def _probing(self) -> bool:
        """The automatic band is not chosen yet (before BAND_PROBE_S of data)."""
        return self.auto_band and not math.isfinite(self.band_edge)

    # ---- configured band (freq_max > 0) with the automatic order (max_order 0) ----
    def _recount_modes(self, last_ns: int) -> None:
        """Every BAND_CHECK_PERIOD_S: the confirmed mode tracks (tracked, ranked out or lost
        for less than the drop timeout: modes seen consistently over many realizations, even
        those that drop out of single ones). When the order has no room for them as the
        automatic band's low group would size it (``params.effective_max_order``: twice the
        larger of max_modes and ORDER_PER_PEAK x the modes), or the Hankel window does not span
        a full period of the lowest lightly damped one (LIGHT_DAMPING; by ROWS_GROWTH x the
        rows or more, within the cost budget of ``params.period_block_rows``), on two checks in
        a row, the estimator is rebuilt with that order and window from the recent raw data,
        keeping the tracks. A band of many close modes (a frame's eight below 10 Hz) fills a
        realization of 2 max_modes: its weakest modes drop out of it for seconds at a time; a
        window short against a lightly damped mode's period gives a noisy frequency (a 2.6 Hz
        mode at 200 Hz, 2 % damped: the notch bank's lag 1.9 -> 1.4 x the oracle's with 35 ->
        70 rows). Both only grow (a quiet spell does not take modes out of the realization)."""
        self._next_check_ns = last_ns + round(BAND_CHECK_PERIOD_S * 1e9)
        if self.estimator is None or self.tracker is None:
            return
        confirmed = [tr for tr in self.tracker.tracks if getattr(tr, "confirmed", False)]
        k = len(confirmed)
        top = self._layout[0] * (self.block_rows - 1)
        order = P.effective_max_order(self.values, k, top)
        f_low = min((tr.frequency_hz for tr in confirmed
                     if tr.frequency_hz > 0 and tr.damping_ratio <= LIGHT_DAMPING),
                    default=math.nan)
        rows = P.period_block_rows(self.values, *self._layout, self.identification_rate, f_low)
        more_rows = math.isfinite(f_low) and rows >= ROWS_GROWTH * self.block_rows
        if not self._voted("_order_votes", order > self.estimator.max_order or more_rows):
            return
        fmin, fmax = self.band
        self.log(f"band {fmin:g}-{fmax:g} Hz holds {k} confirmed modes (lowest lightly damped "
                 f"{f_low:.4g} Hz): "
                 f"model order {self.estimator.max_order} -> {max(order, self.estimator.max_order)}"
                 f", block rows {self.block_rows} -> {max(rows, self.block_rows)}")
        self._band_modes = max(k, self._band_modes)
        if more_rows:
            self._rows_low = f_low
        self._rebuild_from_raw()

    # ---- automatic band (freq_max 0; core/band.py) ----
    def _probe_samples(self) -> int:
        return int(max(BAND_PROBE_S * self.sample_rate, BAND_PROBE_MIN_SAMPLES))

    def _early_samples(self) -> int:
        """Raw samples at which the split is looked for next (``_early_split``), or the probe's
        once the looks are done or found one."""
        if self._early_looks >= len(EARLY_SPLIT_S) or self.low_band is not None:
            return self._probe_samples()
        return int(max(EARLY_SPLIT_S[self._early_looks] * self.sample_rate,
                       BAND_PROBE_MIN_SAMPLES))

    def _samples_to_check(self, c: Chunk) -> int:
        """Samples of ``c`` up to the one at which the next band check is due (all of them
        when none is due within ``c``)."""
        if self._probing:
            due = min(self._probe_samples(), self._early_samples())
            return int(min(max(due - self._raw_count(), 1), len(c)))
        if self._next_check_ns is None:
            return len(c)
        return int(min(np.searchsorted(c.stamps_ns, self._next_check_ns, side="left") + 1,
                       len(c)))

    def _raw_count(self) -> int:
        return sum(len(r) for r in self._raw)

    def _keep_raw(self, c: Chunk) -> None:
        """The raw data of the last BAND_CHECK_WINDOW_S (at least twice the probe), trimmed
        by sample stamps (for the checks and rebuilds)."""
        if not len(c):
            return
        self._raw.append(c)
        fs = self.sample_rate
        keep = round(max(BAND_CHECK_WINDOW_S, 2 * BAND_PROBE_MIN_SAMPLES / fs) * 1e9)
        start = int(c.stamps_ns[-1]) - keep
        while self._raw and self._raw[0].stamps_ns[-1] <= start:
            self._raw.pop(0)
        first = self._raw[0]
        k = int(np.searchsorted(first.stamps_ns, start, side="right"))
        if k:
            self._raw[0] = _slice(first, k, len(first))

    def _raw_arrays(self) -> tuple[np.ndarray, np.ndarray | None]:
        y = np.concatenate([r.y for r in self._raw])
        u = None if self._raw[0].u is None else np.concatenate([r.u for r in self._raw])
        return y, u

    def _band_from_raw(self, prominence: float = 1.0, ratio_factor: float = 1.0):
        t0 = time.perf_counter()
        y, u = self._raw_arrays()
        choice = structure_band(y, u, self.sample_rate, prominence, ratio_factor,
                                self.values["freq_min"])
        self.update_seconds += time.perf_counter() - t0
        return choice

    def _choose_band(self) -> None:
        """The band, once BAND_PROBE_S of data are in (the estimator ran on the full safe band
        until then): when it is narrower, the estimator is rebuilt for it from the raw data
        (decimated to match), keeping the tracks."""
        choice = self._band_from_raw()
        self.band_edge = choice.fmax_hz
        self.band_low = choice.low_hz

        fs_id = self.sample_rate / P.decimation_factor(self.values, self.sample_rate,
                                                       choice.fmax_hz)
        capped = P.window_capped(self.values, *self._layout, fs_id, choice.low_hz)
        top = max_split_hz(self.values, *self._layout, fs_id, choice.low_hz)
        self._set_split(split_frequency(choice, top) if capped else math.nan, choice)
        self._next_check_ns = int(self._raw[-1].stamps_ns[-1]) + round(BAND_CHECK_PERIOD_S * 1e9)
        self._widen_votes = 0
        self._low_votes = 0
        self._split_votes = 0
        top = f"{choice.top_hz:.4g} Hz" if choice.found else "none"
        low = f"{choice.low_hz:.4g} Hz" if math.isfinite(choice.low_hz) else "none"
        self.log(f"automatic band {self.band[0]:g}-{self.band[1]:g} Hz (structure above the "
                 f"noise floor up to {top}, lowest peak {low})")
        factor = P.decimation_factor(self.values, self.sample_rate, self.band_edge)
        rows = P.effective_block_rows(self.values, *self._layout, self.sample_rate / factor,
                                      self.band_low)
        if (factor != self.decimator.factor or self.band[1] < self.estimator_band_max
                or rows != self.block_rows):
            self._rebuild_from_raw()
            return
        if self.estimator is not None and hasattr(self.estimator, "set_forgetting_factor"):
            self.estimator.set_forgetting_factor(self.forgetting_factor)  # memory_periods
        self._start_low_band()

    def _early_split(self) -> None:
        """While the band is being chosen, at each of EARLY_SPLIT_S until one finds it: when the
        full-rate window cannot span the lowest peak of these data and their peaks leave a gap
        (``core.band.split_frequency``), the low group's estimator starts now (fed the raw data
        so far) rather than at the band choice, which decides again on all BAND_PROBE_S (its
        finer bins choose the band, the window and the memory; this look only adds the low
        estimator). With a window capped short of a low mode's period the main estimator does
        not resolve it (a 3.8 Hz mode at 742 Hz with 70 block rows, two modes 6 % apart near 5
        Hz at 613 Hz with 35); the low group found it 0.2-0.5 s after it started. The first
        look's bins are twice the probe's: low modes in its first bins may not show a rise
        (modes near 2-5 Hz at 800 Hz), hence the second."""
        self._early_looks += 1
        choice = self._band_from_raw()
        fs, low = self.identification_rate, choice.low_hz
        if not (math.isfinite(low) and low > 0
                and P.window_capped(self.values, *self._layout, fs, low)):
            return
        split = split_frequency(choice, max_split_hz(self.values, *self._layout, fs, low))
        if not math.isfinite(split):
            return
        self._set_split(split, choice)
        self._start_low_band(low)

    def _start_low_band(self, low_hz: float = math.nan) -> None:
        """The estimator of the group below the split, fed the recent raw data without
        realizations (the main estimator goes on untouched) up to the samples still held for
        it (``_pending``), which both will get at the next flush. ``low_hz``: the lowest peak
        while the band is being chosen (``_early_split``)."""
        self.low_band = self._new_low_band(low_hz)
        if self.low_band is None:
            return
        self.log(f"automatic {self.low_band.describe()}")
        held = [p for p in self._pending if len(p)]
        end = int(held[0].stamps_ns[0]) if held else None
        decimator = Decimator(self.decimator.factor, self.sample_rate)
        for k, seg in enumerate(self._raw_segments()):
            if k:
                decimator.restart()
                self.low_band.restart()
            whole = _concat(seg)
            stamps, y, u = decimator.process(whole.stamps_ns, whole.y, whole.u)
            n = len(stamps) if end is None else int(np.searchsorted(stamps, end))
            self.low_band.update(None if u is None else u[:n], y[:n], realize=False)

    def _recheck_split(self) -> None:
        """While the main estimator's window is capped, look for the split again on the recent
        raw data (the first choice sees 4 s of data in coarse bins): a split found, or one
        SPLIT_MOVE above the current one, on two successive checks starts the second
        estimator there. A split never moves down nor goes (as the band never narrows): the
        group below only grows."""
        if not P.window_capped(self.values, *self._layout, self.identification_rate,
                               self.band_low):
            return
        top = max_split_hz(self.values, *self._layout, self.identification_rate, self.band_low)
        choice = self._band_from_raw()
        new, cur = split_frequency(choice, top), self.split_hz
        up = math.isfinite(new) and not (math.isfinite(cur) and new < SPLIT_MOVE * cur)
        if not self._voted("_split_votes", up):
            return
        self._set_split(new, choice)
        self._start_low_band()

    def _set_split(self, split_hz: float, choice) -> None:
        """The split [Hz] and the count of the choice's clear peaks below it (the low group's
        model order, ``params.effective_max_order``)."""
        self.split_hz = split_hz
        self._split_peaks = sum(1 for p in choice.peaks_hz if p < split_hz)

    def _recheck_band(self, last_ns: int) -> None:
        """Recheck the band on the recent raw data; widen it (rebuild the estimator from those
        data, keeping the tracks) when a clear peak (WIDEN_PROMINENCE, WIDEN_RATIO_FACTOR: not
        the roll-off of a strong mode) shows above WIDEN_FRACTION of it on two
        successive checks. It never narrows (no rebuild for a quiet spell); its lowest peak
        may move down (``_recheck_low``)."""
        self._next_check_ns = last_ns + round(BAND_CHECK_PERIOD_S * 1e9)
        self._recheck_split()
        choice = self._band_from_raw(WIDEN_PROMINENCE, WIDEN_RATIO_FACTOR)
        wider = (choice.found and choice.top_hz > WIDEN_FRACTION * self.band_edge
                 and choice.fmax_hz > self.band_edge)
        if not self._voted("_widen_votes", wider):
            self._recheck_low(choice)
            return
        self.band_edge = choice.fmax_hz
        self.log(f"automatic band widened to 0-{self.band_edge:g} Hz (structure up to "
                 f"{choice.top_hz:.4g} Hz): estimator rebuilt from the last "
                 f"{BAND_CHECK_WINDOW_S:g} s of data")
        self._rebuild_from_raw()

    def _recheck_low(self, choice) -> None:
        """Move the lowest peak down when the recent data (up to BAND_CHECK_WINDOW_S: bins
        finer than the first choice's 4 s) show structure rising below it up to a clear peak
        below it, and the Hankel window needs ROWS_GROWTH x its rows to span half a period of
        it (``params.effective_block_rows``), on two successive checks: the estimator is
        rebuilt from the recent raw data with that window and memory, keeping the tracks. Low
        modes standing little above a flat response (a displacement output's static level) in
        the first choice's coarse bins are missed, and a window of a fraction of their period
        loses them (a 2 Hz mode at 218 Hz with 23 block rows). Never up: a quiet spell does
        not shorten the window."""
        low, cur = choice.low_hz, self.band_low
        # a clear peak (not one of the first bins, clear by default) between the new lowest
        # rise and the current one: a mode below the window's, not a low-frequency drift
        first = PEAK_MIN_BINS * choice.resolution_hz * (1 + 1e-9)
        peak = any(first < p and low <= p and not p >= cur for p in choice.peaks_hz)
        lower = (math.isfinite(low) and low > 0 and peak
                 and P.effective_block_rows(self.values, *self._layout,
                                            self.identification_rate, low)
                 >= ROWS_GROWTH * self.block_rows)
        if not self._voted("_low_votes", lower):
            return
        self.band_low = low
        self.log(f"automatic band: lowest peak moved down to {low:.4g} Hz (structure rising "
                 f"there in the last {BAND_CHECK_WINDOW_S:g} s of data): estimator rebuilt "
                 "with a longer window")
        self._rebuild_from_raw()

    def _voted(self, counter: str, yes: bool) -> bool:
        """Hysteresis of the band's and the split's changes: ``yes`` on two checks in a row
        (the vote count ``counter`` starts again after a no and after a change)."""
        n = getattr(self, counter) + 1 if yes else 0
        setattr(self, counter, 0 if n >= 2 else n)
        return n >= 2

    def _rebuild_from_raw(self) -> None:
        """A new estimator (and decimator) for the current band, fed the recent raw data
        without realizations or records, one block per contiguous segment (as the raw data
        are, however they were chunked); the tracker keeps its tracks, and the residual
        window its data when the identification rate is unchanged."""
        self._pending.clear()
        skipped = self.ingest.counters.get("estimates_skipped", 0)
        samples = self.update_samples
        rate, recent, last_bucket = self.identification_rate, self._recent, self._last_bucket
        self._build_estimator(*self._layout, keep_tracks=True)
        for k, seg in enumerate(self._raw_segments()):
            # gaps inside restart the window as they did
            whole = dataclasses.replace(_concat(seg), new_segment=bool(k), reset=False)
            self._feed_estimator(whole, realize=False)
        if self.identification_rate == rate:
            self._recent = recent
        if last_bucket is not None and self._last_bucket is not None:
            self._last_bucket = max(self._last_bucket, last_bucket)
        self.ingest.counters["estimates_skipped"] = skipped
        self.update_samples = samples

    def _raw_segments(self) -> list[list[Chunk]]:
        """The recent raw data as contiguous segments (a gap starts a new one)."""
        segments: list[list[Chunk]] = []
        for r in self._raw:
            if r.new_segment or not segments:
                segments.append([])
            segments[-1].append(r)
        return segments

    def _feed_estimator(self, c: Chunk, realize: bool = True) -> list[EstimateRecord]:
        """Decimate a chunk and feed it to the estimator (built at its first chunk) up to each
        publication instant it crosses."""
        ny, nu = c.y.shape[1], 0 if c.u is None else c.u.shape[1]
        if self.estimator is None:
            self._build_estimator(ny, nu, keep_tracks=getattr(self, "_keep_tracks", False))
            if self.estimator is None:  # an empty band: nothing to identify
                return []
            self._keep_tracks = False
            self._last_bucket = None
        elif c.new_segment:
            self._flush_pending()
            self._restart_window()
            self.decimator.restart()
        self.update_samples += len(c)  # cost is per sample of the incoming stream
        if self.decimator.factor > 1:
            t0 = time.perf_counter()
            stamps, y, u = self.decimator.process(c.stamps_ns, c.y, c.u)
            self.update_seconds += time.perf_counter() - t0
            if len(stamps) == 0:
                return []
            c = Chunk(stamps_ns=stamps, y=y, u=u, new_segment=c.new_segment)
        # half a period of slack so that a stamp a few ns off a multiple of the publication
        # period (float seconds in a bag) still falls on the same side
        half = round(5e8 / self.identification_rate)
        bucket = (c.stamps_ns + half) // self._bucket_ns()
        prev = bucket[0] if self._last_bucket is None else self._last_bucket
        # a period is crossed once: the running largest bucket (a rebuild at a new rate moves
        # the half-period slack, and a stamp may fall back into the period before)
        bucket = np.maximum.accumulate(np.concatenate(([prev], bucket)))[1:]
        cross = np.flatnonzero(np.diff(np.concatenate(([prev], bucket))) != 0)
        if not realize:
            self._pending.append(c)
            self._absorb_only()
            self._last_bucket = int(bucket[-1])
            self.ingest.counters["estimates_skipped"] += len(cross)
            return []
        records = []
        start = 0
        for i in cross:
            # feed everything up to and including sample i, then make the record
            self._pending.append(_slice(c, start, i + 1))
            self._flush_pending()
            start = i + 1
            records.append(self._record(int(c.stamps_ns[i])))
        if start < len(c):
            self._pending.append(_slice(c, start, len(c)))
        self._last_bucket = int(bucket[-1])
        return records

    def _flush_pending(self) -> None:
        """Feed the held samples (all of one segment) to the estimator as ONE block, so the
        estimator sees the same blocks however the messages were chunked."""
        parts = [p for p in self._pending if len(p)]
        self._pending.clear()
        if not parts:
            return
        self._update(_concat(parts))

    def _absorb_only(self) -> None:
        """Feed the held samples without realizing a model (catching up;
        ``RecursiveDSRA.absorb``): the next realization is due at once after them."""
        self._absorbing = True
        try:
            self._flush_pending()
        finally:
            self._absorbing = False

    def _restart_window(self) -> None:
        """Data resumes after a gap: no Hankel row may span it (the estimate is kept)."""
        self._recent.clear()
        self._excited = (None, None)
        if self.low_band is not None:
            self.low_band.restart()
        est = self.estimator
        if hasattr(est, "restart_window"):
            est.restart_window()
            return
        # RecursiveDSRA.update skips a NaN sample and restarts its window after it
        ny, nu = self._layout
        est.update(np.full((1, nu), np.nan) if nu else None, np.full((1, ny), np.nan))

    def _update(self, c: Chunk) -> None:
        """Feed a piece to the estimator; every model realized in it updates the tracker, at
        the stamp of the sample it was realized after."""
        est = self.estimator
        t0 = time.perf_counter()
        c0 = time.thread_time()
        self._recent.add(c.y, c.u)
        s0 = int(getattr(est, "samples_seen", self._samples))
        low = self.low_band
        absorb = self._absorbing
        if not absorb and self.budget is not None and not self.budget.allow():
            absorb = True  # the realizations' CPU share is used up: stay current instead
            self.ingest.counters["realizations_deferred"] += 1
        spent0 = self._realization_seconds() if self.budget is not None else 0.0
        if low is not None:
            low.update(c.u, c.y, not absorb, (s0 + len(c)) / self.identification_rate)
        if absorb:
            est.absorb(c.u, c.y)
            models = []
        else:
            models = est.update(c.u, c.y) or []
        c_track = time.thread_time()
        for mdl in models:
            t_data = float(getattr(mdl, "time_s", math.nan))
            k = round(t_data * self.identification_rate) - s0 - 1
            k = min(max(k, 0), len(c) - 1) if math.isfinite(k) else len(c) - 1
            modes = list(getattr(mdl, "modes", []))
            if low is not None:  # the group below the split from its own estimator
                modes = [m for m in modes if m.frequency_hz >= low.split_hz] + low.current(
                    t_data, self.values["realization_rate"])
            self._track(modes, int(c.stamps_ns[k]) * 1e-9, _young(est))
        dt = time.perf_counter() - t0
        if self.budget is not None and not absorb:
            # the CPU time of the realizations and the tracking after them (of the whole piece
            # when the estimator does not time its realizations, or was rebuilt meanwhile); CPU
            # time, not wall clock: a stall of the process (a VM descheduling it for up to a
            # second) is not the realizations' cost, and charging it would stop them for seconds
            spent = self._realization_seconds() - spent0
            ok = math.isfinite(spent) and spent >= 0
            c_end = time.thread_time()
            if models or not ok or spent > 0:  # a piece without a realization costs nothing
                self.budget.spend(spent + c_end - c_track if ok else c_end - c0)
        self.update_seconds += dt
        self.last_update_cost = dt / len(c)
        self._samples += len(c)

    def _realization_seconds(self) -> float:
        """CPU seconds the estimators have spent realizing (NaN: not timed)."""
        ests = [self.estimator] + ([self.low_band.estimator] if self.low_band else [])
        return sum(float(getattr(e, "realization_seconds", math.nan)) for e in ests)

    def go_live(self, clock: Callable[[], float] = time.monotonic) -> None:
        """The live node's wall-clock rules (its worker calls this; offline never does): the
        realizations use at most ``realization_budget`` of a core, and a late input stream is
        waited for ``ingest.INPUT_WAIT`` s of wall-clock time as well as of data. The estimates
        then depend on the machine's speed and load (the budget; 0 = none)."""
        self._live_clock = clock
        self.ingest.clock = clock
        share = float(self.values["realization_budget"])
        self.budget = RealizationBudget(share, clock=clock) if share > 0 else None

    def _track(self, modes: list, t: float, young: bool = False) -> None:
        """The current (live) band, bounds and mode count, then the tracker (which matches only
        the modes that passed the spurious-mode tests: ``spurious_rejection``; while the
        estimator is ``young`` test 3 is lifted for pole pairs that persist over successive
        realizations: ``core.spurious.Persistence``). At most
        ``max_modes`` candidates: the stable ones first, then by contribution (scale-free, the
        tracker's ranking; :func:`~sysid_node.core.modal.select_modes`)."""
        v = self.values
        fmin, fmax = self.band
        modes = [
            m for m in modes
            if fmin <= m.frequency_hz <= fmax
            and v["damping_min"] <= m.damping_ratio <= v["damping_max"]
        ]
        self._persistence.apply(modes, young)
        modes = sorted(modes, key=lambda m: (not getattr(m, "stable", True),
                                             -_finite(_rank_key(m))))[: v["max_modes"]]
        self._tracked = self.tracker.update(modes, t, self._excitation())

    def _excitation(self) -> Callable[[np.ndarray], np.ndarray] | None:
        """Which frequencies the measured input excites over two memory time constants of the
        estimator (Welch spectrum, any input within EXCITATION_DB of the peak); None for
        output-only data or too little of it. Made again once an eighth of that window is
        new (the spectrum of a window that moved less is about the same)."""
        if not self._layout[1]:
            return None
        fs = self.identification_rate
        lam = P.effective_lambda(self.values, fs, self.band_low)
        n = min(self._recent.n, max(SPECTRUM_MIN_SAMPLES, round(2.0 * memory_samples(lam))))
        made, fn = self._excited
        if made is not None and 0 <= self._samples - made < max(1, n // 8):
            return fn
        _, u = self._recent.arrays()
        fn = None
        if u is not None and len(u) >= SPECTRUM_MIN_SAMPLES:
            f, p = signal.welch(u[-n:], fs=fs, nperseg=min(n, len(u)) // 2, axis=0)
            p = p.max(axis=1)
            floor = float(p.max()) * 10.0 ** (-EXCITATION_DB / 10.0)
            if floor > 0:
                fn = lambda freqs: np.interp(freqs, f, p) >= floor  # noqa: E731
        self._excited = (self._samples, fn)
        return fn

    def pop_spectra(self) -> list[SpectrumRecord]:
        """Residual spectra made since the last call (at most ``residual_spectrum_rate`` per
        second of data, at estimate instants)."""
        out, self.spectra = self.spectra, []
        return out

    def _spectrum(self, stamp_ns: int) -> None:
        """Residual of the current model on the recent data: the one-step Kalman predictor of
        the latest realization (A, B, C, D, K) run over the last RESIDUAL_WINDOW_S seconds
        (its first block-rows samples dropped as the predictor's start-up), then the same Welch
        spectrum and white noise floor as ``validate`` (validation/residuals.py)."""
        rate = self.values["residual_spectrum_rate"]
        model = getattr(self.estimator, "model", None)
        if rate <= 0 or model is None or not hasattr(model, "predict"):
            return
        if self._next_spectrum_ns is not None and stamp_ns < self._next_spectrum_ns:
            return
        y, u = self._recent.arrays()
        skip = self.block_rows
        if y.shape[0] - skip < SPECTRUM_MIN_SAMPLES:
            return
        try:
            e = (y - model.stable_predictor().predict(y, u))[skip:]
        except (ValueError, np.linalg.LinAlgError):
            return
        if not np.all(np.isfinite(e)):
            return
        self._next_spectrum_ns = stamp_ns + round(1e9 / rate)
        sp = residual_spectrum(e, self.identification_rate)
        for k in range(e.shape[1]):
            self.spectra.append(SpectrumRecord(
                stamp_ns, self.channel_name("output", k, e.shape[1]), sp.f,
                np.sqrt(sp.psd[:, k]), np.sqrt(sp.floor[:, k])))

    def _record(self, stamp_ns: int) -> EstimateRecord:
        self._spectrum(stamp_ns)
        est = self.estimator
        t = stamp_ns * 1e-9
        out = [self._mode_record(tm, t) for tm in self._tracked]
        out.sort(key=lambda m: m.frequency_hz)
        pe = np.asarray(_get(est, "prediction_error_rms", default=np.full(self._layout[0], np.nan)),
                        dtype=float).reshape(-1)
        self.records_made += 1
        band = self.band
        status = est.status() if hasattr(est, "status") else None  # estimator-side health
        return EstimateRecord(
            stamp_ns=stamp_ns,
            modes=out,
            model_order=_model_order(est),
            block_rows=int(self.block_rows),
            forgetting_factor=self.forgetting_factor,
            sample_rate=self.identification_rate,
            prediction_error_rms_per_channel=pe,
            converged=bool(_get(est, "converged", default=False)),
            samples_used=int(_get(est, "samples_seen", default=self._samples)),
            counters=self.counters,
            band_min_hz=band[0],
            band_max_hz=band[1],
            health=status.health if status else 0,
            health_reason=status.reason if status else "",
        )

    def _mode_record(self, tm: Any, t: float) -> ModeRecord:
        m = tm
        for name in ("mode", "modal", "params", "parameters", "modal_parameters", "latest"):
            if getattr(tm, name, None) is not None and hasattr(getattr(tm, name), "frequency_hz"):
                m = getattr(tm, name)
                break
        status = getattr(tm, "status", "tentative")
        if not isinstance(status, str):
            status = STATUS_NAMES[int(status)]
        first = _get(tm, "first_seen", default=t)
        shape = np.asarray(_get(m, "shape", default=np.full(self._layout[0], np.nan)))
        return ModeRecord(
            id=int(_get(tm, "id", "mode_id", default=0)),
            status=status,
            frequency_hz=float(_get(m, "frequency_hz")),
            frequency_std_hz=float(_get(m, "frequency_std_hz")),
            damping_ratio=float(_get(m, "damping_ratio")),
            damping_std=float(_get(m, "damping_std")),
            amplitude=float(_get(m, "amplitude")),
            age_s=float(t - first) if math.isfinite(first) else math.nan,
            shape=shape.astype(complex),
        )

    # ---- parameters ----
    def set_parameters(self, changes: dict[str, Any]) -> str:
        """Validate and apply ``changes``; return '' on success, else the reason (nothing
        changed). Structural changes rebuild the estimator with a log line."""
        changes = {k: v for k, v in changes.items() if self.values.get(k) != v}
        if not changes:
            return ""
        new = {**self.values, **changes}
        fs = self.sample_rate if self.values["sample_rate"] == new["sample_rate"] else math.nan
        reason = P.validate_set(new, sample_rate=fs)
        if reason:
            return reason
        structural = P.structural_changes(self.values, changes)
        if (self.values["freq_max"] <= 0) != (new["freq_max"] <= 0):
            structural.append("automatic band")  # choosing it from the data, or leaving it
        elif self.decimator is not None and (
            P.decimation_factor(new, fs, self.band_edge) != self.decimator.factor
        ):
            structural.append("decimation factor")  # e.g. auto decimation and a new freq_max
        if new["freq_max"] <= 0 and "freq_min" in changes and "automatic band" not in structural:
            structural.append("freq_min of the automatic band")  # chosen again above it
        self.values = new
        if structural:
            self.log(f"structural parameter(s) changed ({', '.join(sorted(structural))}): "
                     "estimator reset")
            self._build_ingest()
            return ""
        self._apply_live(changes)
        self.log("parameter(s) applied live: "
                 + ", ".join(f"{k}={v}" for k, v in sorted(changes.items())))
        return ""

    def _apply_live(self, changes: dict[str, Any]) -> None:
        est, v, fs = self.estimator, self.values, self.identification_rate
        if "realization_budget" in changes and self._live_clock is not None:
            self.go_live(self._live_clock)
        if any(k.startswith("tracking_") for k in changes) and self.tracker is not None:
            for names, key in (
                (("frequency_gate", "frequency_tolerance"), "tracking_frequency_tolerance"),
                (("confirm_hits", "confirm_count"), "tracking_confirm_count"),
                (("lost_timeout_s", "lost_timeout"), "tracking_lost_timeout"),
                (("drop_timeout_s",), "tracking_drop_timeout"),
                (("report_hits",), "tracking_median_count"),
            ):
                for n in names:
                    if hasattr(self.tracker, n):
                        setattr(self.tracker, n, v[key])
                        break
        if est is None:
            return
        if self.low_band is not None:
            self.low_band.apply_live(v, changes)
        if "spurious_rejection" in changes and hasattr(est, "stabilize"):
            est.stabilize = bool(v["spurious_rejection"])
        if {"forgetting_factor", "memory_time_constant", "memory_periods"} & changes.keys():
            est.set_forgetting_factor(P.effective_lambda(v, fs, self.band_low))
        if {"freq_min", "freq_max", "damping_min", "damping_max"} & changes.keys():
            est.set_band(P.effective_band(v, fs, self.band_edge),
                         (v["damping_min"], v["damping_max"]))
        if "max_modes" in changes and hasattr(self.tracker, "max_tracked"):
            self.tracker.max_tracked = v["max_modes"]
        if "max_modes" in changes:
            if hasattr(est, "set_max_modes"):
                est.set_max_modes(v["max_modes"])
            elif hasattr(est, "max_modes"):
                est.max_modes = v["max_modes"]
        if "realization_rate" in changes:
            if hasattr(est, "set_realization_interval"):
                est.set_realization_interval(self._realization_interval())
            elif hasattr(est, "realization_interval"):
                est.realization_interval = self._realization_interval()


#: Automatic band (freq_max 0): data before the band is chosen [s] and [samples] (the
#: larger), the period of its rechecks [s of data], the recent raw data they look at [s], and
#: the fraction of the band above which a clear peak (prominence and ratio factor of
#: core/band.structure_band) widens it (hysteresis: the band is half an octave above the
#: structure when chosen, so a mode may rise by ~27 % before a rebuild).
BAND_PROBE_S = 4.0
BAND_PROBE_MIN_SAMPLES = 512
#: While the band is being chosen, the split (a low group's estimator) is looked for after
#: these amounts of data [s] (and BAND_PROBE_MIN_SAMPLES) until found: half and three
#: quarters of the probe (MIN_SEGMENTS Welch segments of half and three quarters its length).
EARLY_SPLIT_S = (0.5 * BAND_PROBE_S, 0.75 * BAND_PROBE_S)
BAND_CHECK_PERIOD_S = 2.0
#: A configured band's window grows when its lowest lightly damped confirmed mode asks this
#: many times the rows it has (one rebuild, not one per step of a drifting mode).
ROWS_GROWTH = 1.25
#: Lightly damped (the structural modes notches are for): a window spanning their period
#: sharpens their frequency. A well-damped response (a rigid-body mode) does not size the
#: window: sized by one, the fast drifts of the mode above it were followed worse
#: (benchmarks/notch_drift_suite.py draws 5 and 13).
LIGHT_DAMPING = 0.05
BAND_CHECK_WINDOW_S = 10.0
WIDEN_FRACTION = 0.85
WIDEN_PROMINENCE = 2.0
WIDEN_RATIO_FACTOR = 4.0
#: A split found again this factor above the current one moves there (two checks in a row).
SPLIT_MOVE = 1.5
#: Residual samples needed before a spectrum is made (a few Welch segments).
SPECTRUM_MIN_SAMPLES = 256
#: Recent data the residual spectrum is computed over [s].
RESIDUAL_WINDOW_S = 20.0
#: A frequency the input's spectrum over the estimator's memory holds more than this far below
#: its peak [dB] is not excited: a confirmed mode seen while excited is held there, not lost
#: (core.tracking; a sweep or a record-long Schroeder multisine excites one band at a time).
EXCITATION_DB = 20.0


class _Recent:
    """The last ``n`` samples (y, u) fed to the estimator, for the residual spectrum."""

    def __init__(self, n: int) -> None:
        self.n = n
        self.clear()

    def clear(self) -> None:
        self._y: list[np.ndarray] = []
        self._u: list[np.ndarray | None] = []
        self._count = 0

    def add(self, y: np.ndarray, u: np.ndarray | None) -> None:
        if self.n <= 0:
            return
        self._y.append(y)
        self._u.append(u)
        self._count += y.shape[0]
        if self._count > 2 * self.n:  # compact now and then
            yy, uu = self.arrays()
            self._y, self._u, self._count = [yy], [uu], yy.shape[0]

    def arrays(self) -> tuple[np.ndarray, np.ndarray | None]:
        if not self._y:
            return np.zeros((0, 0)), None
        y = np.concatenate(self._y)[-self.n :]
        u = None if self._u[0] is None else np.concatenate(self._u)[-self.n :]
        return y, u


def _model_order(est: Any) -> int:
    """State dimension of the latest realized model (0 before the first)."""
    model = getattr(est, "model", None)
    if model is not None and getattr(model, "A", None) is not None:
        return int(np.asarray(model.A).shape[0])
    return 0


def _young(est: Any) -> bool:
    """The estimator's memory 1/(1 - lambda) is not filled yet (start-up)."""
    lam = float(getattr(est, "forgetting_factor", 1.0))
    return int(getattr(est, "samples_seen", 0)) < memory_samples(lam)


def _rank_key(m: Any) -> float:
    """The mode's ranking value (``ModalParameters.rank_key``: contribution, else amplitude)."""
    key = getattr(m, "rank_key", None)
    return float(key) if key is not None else float(_get(m, "amplitude"))


def _finite(x: float) -> float:
    return x if math.isfinite(x) else -math.inf


def _concat(parts: list[Chunk]) -> Chunk:
    """One chunk of consecutive pieces (a new segment if the first one is)."""
    if len(parts) == 1:
        return parts[0]
    return Chunk(
        stamps_ns=np.concatenate([p.stamps_ns for p in parts]),
        y=np.concatenate([p.y for p in parts]),
        u=None if parts[0].u is None else np.concatenate([p.u for p in parts]),
        new_segment=parts[0].new_segment,
    )


def _slice(c: Chunk, a: int, b: int) -> Chunk:
    """Rows ``a:b`` of a chunk (a new segment only if it starts where ``c`` does)."""
    return Chunk(
        stamps_ns=c.stamps_ns[a:b],
        y=c.y[a:b],
        u=None if c.u is None else c.u[a:b],
        new_segment=c.new_segment and a == 0,
    )
