"""Randomized identification suite (issue #10) with DEFAULT parameters: a subset of the draws of
``benchmarks/random_suite.py``, which runs 50+ of them and prints the table and the aggregate
rates (definitions in ``sysid_node/suite.py``).

Asserted here on every estimate of the subset: the ``max_modes`` contract (never more
``tracked`` modes than ``max_modes``) and the searched band reported. On the easy draws
(input-output, at most two modes) every true mode is tracked within 2 % by 3 s of data and the
estimates stay right. Issue #10's aggregate targets (>= 90 % found, <= 0.5 false per
estimate, never more than 2, >= 95 % right after a change) are asserted on the benchmark's
first draws, a strict xfail while the defaults miss them (the benchmark measures all 52)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from sysid_node.records import EstimateRecord, ModeRecord
from sysid_node.scenarios import draw_modal_scenario
from sysid_node.suite import T0_NS, run_pipeline, score

from sysid_node import params as P

#: The first draws of the benchmark's table that are input-output with at most two modes
#: (seed 2: one mode at 183 Hz; seed 3: two modes at 122 Hz, one appearing at 40-60 %).
SEEDS = (2, 3)
DURATION_S = 30.0


def _record(t_s: float, freqs: list[float]) -> EstimateRecord:
    modes = [ModeRecord(id=i, status="tracked", frequency_hz=f, frequency_std_hz=0.0,
                        damping_ratio=0.01, damping_std=0.0, amplitude=1.0, age_s=1.0,
                        shape=np.ones(1)) for i, f in enumerate(freqs)]
    return EstimateRecord(stamp_ns=T0_NS + int(t_s * 1e9), modes=modes, model_order=10,
                          block_rows=10, forgetting_factor=0.99, sample_rate=100.0,
                          prediction_error_rms_per_channel=np.zeros(1), converged=True,
                          samples_used=1)


def test_kept_share_counts_the_modes_that_did_not_change_from_the_change_on():
    """Seed 8: two modes, one jumping 10.3 -> 11.1 Hz at 15.9 s. Estimates that keep the other
    mode but have not found the jumped one count as kept (not as all right); estimates that
    lose the other mode do not."""
    scn = draw_modal_scenario(np.random.default_rng(8), duration_s=DURATION_S)
    ch = scn.change
    assert ch["kind"] == "jump"
    other = [f for f, _ in scn.modes_at(0.0) if abs(f - ch["from_hz"]) > 1e-9]
    times = np.arange(1.0, DURATION_S, 0.1)
    recs = []
    for tk in times:
        truth = [f for f, _ in scn.modes_at(tk)]
        if tk < ch["time_s"]:
            recs.append(_record(tk, truth))
        elif tk < ch["time_s"] + 6.0:  # the jumped mode not yet found, the other kept
            recs.append(_record(tk, other))
        elif tk < ch["time_s"] + 10.0:  # the other mode lost, the new one found
            recs.append(_record(tk, [ch["to_hz"]]))
        else:
            recs.append(_record(tk, truth))
    res = score(scn, recs, 8)
    since = times >= ch["time_s"]
    lost = since & (times >= ch["time_s"] + 6.0) & (times < ch["time_s"] + 10.0)
    assert res.kept_share == pytest.approx(1 - lost.sum() / since.sum())
    late = times >= ch["time_s"] + 5.0
    assert res.after_share == pytest.approx(
        ((times >= ch["time_s"] + 10.0) & late).sum() / late.sum())


@pytest.fixture(scope="module")
def runs():
    out = []
    for seed in SEEDS:
        scn = draw_modal_scenario(np.random.default_rng(seed), duration_s=DURATION_S)
        recs = run_pipeline(scn)
        out.append((scn, recs, score(scn, recs, seed)))
    return out


@pytest.mark.slow
def test_max_modes_is_a_contract_and_the_band_is_reported(runs):
    limit = P.defaults()["max_modes"]
    for scn, recs, _ in runs:
        assert len(recs) >= 10 * DURATION_S - 2
        for r in recs:
            tracked = [m.frequency_hz for m in r.modes if m.status == "tracked"]
            assert len(tracked) <= limit, (scn.fs, r.stamp_ns, tracked)
            if r.model_order > 0:
                assert math.isfinite(r.band_min_hz) and r.band_max_hz > r.band_min_hz


@pytest.mark.slow
def test_easy_draws_found_by_3_s_and_kept(runs):
    for scn, _, res in runs:
        assert not scn.output_only and res.n_modes <= 2
        assert res.found_by_3s and res.settled_share >= 0.9, res
        if res.change != "none":
            assert res.pickup_s <= 3.0 and res.after_share >= 0.9, res


#: Draws with a record-long Schroeder multisine input, a sweep within its period (the suite's
#: draws until 2026-11-28, when its multisine got random phases; seed 38: three modes at
#: 306 Hz, one appearing; seed 42: six modes at 594 Hz): modes the sweep has left are held, not
#: lost (core.tracking, pipeline.EXCITATION_DB). Before the hold, seed 38's share right after
#: its change was 0.13 and seed 42's settled share 0.39.
SWEPT_SEEDS = (38, 42)
SWEPT_KINDS = ("white", "coloured", "multisine")


@pytest.mark.slow
@pytest.mark.parametrize("seed", SWEPT_SEEDS)
def test_modes_a_sweep_has_left_stay_tracked(seed):
    scn = draw_modal_scenario(np.random.default_rng(seed), duration_s=DURATION_S,
                              excitations=SWEPT_KINDS)
    assert scn.excitation == "multisine" and not scn.output_only
    res = score(scn, run_pipeline(scn), seed)
    assert res.settled_share >= 0.9, res
    if res.change != "none":
        assert res.after_share >= 0.9, res


#: The first draws of the benchmark's table (all kinds: output-only, up to 8 modes, changes).
TARGET_SEEDS = range(8)


@pytest.mark.slow
@pytest.mark.xfail(strict=True, reason=(
    "issue #10 targets not met by the defaults: benchmarks/random_suite.py --draws 26 "
    "--first-seed 0 and 26 (52 draws, defaults) gives every mode within 2 % by 3 s in 71.2 % "
    "of draws (target 90 %; input-output 96 %, output-only 48 %: what a prediction-error fit "
    "of the true-order model from the truth reaches on the same data, 48-52 %; the bounds "
    "suite.ambient_ceiling 81 %, ambient_realistic 71 %), false tracked per estimate mean "
    "0.098 / max 2 (round 37, by replay of the recorded tracker inputs) "
    "(target 0.5 / 2: met), after a change 79.1 % and unchanged modes kept 85.5 % (target "
    "95 %), settled 88.9 %"))
def test_issue_10_targets_on_the_first_draws():
    from sysid_node.suite import run_draw, summary

    s = summary([run_draw(seed, duration_s=DURATION_S) for seed in TARGET_SEEDS])
    assert s["found_2pct_by_3s"] >= 0.9, s
    assert s["false_per_estimate_mean"] <= 0.5 and s["false_per_estimate_max"] <= 2, s
    assert not s["changes"] or s["after_change_share"] >= 0.95, s
    assert not s["changes"] or s["unchanged_kept_share"] >= 0.95, s


#: Seed 35: input-output, 218 Hz, two outputs, modes at 2.0 Hz (3.7 % damped), 3.7, 7.7, 18,
#: 26 and 81 Hz, one appearing at 2.9 Hz at 16.5 s. The first band choice (4 s of data, 1.7 Hz
#: bins) sees no structure rising below 6 Hz (the outputs' response is flat below the 2 Hz
#: mode, well above the floor) and sizes the window for 6 Hz: 23 block rows, a tenth of the
#: 2 Hz period; the two low modes then dissolved into a 2.4 Hz smear with 12 % damping for the
#: rest of the run (settled share 0.00, after the change 0.00).
LOW_SEED = 35


@pytest.mark.slow
def test_a_lowest_peak_the_first_band_choice_missed_moves_the_window_down():
    scn = draw_modal_scenario(np.random.default_rng(LOW_SEED), duration_s=DURATION_S)
    assert not scn.output_only and min(f for f, _ in scn.modes_at(0.0)) < 2.1
    logs: list[str] = []
    res = score(scn, run_pipeline(scn, log=logs.append), LOW_SEED)
    assert any("lowest peak moved down" in m for m in logs), logs
    assert res.settled_share >= 0.9 and res.after_share >= 0.9, res
    assert res.false_max <= 1, res



#: Seed 26: output-only from one output, 310 Hz, modes at 4.13 Hz (2.7 % damped), 5.78 (1.2 %),
#: 8.2, 16.2 and 106 Hz. A window of half the lowest peak's period (86 block rows, 0.28 s)
#: left the 5.78 Hz mode out of the realizations until 10 s and again from 21 s (the 4.13 Hz
#: mode absorbed it at 5-6 % damping): settled share 0.17. One output has no mode shapes to
#: tell neighbours apart: its window spans a full period (params.window_periods).
ONE_OUTPUT_SEED = 26


@pytest.mark.slow
def test_one_output_output_only_neighbouring_low_modes_stay_apart():
    scn = draw_modal_scenario(np.random.default_rng(ONE_OUTPUT_SEED), duration_s=DURATION_S)
    assert scn.output_only and scn.y.shape[1] == 1
    res = score(scn, run_pipeline(scn), ONE_OUTPUT_SEED)
    assert res.found_by_3s and res.settled_share >= 0.9, res
    assert res.false_max <= 1, res


#: Seed 25: output-only from one output, 145 Hz, seven modes; the 0.2 %-damped 43.83 Hz one is
#: within 0.5 % in 69 of the first 83 realizations but below the overfit level (spurious test 3)
#: in 55 of them, and was tracked only at 3.6 s (found by 3 s: False). Test 3 is lifted for
#: pole pairs that persist while the estimator's memory fills (core.spurious.Persistence).
PERSIST_SEED = 25


@pytest.mark.slow
def test_a_persistent_mode_below_the_overfit_level_is_found_by_3_s():
    scn = draw_modal_scenario(np.random.default_rng(PERSIST_SEED), duration_s=DURATION_S)
    assert scn.output_only
    res = score(scn, run_pipeline(scn), PERSIST_SEED)
    assert res.found_by_3s, res
    assert res.false_max <= 1, res
