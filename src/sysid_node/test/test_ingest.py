"""Unit tests of the stamp alignment (ingest.py): one test per kind of bad input."""

from __future__ import annotations

import numpy as np
import pytest
from sysid_node.ingest import Ingest

T0 = 1_700_000_000 * 10**9
FS = 100.0
DT = int(1e9 / FS)


def _data(n: int, ny: int = 2, seed: int = 0):
    rng = np.random.default_rng(seed)
    t = T0 + np.arange(n, dtype=np.int64) * DT
    return t, rng.standard_normal((n, ny)), rng.standard_normal((n, 1))


def _run(ing: Ingest, t, y, u=None, block: int = 10, tu=None, flush: bool = True):
    chunks = []
    tu = t if tu is None else tu
    for a in range(0, len(t), block):
        ing.push_output(t[a : a + block], y[a : a + block])
        if u is not None:
            ing.push_input(tu[a : a + block], u[a : a + block])
        chunks += ing.pop()
    chunks += ing.pop(flush=flush)
    return chunks


def _cat(chunks, attr="y"):
    return np.concatenate([getattr(c, attr) for c in chunks])


def test_clean_stream_passes_unchanged_and_rate_is_measured():
    t, y, u = _data(400)
    ing = Ingest()
    chunks = _run(ing, t, y, u)
    assert ing.fs == pytest.approx(FS, rel=1e-9)
    assert ing.mode == "io"
    np.testing.assert_array_equal(_cat(chunks), y)
    np.testing.assert_array_equal(_cat(chunks, "u"), u)
    np.testing.assert_array_equal(_cat(chunks, "stamps_ns"), t)
    assert chunks[0].new_segment and not any(c.new_segment for c in chunks[1:])
    bad = {k: v for k, v in ing.counters.items() if not k.endswith(("received", "accepted"))}
    assert bad == {}


@pytest.mark.parametrize("lost", [0.0, 0.6, 0.85])
def test_rate_measured_when_most_samples_are_lost(lost):
    """Lost messages make most stamp intervals 2, 3, ... periods (a busy receiver): the rate is
    still the sensor's (their median would say half of it)."""
    rng = np.random.default_rng(int(lost * 100))
    t, y, _ = _data(2000, ny=1)
    keep = rng.random(len(t)) >= lost
    keep[:2] = True
    ing = Ingest(use_input=False)
    _run(ing, t[keep], y[keep])
    assert ing.fs == pytest.approx(FS, rel=1e-6)


def test_inputs_aligned_by_stamp_not_arrival():
    t, y, u = _data(300)
    ing = Ingest(sample_rate=FS)
    # input arrives 7 samples later than the output and in a different block size
    chunks = []
    for a in range(0, 300, 10):
        ing.push_output(t[a : a + 10], y[a : a + 10])
        if a >= 70:
            b = a - 70
            ing.push_input(t[b : b + 10], u[b : b + 10])
        chunks += ing.pop()
    ing.push_input(t[230:], u[230:])
    chunks += ing.pop(flush=True)
    np.testing.assert_array_equal(_cat(chunks, "u"), u)
    np.testing.assert_array_equal(_cat(chunks), y)


def test_out_of_order_messages_are_reordered():
    t, y, u = _data(200)
    order = np.arange(200).reshape(-1, 5)
    order[[3, 4]] = order[[4, 3]]  # two message blocks swapped in arrival
    order = order.reshape(-1)
    ing = Ingest(sample_rate=FS, use_input=False, reorder_window=0.1)
    chunks = _run(ing, t[order], y[order], block=5)
    np.testing.assert_array_equal(_cat(chunks), y)
    assert ing.counters["output_out_of_order"] == 5
    assert ing.counters["output_late"] == 0


def test_stamps_going_backwards_are_dropped_as_late():
    t, y, _ = _data(300)
    ing = Ingest(sample_rate=FS, use_input=False)
    chunks = _run(ing, t[:200], y[:200])
    ing.push_output(t[100:110][::-1], y[100:110][::-1])  # ten old stamps, descending
    chunks += ing.pop()
    chunks += _run(ing, t[200:], y[200:])
    np.testing.assert_array_equal(_cat(chunks), y)
    assert ing.counters["output_out_of_order"] >= 9
    assert ing.counters["output_late"] + ing.counters["output_duplicate"] == 10
    assert any("backwards" in e or "duplicate" in e for e in ing.events)


def test_duplicates_dropped_and_counted():
    t, y, _ = _data(200)
    td = np.insert(t, [51, 121], t[[50, 120]])  # repeated after the original
    yd = np.insert(y, [51, 121], y[[50, 120]] + 1.0, axis=0)
    ing = Ingest(sample_rate=FS, use_input=False)
    chunks = _run(ing, td, yd)
    assert ing.counters["output_duplicate"] == 2
    np.testing.assert_array_equal(_cat(chunks), y)


def test_wrong_channel_count_dropped_and_counted():
    t, y, _ = _data(200, ny=3)
    ing = Ingest(sample_rate=FS, use_input=False, gap_fill_max_samples=0)
    chunks = []
    for a in range(0, 200, 10):
        yy = y[a : a + 10]
        if a == 100:
            yy = yy[:, :2]
        ing.push_output(t[a : a + 10], yy)
        chunks += ing.pop()
    chunks += ing.pop(flush=True)
    assert ing.counters["output_wrong_channels"] == 10
    assert ing.counters["gaps"] == 1 and ing.counters["gap_samples"] == 10
    assert len(chunks) >= 2 and any(c.new_segment for c in chunks[1:])
    assert all(c.y.shape[1] == 3 for c in chunks)
    assert any("expected 3" in e for e in ing.events)


def test_configured_channel_count_rejects_first_message_with_other_count():
    t, y, _ = _data(50, ny=2)
    ing = Ingest(sample_rate=FS, use_input=False, output_channels=6)
    assert _run(ing, t, y) == []
    assert ing.counters["output_wrong_channels"] == 50


def test_nan_sample_dropped_and_hole_repaired():
    t, y, _ = _data(200)
    y_bad = y.copy()
    y_bad[77, 1] = np.nan
    y_bad[140, 0] = np.inf
    ing = Ingest(sample_rate=FS, use_input=False)
    chunks = _run(ing, t, y_bad)
    out = _cat(chunks)
    assert len(out) == 200 and np.isfinite(out).all()
    assert ing.counters["output_nonfinite"] == 2
    assert ing.counters["output_repaired"] == 2
    assert ing.counters.get("gaps", 0) == 0
    np.testing.assert_allclose(out[77], (y[76] + y[78]) / 2)
    keep = np.setdiff1d(np.arange(200), [77, 140])
    np.testing.assert_array_equal(out[keep], y[keep])
    assert any("NaN/Inf" in e for e in ing.events)


def test_late_block_in_the_same_burst_as_the_next_samples_is_no_jump():
    """A burst (the node's reader decodes several messages as one array) holding a block
    stamped 2.5 s back (half a period off the grid) and the stream's next samples: only the
    old block is dropped; the next samples are not mistaken for a forward clock jump (they
    were held, then dropped as bad stamps: good data lost and a gap counted; seen in
    sysid_node's DDS test)."""
    t, y, u = _data(800, ny=1)
    ing = Ingest(sample_rate=FS, use_input=True)
    chunks = _run(ing, t[:300], y[:300], u[:300], flush=False)
    old = np.arange(50, 60)
    burst = np.r_[old, 300:330]
    ing.push_output(t[300:330], y[300:330])
    ing.push_input(t[burst] + np.isin(burst, old) * (DT // 2), u[burst])
    chunks += ing.pop()
    chunks += _run(ing, t[330:], y[330:], u[330:])
    np.testing.assert_array_equal(_cat(chunks), y)
    np.testing.assert_array_equal(_cat(chunks, "u"), u)
    assert ing.counters["input_late"] == 10
    assert not ing.counters["input_bad_stamp"] and not ing.counters["gaps"]


def test_gap_whose_first_samples_share_a_burst_with_the_last_ones_loses_nothing():
    """A burst holding the stream's last 0.6 s before a 2 s gap and the first 0.4 s after it:
    the post-gap samples are held as a possible clock jump, and the stream's data in the same
    burst does not count as "the stream moved on without them" (they were dropped as bad
    stamps: 40 good samples lost, seen in sysid_node's DDS test)."""
    t, y, u = _data(1200, ny=1)
    keep = np.r_[0:800, 1000:1200]
    ing = Ingest(sample_rate=FS, use_input=True)
    chunks = _run(ing, t[:740], y[:740], u[:740], flush=False)
    burst = np.r_[740:800, 1000:1040]
    ing.push_output(t[740:800], y[740:800])
    ing.push_input(t[burst], u[burst])
    chunks += ing.pop()
    rest = keep[keep >= 1000]
    chunks += _run(ing, t[rest], y[rest], u[rest], tu=t[rest])
    assert not ing.counters["input_bad_stamp"] and not ing.counters["output_bad_stamp"]
    assert ing.counters["gaps"] == 1 and ing.counters["gap_samples"] == 200
    np.testing.assert_array_equal(_cat(chunks), y[keep])
    np.testing.assert_array_equal(_cat(chunks, "u"), u[keep])


def test_two_second_gap_splits_data_and_is_counted():
    t, y, _ = _data(800)
    keep = np.r_[0:300, 500:800]
    ing = Ingest(sample_rate=FS, use_input=False)
    chunks = _run(ing, t[keep], y[keep])
    assert ing.counters["gaps"] == 1
    assert ing.counters["gap_samples"] == 200
    segs = [c for c in chunks if c.new_segment]
    assert len(segs) == 2
    assert segs[1].stamps_ns[0] == t[500]
    np.testing.assert_array_equal(_cat(chunks), y[keep])  # no good sample lost
    assert any("gap of 2.000 s" in e for e in ing.events)


def test_rate_mismatch_resampled_or_rejected():
    n = 400
    t2 = T0 + np.arange(n, dtype=np.int64) * (DT // 2)  # a 200 Hz stream
    y = np.sin(2 * np.pi * 1.0 * np.arange(n) / 200.0)[:, None]
    ing = Ingest(sample_rate=FS, use_input=False, rate_mismatch="resample")
    chunks = _run(ing, t2, y)
    out = _cat(chunks)
    stamps = (_cat(chunks, "stamps_ns") - T0) * 1e-9
    assert np.allclose(np.diff(stamps), 0.01)
    np.testing.assert_allclose(out[:, 0], np.sin(2 * np.pi * stamps), atol=1e-3)
    assert any("resampled onto the 100 Hz grid" in e for e in ing.events)

    ing = Ingest(sample_rate=FS, use_input=False, rate_mismatch="reject")
    chunks = _run(ing, t2, y)
    assert sum(len(c) for c in chunks) < 30  # only what came before the rate was measured
    assert ing.counters["output_rate_rejected"] > 0
    assert any("rejected" in e for e in ing.events)


def test_slower_input_stream_resampled_onto_output_grid():
    t, y, _ = _data(400)
    tu = T0 + np.arange(200, dtype=np.int64) * 2 * DT  # 50 Hz excitation
    u = np.linspace(0.0, 1.0, 200)[:, None]
    ing = Ingest(sample_rate=FS)
    chunks = []
    for a in range(0, 400, 20):
        ing.push_output(t[a : a + 20], y[a : a + 20])
        ing.push_input(tu[a // 2 : a // 2 + 10], u[a // 2 : a // 2 + 10])
        chunks += ing.pop()
    chunks += ing.pop(flush=True)
    uu = _cat(chunks, "u")[:, 0]
    assert len(uu) >= 390
    np.testing.assert_allclose(np.diff(uu), 1.0 / 199 / 2, rtol=1e-6)
    assert ing.counters["input_resampled"] > 0


def test_no_input_means_output_only():
    t, y, _ = _data(300)
    ing = Ingest(sample_rate=FS, use_input=True)
    chunks = _run(ing, t, y)
    assert ing.mode == "output_only"
    assert all(c.u is None for c in chunks)
    np.testing.assert_array_equal(_cat(chunks), y)


def _late_input(ing: Ingest, t, y, u, lag: int, wall_per_block: float, now: list) -> list:
    """Output blocks of 10 with the input ``lag`` samples behind in transport (a busy node, a
    fast replay), the live clock advancing ``wall_per_block`` s per block."""
    chunks = []
    for a in range(0, len(t) + lag, 10):
        if a < len(t):
            ing.push_output(t[a : a + 10], y[a : a + 10])
        if a >= lag:
            ing.push_input(t[a - lag : a - lag + 10], u[a - lag : a - lag + 10])
        chunks += ing.pop()
        now[0] += wall_per_block
    return chunks + ing.pop(flush=True)


def test_live_input_late_in_transport_is_waited_for_not_dropped():
    # 2 s of data behind (beyond INPUT_WAIT) but only 0.4 s of wall-clock time, as in a 5x replay
    t, y, u = _data(1000, ny=1)
    now = [0.0]
    live = Ingest(sample_rate=FS, use_input=True, clock=lambda: now[0])
    chunks = _late_input(live, t, y, u, lag=200, wall_per_block=0.02, now=now)
    assert live.mode == "io" and live.counters.get("input_late", 0) == 0
    assert all(c.u is not None for c in chunks)
    np.testing.assert_array_equal(_cat(chunks, "u"), u)
    # offline (no clock) judges by data time alone: output-only first, the late input dropped
    off = Ingest(sample_rate=FS, use_input=True)
    chunks = _late_input(off, t, y, u, lag=200, wall_per_block=0.02, now=[0.0])
    assert any(c.u is None for c in chunks) and off.counters["input_late"] > 0
    # live, a silent input (more than INPUT_WAIT of wall-clock time) is still given up
    now = [0.0]
    slow = Ingest(sample_rate=FS, use_input=True, clock=lambda: now[0])
    chunks = _late_input(slow, t, y, u, lag=200, wall_per_block=0.1, now=now)
    assert any(c.u is None for c in chunks)


def test_live_stall_drained_output_first_keeps_the_input():
    # real time, then the process stalls 1.2 s (nothing arrives), then the queued samples are
    # drained, the output's 1.5 s first and the input's right after: still input-output, no
    # input sample dropped (the demo's node logged "input stream stopped" and dropped 100)
    t, y, u = _data(600, ny=1)
    now = [0.0]
    ing = Ingest(sample_rate=FS, use_input=True, clock=lambda: now[0])
    chunks = []
    for a in range(0, 300, 10):
        ing.push_output(t[a:a + 10], y[a:a + 10])
        ing.push_input(t[a:a + 10], u[a:a + 10])
        chunks += ing.pop()
        now[0] += 0.1
    now[0] += 1.2
    for a in range(300, 450, 10):
        ing.push_output(t[a:a + 10], y[a:a + 10])
        chunks += ing.pop()
        now[0] += 0.001
    for a in range(300, 450, 10):
        ing.push_input(t[a:a + 10], u[a:a + 10])
        chunks += ing.pop()
    assert ing.mode == "io" and ing.counters.get("input_late", 0) == 0, ing.events
    chunks += ing.pop(flush=True)
    np.testing.assert_array_equal(_cat(chunks, "u"), u[:450])


def test_clock_jumping_back_starts_a_new_time_line():
    t, y, _ = _data(600)
    ing = Ingest(sample_rate=FS, use_input=False)
    chunks = _run(ing, t[:300], y[:300], flush=False)
    chunks += _run(ing, t[:300] - 0, y[300:], flush=True)  # same stamps again, new data
    assert ing.counters["time_resets"] == 1
    assert any(c.reset for c in chunks)
    assert sum(len(c) for c in chunks) >= 590
