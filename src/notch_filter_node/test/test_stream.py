"""Stream checks of the node (pure): stamp order, the rate the stamps measure (robust to lost
messages and jitter, quick on a real change), the channel-layout rule, event throttling."""

import numpy as np
import pytest

from notch_filter_node import stream as ST


def feed(check, stamps_ns, samples=1):
    out = []
    for s in stamps_ns:
        v = check.check(int(s))
        out.append(v)
        if v in (ST.OK, ST.RESTART):
            if v == ST.RESTART:
                check.restart()
            check.accept(int(s), samples)
    return out


def test_duplicates_out_of_order_and_restart():
    c = ST.StampCheck()
    assert feed(c, [10, 20, 20, 15, 30, 3_000_000_000]) == [
        ST.OK, ST.OK, ST.DUPLICATE, ST.OUT_OF_ORDER, ST.OK, ST.OK]
    assert c.check(30) == ST.RESTART  # more than 1 s back


@pytest.mark.parametrize("fs", [100.0, 200.0, 1000.0, 37.5])
@pytest.mark.parametrize("block", [1, 10])
def test_rate_robust_to_lost_messages_and_jitter(fs, block):
    rng = np.random.default_rng(int(fs) + block)
    n = 400
    first = np.arange(n) * block / fs
    keep = rng.random(n) > 0.5  # half the messages lost, in random runs
    jitter = rng.normal(0.0, 0.02 / fs, n)  # stamps jitter by 2 % of a period
    c = ST.StampCheck()
    feed(c, np.round((first + jitter)[keep] * 1e9).astype(np.int64), block)
    assert c.rate() == pytest.approx(fs, rel=0.01)


@pytest.mark.parametrize("lost", [0.7, 0.85, 0.9])
@pytest.mark.parametrize("fs", [100.0, 400.0])
def test_rate_holds_when_most_messages_are_lost(fs, lost):
    """A busy receiver loses runs of messages (most of the window): the intervals are then
    mostly multiples of the period, and the period is still the period (a bank re-designed at
    half the rate would put every notch at twice its frequency)."""
    rng = np.random.default_rng(int(fs * lost))
    n = 2000
    keep = rng.random(n) > lost
    keep[rng.integers(0, n - 300):][:300] &= rng.random(300) > 0.5  # a worse stretch
    c = ST.StampCheck()
    stamps = np.round((np.arange(n) / fs + rng.normal(0.0, 0.02 / fs, n)) * 1e9)
    rates = []
    for s in stamps[keep].astype(np.int64):
        feed(c, [s])
        rates.append(c.rate())
    rates = np.asarray(rates)
    rates = rates[np.isfinite(rates)]
    assert rates.size > 0
    assert np.all(np.abs(rates / fs - 1.0) < 0.02)


def test_rate_change_is_seen_within_a_fifth_of_the_window():
    c = ST.StampCheck()
    t100 = np.arange(100) / 100.0
    feed(c, np.round(t100 * 1e9).astype(np.int64))
    assert c.rate() == pytest.approx(100.0)
    t200 = t100[-1] + np.arange(1, 200) / 200.0
    seen = None
    for k, t in enumerate(t200):
        feed(c, [int(round(t * 1e9))])
        if seen is None and abs(c.rate() - 200.0) < 2.0:
            seen = k + 1
    assert seen is not None and seen <= c.window // 5 + ST.RECOMPUTE


def test_layout_reorder_maps_by_name_new_layout_needs_confirmation():
    lt = ST.LayoutTracker(confirm=3)
    m = lt.observe(["a", "b", "c"], 3)
    assert m.event == "adopted"
    m = lt.observe(["c", "a", "b"], 3)
    assert m.event == "reordered" and list(m.index) == [2, 0, 1]
    m = lt.observe(["a", "b", "c", "d"], 4)  # one more channel: pending twice, then adopted
    assert m.event == "pending" and list(m.index) == [0, 1, 2, -1] and m.unknown == ["d"]
    assert lt.observe(["a", "b", "c", "d"], 4).event == "pending"
    m = lt.observe(["a", "b", "c", "d"], 4)
    assert m.event == "adopted" and list(m.kept) == [0, 1, 2, -1]
    assert lt.observe(["a", "b", "c", "d"], 4).event == ""


def test_flapping_layout_never_adopted_unnamed_by_position():
    lt = ST.LayoutTracker(confirm=2)
    lt.observe([], 3)
    for _ in range(10):
        assert lt.observe([], 2).event == "pending"
        assert lt.observe([], 3).event == ""
    m = lt.observe([], 2)
    assert list(m.index) == [0, 1]
    m = lt.observe(["x", "y"], 2)  # names now: not the same layout as unnamed
    assert m.event == "pending" and list(m.index) == [0, 1]


def test_event_log_throttles_and_summarises_and_forgets():
    ev = ST.EventLog(period=5.0, recent=10.0)
    lines = [ev.add("duplicate", "dup", t) for t in np.arange(0.0, 4.0, 0.01)]
    assert lines[0] == "dup" and all(line is None for line in lines[1:])
    assert ev.due(4.5) == []
    (summary,) = ev.due(5.5)
    assert "399 more 'duplicate'" in summary and "400 in total" in summary
    assert ev.add("duplicate", "dup", 6.0) is None  # within 5 s of the summary
    assert ev.add("duplicate", "dup", 11.0) == "dup (and 1 more since the last report)"
    assert ev.recent(15.5) == {"duplicate": 2}  # 6.0 and 11.0 within 10 s
    assert ev.recent(30.0) == {} and ev.counts["duplicate"] == 402
