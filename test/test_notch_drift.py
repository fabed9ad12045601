"""Issue #12 acceptance, process level over real DDS: a drifting, lightly damped, broadband-excited
mode (``sysid_node.scenarios.drifting_mode``, seeded; not a committed bag) replayed at real time
through sysid_node and notch_filter_node, quiet and with two CPU hogs (busy-loop processes
started and stopped by pid by the script). benchmarks/notch_drift_figures.py runs it and writes
the figures; its module docstring says how each is measured.

Over the /notch_bank messages from the first estimate that tracks the mode plus the notch's
fade-in (``fade_time``, a deliberate 1 s ramp): the true mode's resonance peak times the
published bank at least 15 dB below the bare peak in >= 99 % (quiet) / >= 95 % (hogs) of the
messages, the rigid-body mode below the band changed by at most 1 dB, no ``fallback_active``
while the latest estimate tracks the mode, never a claimed peak reduction above the delivered
one; quiet, the phase lag at the crossover within 1.5 x the oracle notch's while the bank tracks
a current estimate.

Under the hogs a late estimate holds the notches and widens them; sysid_node's bounded latency
under contention (#12 item 1) keeps the estimate age well under fallback_timeout. The quiet lag
comes from the widths, which follow the identification's frequency and damping stds
(benchmarks/notch_width_budget.py splits them): on this 2.6 Hz, 2 %-damped mode at 200 Hz the
frequency std fell with a Hankel window spanning a full period of the mode (sysid_node grows a
configured band's window for its lowest lightly damped mode, ``params.period_block_rows``): the
bank's lag went from 1.9 to 1.4 x the oracle notch's.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

pytestmark = [pytest.mark.dds, pytest.mark.slow]

ROOT = Path(__file__).resolve().parents[1]
SEED = 3


def _run(tmp: Path, hogs: int) -> dict:
    out = tmp / f"hogs{hogs}.json"
    env = dict(os.environ)
    env["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    env["ROS_DOMAIN_ID"] = str(10 + (os.getpid() + 7 * hogs) % 80)
    proc = subprocess.run(
        [sys.executable, str(ROOT / "benchmarks" / "notch_drift_figures.py"), "--seed", str(SEED),
         "--hogs", str(hogs), "--json", str(out)],
        capture_output=True, text=True, timeout=600, env=env)
    print(proc.stdout[-3000:])
    assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-2000:]
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
    assert fig["fallback_while_tracked"] == 0, fig
    assert fig["claimed_over_delivered"] == 0, fig


def test_quiet_keeps_the_peak_15_db_down_in_99_percent(quiet):
    _common(quiet, 0.99)


def test_quiet_phase_lag_within_1_5_x_the_oracle(quiet):
    # over the messages where the bank tracks a current estimate: the lag of the widths the
    # identification gives. Notches held on a late estimate are widened on purpose (their
    # share is holding_share); on this 2-core VM, whose processes stall for up to ~1 s a few
    # times every 10 s even when idle, a "quiet" run holds for 3-16 % of its messages, and the
    # median over all of them measured 1.46-1.70 across runs of the same code
    assert quiet["lag_ratio_tracking_median"] <= 1.5, quiet


def test_two_cpu_hogs_keep_the_peak_15_db_down_in_95_percent(stressed):
    _common(stressed, 0.95)
