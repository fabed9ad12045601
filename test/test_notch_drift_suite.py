"""Issue #12 on drifting modes the project did not pick: benchmarks/notch_drift_suite.py draws
eight seeded drift scenarios (sample rate 100-1000 Hz, a 1-3 %-damped mode between 2 Hz and
0.2 fs drifting by 5-20 %, a rigid-body mode below it), runs sysid_node's processing over each
(the offline tool, identical to the node) and the adaptive notch bank on its estimates, and
measures the true resonance times the bank at every 20 ms block (offline, no DDS: the same
numbers on any machine).

Over the draws: every mode is tracked; the resonance peak is >= 15 dB down in at least 99 % of
the blocks in the median draw and in at least 95 % in every draw; the bank's phase lag at the
crossover is within 1.5 x the oracle notch's in the median draw. Open (xfail strict): no claim
above what is delivered in any draw - at the onset of a fast drift (45-70 Hz) the identification
has not seen the move yet and its frequency std is that of a still mode, and the bank's guarantee
is built on that std (1-2 % of the blocks of three draws).
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def suite(tmp_path_factory) -> list[dict]:
    out = tmp_path_factory.mktemp("suite") / "suite.json"
    proc = subprocess.run(
        [sys.executable, str(ROOT / "benchmarks" / "notch_drift_suite.py"), "--draws", "8",
         "--first-seed", "0", "--json", str(out)],
        capture_output=True, text=True, timeout=900, env=os.environ.copy())
    print(proc.stdout)
    assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-2000:]
    return json.loads(out.read_text())


def test_every_mode_tracked_and_the_median_draw_keeps_15_db(suite):
    assert all("error" not in f for f in suite), suite
    assert np.median([f["pr_share"] for f in suite]) >= 0.99, suite


def test_median_draw_lags_within_1_5_x_the_oracle(suite):
    assert np.median([f["lag_ratio_median"] for f in suite]) <= 1.5, suite


def test_every_draw_keeps_15_db_in_95_percent(suite):
    assert all(f["pr_share"] >= 0.95 for f in suite), suite


@pytest.mark.xfail(strict=True, reason="at the onset of a fast drift sysid's frequency std is "
                   "that of a still mode: the bank claims more than it gives in 1-2 % of blocks")
def test_no_draw_claims_more_than_it_delivers(suite):
    assert all(f["claimed_over_delivered_share"] == 0 for f in suite), suite
