"""Acceptance: the paper's Sec. II example (2 & 4 Hz, a 6 Hz mode appears at t = 20 s, 100 Hz,
wideband input, 5 % output noise, at most five modes in [0, 10] Hz), over 10 noise seeds,
judged on the ModeTracker output (ids and status)."""

from __future__ import annotations

import numpy as np
import pytest
from sysid_node.scenarios.paper import paper_example_systems

_, AFTER = paper_example_systems()
TRUE = AFTER.modes()  # [(f, zeta)] for 2, 4, 6 Hz from the eigen-analysis
TRUE_DAMPING = [
    0.5 / (2 * np.sqrt(157.91)),
    2.51 / (2 * np.sqrt(631.65)),
    3.76 / (2 * np.sqrt(1420)),
]
SEEDS = range(10)


def _find(tracks, f_true, tol=0.02, statuses=("tracked",)):
    hits = [t for t in tracks if t[1] in statuses and abs(t[2] / f_true - 1) <= tol]
    return min(hits, key=lambda t: abs(t[2] - f_true)) if hits else None


def test_true_damping_matches_paper_matrices():
    assert np.allclose([z for _, z in TRUE], TRUE_DAMPING, rtol=1e-6)


@pytest.mark.slow
@pytest.mark.parametrize("seed", SEEDS)
def test_two_and_four_hz_within_2_percent_from_2_s(seed_example_runs, seed):
    recs = [(t, tr) for t, tr in seed_example_runs[seed] if 2.0 <= t < 20.0]
    assert len(recs) > 150
    bad = [t for t, tr in recs if not (_find(tr, TRUE[0][0]) and _find(tr, TRUE[1][0]))]
    assert not bad, f"2/4 Hz not both tracked within 2 % at t = {bad[:5]}"


@pytest.mark.slow
@pytest.mark.parametrize("seed", SEEDS)
def test_six_hz_reported_within_1_5_s_without_losing_the_others(seed_example_runs, seed):
    recs = seed_example_runs[seed]
    before = [tr for t, tr in recs if t <= 20.0][-1]
    ids = [_find(before, TRUE[k][0])[0] for k in (0, 1)]
    t_six = next((t for t, tr in recs if t > 20.0 and _find(tr, TRUE[2][0])), np.inf)
    assert t_six - 20.0 <= 1.5, f"6 Hz tracked only at t = {t_six}"
    for t, tr in recs:
        if 20.0 < t <= 21.5:
            status = {i: s for i, s, _, _ in tr}
            assert all(status.get(i) == "tracked" for i in ids), f"2/4 Hz track lost at {t}"
    # the same ids still hold the 2 and 4 Hz modes once the 6 Hz mode is in (within the
    # tracker's 5 % gate: the windows that straddle the change still perturb them at 21.5 s;
    # the 2 % accuracy after the change is checked from 30 s on, below)
    after = [tr for t, tr in recs if t >= 21.5][0]
    held = [_find(after, TRUE[k][0], tol=0.05) for k in (0, 1)]
    assert all(held) and [h[0] for h in held] == ids, (ids, after)


@pytest.mark.slow
def test_after_30_s_95_percent_of_estimates_within_tolerances(seed_example_runs):
    fractions = []
    for seed in SEEDS:
        recs = [tr for t, tr in seed_example_runs[seed] if t >= 30.0]
        ok = []
        for tr in recs:
            good = True
            for f, zeta in TRUE:
                hit = _find(tr, f)
                good &= hit is not None and abs(hit[3] / zeta - 1) <= 0.30
            ok.append(good)
        fractions.append(np.mean(ok))
    assert min(fractions) >= 0.95, f"per-seed fractions {np.round(fractions, 3)}"
