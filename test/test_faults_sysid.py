"""Fault injection into sysid_node's processing, one case per class of bad input (issue #13).

The pure pipeline (what the node's worker and ``offline`` run) is fed the paper's Sec. II data
(2 and 4 Hz) on three output channels, transformed by ``sysid_node.scenarios.faults``. Each
case states its expected outcome and asserts it:

- ``rejected``: the bad samples are dropped and counted under a named counter, and the
  estimate stays right (2 and 4 Hz within 2 %);
- ``degraded``: the estimate says so itself (``health`` DEGRADED or FAULT with a reason; a
  FAULT never reports ``converged``), while the fault lasts;
- ``handled``: the data change is absorbed (mapped, adopted, bounded) and identification goes
  on (2 and 4 Hz within 2 % at the end).

A silent wrong output (health OK, converged, wrong modes) fails every case. The node-level
classes (dead worker, backlog, signals, parameter files) are in the DDS tests of
``src/sysid_node/test``. ``test_fault_counts`` prints the tally for the note.
"""

from __future__ import annotations

import tracemalloc

import numpy as np
import pytest
from sysid_node.pipeline import Pipeline
from sysid_node.scenarios import faults as F
from sysid_node.scenarios.paper import paper_example_data

FS = 100.0
T0 = 1_700_000_000 * 10**9
NAMES = ("wing_l", "wing_r", "fuselage")
TALLY: dict[str, list[str]] = {}


@pytest.fixture(scope="module")
def clean() -> tuple[F.Stream, F.Stream]:
    t, u, y = paper_example_data(duration_s=14.0, fs=FS, seed=4)
    rng = np.random.default_rng(4)
    y3 = y[:, :1] @ np.array([[1.0, 0.6, -0.8]]) + 0.02 * np.std(y) * rng.standard_normal(
        (len(y), 3))
    out = F.Stream.uniform(y3, FS, T0, NAMES)
    inp = F.Stream.uniform(u, FS, T0, ("force",))
    return out, inp


def run(out: F.Stream | list[F.Stream], inp: F.Stream | list[F.Stream] | None,
        block: int = 10, **values) -> tuple[Pipeline, list]:
    """Feed the streams in arrival order (blocks of ``block`` samples) and step."""
    pl = Pipeline({"sample_rate": FS, "realization_rate": 10.0, "publish_rate": 5.0,
                   "residual_spectrum_rate": 0.0, **values})
    outs = out if isinstance(out, list) else [out]
    inps = inp if isinstance(inp, list) else ([inp] if inp is not None else [])
    records = []
    for o, i in zip(outs, inps or [None] * len(outs), strict=True):
        for a in range(0, len(o), block):
            pl.push_output(o.stamps_ns[a:a + block], o.values[a:a + block], o.names)
            if i is not None and a < len(i):
                pl.push_input(i.stamps_ns[a:a + block], i.values[a:a + block], i.names)
            records += pl.step()
    return pl, records + pl.step(flush=True)


def near(rec, f: float, tol: float = 0.02) -> bool:
    return any(abs(m.frequency_hz - f) <= tol * f and m.status != "lost" for m in rec.modes)


def right(rec) -> bool:
    return near(rec, 2.0) and near(rec, 4.0)


def tally(outcome: str, case: str) -> None:
    TALLY.setdefault(outcome, []).append(case)


def _resend(s: F.Stream, first: int, n: int, after: int) -> F.Stream:
    """Samples ``first .. first + n`` sent again after sample ``after``, half a period off
    their instants (stamps gone backwards, not duplicates)."""
    old_t = s.stamps_ns[first:first + n] + int(0.5e9 / FS)
    t = np.concatenate([s.stamps_ns[:after], old_t, s.stamps_ns[after:]])
    v = np.concatenate([s.values[:after], s.values[first:first + n], s.values[after:]])
    return F.Stream(t, v, s.names)


# ---- rejected and counted ----
REJECTED = {
    "nonfinite_samples": (lambda o, i: (F.nonfinite(o, indices=[300, 301, 900]), i),
                          "output_nonfinite", 3),
    "inf_in_excitation": (lambda o, i: (o, F.nonfinite(i, indices=[500], value=np.inf)),
                          "input_nonfinite", 1),
    "duplicates": (lambda o, i: (F.duplicate(o, [100, 200, 1200]), i), "output_duplicate", 3),
    "future_stamp_1_day": (lambda o, i: (F.future_stamp(o, 600, 86400.0), i),
                           "output_bad_stamp", 1),
    "future_stamp_30_days": (lambda o, i: (F.future_stamp(o, 600, 30 * 86400.0), i),
                             "output_bad_stamp", 1),
    "stale_block_resent": (lambda o, i: (_resend(o, 300, 10, after=800), i), "output_late",
                           10),
}


@pytest.mark.parametrize("case", list(REJECTED))
def test_rejected_and_counted(case, clean):
    make, counter, at_least = REJECTED[case]
    o, i = make(*clean)
    tracemalloc.start()
    try:
        pl, recs = run(o, i)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert pl.counters.get(counter, 0) >= at_least, pl.counters
    assert peak < 200e6, f"{peak / 1e6:.0f} MB allocated"  # bounded by the data, not stamps
    assert right(recs[-1]), [m.frequency_hz for m in recs[-1].modes]
    tally("rejected and counted", case)


# ---- degraded, visibly ----
DEGRADED = {
    "output_stuck": (lambda o, i: (F.stuck(o, 1, 700), i), 2, "stuck"),
    "excitation_dead": (lambda o, i: (o, F.dead(i, 0, 700)), 2, "dead excitation"),
    "output_clipped": (lambda o, i: (F.saturate(o, -0.5 * np.abs(o.values).max(),
                                                0.5 * np.abs(o.values).max()), i), 1, "clipped"),
}


@pytest.mark.parametrize("case", list(DEGRADED))
def test_degraded_visibly(case, clean):
    make, level, word = DEGRADED[case]
    o, i = make(*clean)
    pl, recs = run(o, i)
    late = [r for r in recs if r.stamp_ns >= T0 + 9 * 10**9]
    assert late and all(r.health >= level and word in r.health_reason for r in late), \
        {(r.health, r.health_reason) for r in late}
    assert not any(r.converged for r in late if r.health >= 2)
    # visible within 1 s of data after the fault starts (sample 700 = 7 s)
    first = next(r for r in recs if r.health >= level)
    assert first.stamp_ns <= T0 + 8 * 10**9 or case == "output_clipped", first.stamp_ns
    tally("degraded visibly", case)


def test_fault_clears_when_the_sensor_recovers(clean):
    o, i = clean
    v = o.values.copy()
    v[500:700, 0] = v[500, 0]  # stuck 2 s, then back
    pl, recs = run(F.Stream(o.stamps_ns, v, o.names), i)
    assert any(r.health == 2 for r in recs)
    assert recs[-1].health == 0 and recs[-1].converged and right(recs[-1])
    tally("degraded visibly", "stuck_then_recovered")


# ---- handled: mapped, adopted, bounded ----
def test_channels_reordered_are_mapped_back_by_name(clean):
    o, i = clean
    half = len(o) // 2
    a = F.Stream(o.stamps_ns[:half], o.values[:half], o.names)
    b = F.reorder_channels(F.Stream(o.stamps_ns[half:], o.values[half:], o.names), [2, 0, 1])
    pl, recs = run([a, b], [F.Stream(i.stamps_ns[:half], i.values[:half], i.names),
                            F.Stream(i.stamps_ns[half:], i.values[half:], i.names)])
    _, ref = run(o, i)
    assert pl.counters["output_reordered"] == len(o) - half
    last, want = recs[-1], ref[-1]
    assert last.samples_used == want.samples_used
    for m, n in zip(last.modes, want.modes, strict=True):
        assert m.frequency_hz == pytest.approx(n.frequency_hz, rel=1e-9)
    tally("handled", "channels_reordered")


def test_channels_renamed_are_flagged_then_adopted(clean):
    o, i = clean
    half = len(o) // 2
    a = F.Stream(o.stamps_ns[:half], o.values[:half], o.names)
    b = F.rename_channels(F.Stream(o.stamps_ns[half:], o.values[half:], o.names),
                          {"wing_r": "tail"})
    pl, recs = run([a, b], [F.Stream(i.stamps_ns[:half], i.values[:half], i.names),
                            F.Stream(i.stamps_ns[half:], i.values[half:], i.names)])
    assert pl.counters["output_channel_names_changed"] >= 90
    assert pl.counters["layout_changes"] == 1
    assert right(recs[-1]) and recs[-1].health == 0
    tally("handled", "channels_renamed")


def test_permanent_channel_count_change_adopted(clean):
    o, i = clean
    half = len(o) // 2
    before, after = F.change_channel_count(o, half, 2)
    ib = F.Stream(i.stamps_ns[:half], i.values[:half], i.names)
    ia = F.Stream(i.stamps_ns[half:], i.values[half:], i.names)
    pl, recs = run([before, after], [ib, ia])
    assert pl.counters["layout_changes"] == 1 and pl.counters["output_wrong_channels"] >= 90
    tail = [r for r in recs if r.stamp_ns > after.stamps_ns[0] + 5 * 10**9]
    assert tail and right(tail[-1]), [m.frequency_hz for m in tail[-1].modes]
    assert len(tail[-1].prediction_error_rms_per_channel) == 2
    tally("handled", "channel_count_changed")


def test_forward_clock_jump_is_a_gap(clean):
    o, i = clean
    pl, recs = run(F.stamp_jump(o, 800, 3600.0), F.stamp_jump(i, 800, 3600.0))
    assert pl.counters["gaps"] == 1 and pl.counters.get("output_bad_stamp", 0) == 0
    assert recs[-1].stamp_ns > T0 + 3600 * 10**9 and right(recs[-1])
    tally("handled", "clock_jumped_ahead")


def test_out_of_order_arrivals_reordered(clean):
    o, i = clean
    pl, recs = run(F.out_of_order(o, [250, 640, 1000]), i)
    assert pl.counters["output_out_of_order"] >= 3 and pl.counters.get("output_late", 0) == 0
    assert right(recs[-1])
    tally("handled", "out_of_order")


def test_gap_repaired_or_split(clean):
    o, i = clean
    pl, recs = run(F.gap(o, 400, 2), i)
    assert pl.counters["output_repaired"] >= 2
    pl, recs = run(F.gap(F.gap(o, 900, 150), 400, 2), F.gap(i, 900, 150))
    assert pl.counters["gaps"] == 1 and right(recs[-1])
    # a gap in both streams is a gap, not an input stop (the output's first message after it
    # arrives before the input's): the estimate is kept across it, and so are the mode ids
    before = [r for r in recs if r.stamp_ns < T0 + int(9e9)][-1]
    assert recs[-1].samples_used > before.samples_used
    _same_ids(before, recs[-1])
    tally("handled", "gaps")


def _same_ids(a, b) -> None:
    for f in (2.0, 4.0):
        ids = [{m.id for m in r.modes if abs(m.frequency_hz / f - 1) <= 0.02
                and m.status == "tracked"} for r in (a, b)]
        assert ids[0] & ids[1], (f, ids)


def test_input_stop_and_return_keep_the_modes(clean):
    """The input stops for 1.5 s while the outputs go on: output-only, then input-output again
    (each a new estimator); the tracker keeps the modes, their ids and tracked status (a notch
    bank keyed on them keeps its notches)."""
    o, i = clean
    i = F.gap(i, 900, 150)
    pl = Pipeline({"sample_rate": FS, "realization_rate": 10.0, "publish_rate": 5.0,
                   "residual_spectrum_rate": 0.0})
    recs, k = [], 0
    for a in range(0, len(o), 10):  # the input's samples arrive with the outputs of their time
        pl.push_output(o.stamps_ns[a:a + 10], o.values[a:a + 10], o.names)
        b = int(np.searchsorted(i.stamps_ns, o.stamps_ns[min(a + 9, len(o) - 1)], "right"))
        if b > k:
            pl.push_input(i.stamps_ns[k:b], i.values[k:b], i.names)
            k = b
        recs += pl.step()
    recs += pl.step(flush=True)
    before = [r for r in recs if r.stamp_ns < T0 + int(9e9)][-1]
    assert recs[-1].samples_used < before.samples_used  # a new estimator after the return
    assert right(recs[-1])
    _same_ids(before, recs[-1])


def test_signal_block_with_bad_period_is_an_error_with_a_reason():
    from types import SimpleNamespace

    from sysid_node import msg_convert as mc

    for period in (float("nan"), -0.01):
        msg = SimpleNamespace(header=SimpleNamespace(stamp=SimpleNamespace(sec=1, nanosec=0)),
                              data=[0.0] * 6, channel_count=2, sample_period=period,
                              channel_names=[])
        with pytest.raises(ValueError, match="sample_period"):
            mc.to_arrays(msg, "SignalBlock")
        blocks, errors = mc.burst_to_blocks([msg], "SignalBlock")
        assert not blocks and len(errors) == 1 and "sample_period" in errors[0]
    tally("rejected and counted", "signal_block_bad_period")


def test_freq_max_rechecked_against_the_measured_rate():
    """freq_max is accepted before the rate is known (sample_rate 0); the rate the stamps
    give, at start and again after a clock reset to a lower rate, is checked against it."""
    lines: list[str] = []
    pl = Pipeline({"sample_rate": 0.0, "freq_max": 30.0, "output_only": True,
                   "residual_spectrum_rate": 0.0}, log=lines.append)
    rng = np.random.default_rng(3)

    def feed(t0_ns: int, fs: float, seconds: float) -> None:
        n = int(seconds * fs)
        stamps = t0_ns + np.round(np.arange(n) * 1e9 / fs).astype(np.int64)
        y = rng.standard_normal((n, 1))
        for a in range(0, n, 10):
            pl.push_output(stamps[a:a + 10], y[a:a + 10])
            pl.step()

    feed(T0, 100.0, 3.0)
    assert pl.sample_rate == pytest.approx(100.0, rel=1e-6)
    assert pl.band_warning() == ""
    feed(T0 - 60 * 10**9, 50.0, 3.0)  # the clock went back a minute; the sensor now at 50 Hz
    assert pl.counters["time_resets"] == 1
    assert pl.sample_rate == pytest.approx(50.0, rel=1e-6)
    assert "freq_max=30 Hz is above the Nyquist frequency 25 Hz" in pl.band_warning()
    said = [x for x in lines if x.startswith("WARN ") and "freq_max=30" in x]
    assert len(said) == 1, lines
    tally("handled", "freq_max_above_measured_nyquist")


def test_fault_counts():
    """The tally of the cases above (run with -s to see it)."""
    cases = sum(len(v) for v in TALLY.values())
    print(f"\nfault injection, pure pipeline: {cases} cases, 0 crashes, 0 silent wrong outputs; "
          + "; ".join(f"{k}: {len(v)}" for k, v in sorted(TALLY.items())))
    assert cases == 0 or cases >= 10
