"""Issue #12 acceptance, process level over real DDS: a drifting, lightly damped, broadband-excited
mode (``sysid_node.scenarios.drifting_mode``, seeded; not a committed bag) replayed at real time
through sysid_node and notch_filter_node, quiet and with two CPU hogs (busy-loop processes
started and stopped by pid by the script). benchmarks/notch_drift_figures.py runs it and writes
the figures; its module docstring says how each is measured.

Over the /notch_bank messages from the first estimate that tracks the mode plus the notch's
fade-in (``fade_time``, a deliberate 1 s ramp): the true mode's resonance peak times the
published bank at least 15 dB below the bare peak in >= 95 % of the messages quiet, >= 85 %
with the hogs; the rigid-body mode below the band changed by at most 1 dB; no ``fallback_active``
while the latest estimate tracks the mode and is fresh (age <= ``stale_timeout``: an estimate
seconds old on a saturated machine is meant to end in the fallback at ``fallback_timeout``);
the bank's claimed peak reduction above the delivered one in no more messages than its
guarantee allows (the claim holds over a region that covers the true mode with probability
``resonance.region_confidence(sigma_k, damping_sigma_k)``, 96.5 % by default: a claim that
never failed would be a needlessly wide notch); quiet, the phase lag at the crossover below the
static notch's with the same guarantee, while the bank tracks a current estimate.

The 99 % share and the 1.5 x the oracle notch's lag are judged in data time
(test/test_notch_drift_suite.py: eight seeded draws, deterministic). Live, the widths also cover
the drift the mode could make during the estimate's age (``policy``: ``h = sigma_k sigma_f +
drift * age``), and the age is the machine's. On this 2-core VM, whose processes stall for up
to ~1 s a few times every 10 s even idle, the quiet run's share measured 97.5-99.1 % and its
tracking lag median 1.43-1.72 x the oracle's across runs of the same code; the script prints
both.

Under the hogs a late estimate holds the notches and widens them; sysid_node's bounded latency
under contention (#12 item 1) keeps the estimate age mostly under fallback_timeout (p95 2.6 s
and 7.7 s in two runs of the same code on this VM). The hogs share is 85 %: two busy loops, the
two nodes and the harness's replay and record (together about a core of Python) on two cores
starve the estimator for seconds; in four runs of the same code on this VM the share measured
91.1-100 % (the misses: an estimate that lags the drift when few realizations run, or one
held 7-10 s). A run in which the mode is never tracked fails with the nodes' log tails.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
from scipy.stats import binom

pytestmark = [pytest.mark.dds, pytest.mark.slow]

ROOT = Path(__file__).resolve().parents[1]
SEED = 3


def _run(tmp: Path, hogs: int) -> dict:
    out = tmp / f"hogs{hogs}.json"
    env = dict(os.environ)
    env["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    domain = 10 + (os.getpid() + 7 * hogs) % 80
    if str(domain) == os.environ.get("ROS_DOMAIN_ID"):  # not the domain of the other tests
        domain += 1
    env["ROS_DOMAIN_ID"] = str(domain)
    proc = subprocess.run(
        [sys.executable, str(ROOT / "benchmarks" / "notch_drift_figures.py"), "--seed", str(SEED),
         "--hogs", str(hogs), "--json", str(out)],
        capture_output=True, text=True, timeout=600, env=env)
    print(proc.stdout[-3000:])
    assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-8000:]  # + the logs' tails
    return json.loads(out.read_text())


@pytest.fixture(scope="module")
def quiet(tmp_path_factory):
    return _run(tmp_path_factory.mktemp("quiet"), 0)


@pytest.fixture(scope="module")
def stressed(tmp_path_factory):
    return _run(tmp_path_factory.mktemp("stressed"), 2)


def _common(fig: dict, share: float) -> None:
    assert fig["pr_share"] >= share, fig
    assert fig["rigid_max_abs_db"] <= 1.0, fig
    assert fig["fallback_while_tracked_fresh"] == 0, fig
    # the guarantee's confidence: a claim that holds with it fails in a binomial number of
    # messages at most; the test rejects it at the 1 % level (messages in a row share one
    # estimate, so their failures cluster and the count spreads wider still: the bound is on
    # the strict side). The failures, if any, are listed with their estimate's age and state.
    allowed = binom.ppf(0.99, fig["claimed_messages"], 1.0 - fig["claim_confidence"])
    assert fig["claimed_over_delivered"] <= allowed, (allowed, fig["over_delivered_at"], fig)


def test_quiet_keeps_the_peak_15_db_down_in_95_percent(quiet):
    _common(quiet, 0.95)


def test_quiet_phase_lag_below_the_static_notch(quiet):
    # over the messages where the bank tracks a current estimate (notches held on a late one are
    # widened on purpose: holding_share); the oracle ratio is printed, judged in data time
    static_ratio = quiet["static_lag_deg"] / quiet["oracle_lag_median_deg"]
    assert quiet["lag_ratio_tracking_median"] < static_ratio, quiet


def test_two_cpu_hogs_keep_the_peak_15_db_down_in_85_percent(stressed):
    _common(stressed, 0.85)
