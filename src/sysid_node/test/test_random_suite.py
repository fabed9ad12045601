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
from sysid_node.scenarios import draw_modal_scenario
from sysid_node.suite import run_pipeline, score

from sysid_node import params as P

#: The first draws of the benchmark's table that are input-output with at most two modes
#: (seed 2: one mode at 183 Hz; seed 3: two modes at 122 Hz, one appearing at 40-60 %).
SEEDS = (2, 3)
DURATION_S = 30.0


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
    "--first-seed 0 and 26 (52 draws, defaults) on 2026-11-28's code gives every mode within "
    "2 % by 3 s in 57.7 % of draws (target 90 %; input-output 84 %, output-only 33 %), false "
    "tracked per estimate mean 0.22 / max 3 (target 0.5 / 2; the 3 in output-only draws), "
    "after a change 72.8 % (target 95 %), settled 83.6 %"))
def test_issue_10_targets_on_the_first_draws():
    from sysid_node.suite import run_draw, summary

    s = summary([run_draw(seed, duration_s=DURATION_S) for seed in TARGET_SEEDS])
    assert s["found_2pct_by_3s"] >= 0.9, s
    assert s["false_per_estimate_mean"] <= 0.5 and s["false_per_estimate_max"] <= 2, s
    assert not s["changes"] or s["after_change_share"] >= 0.95, s
