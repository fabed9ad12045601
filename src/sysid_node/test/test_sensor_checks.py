"""Stuck and dead channels (sensor_checks.py) are flagged within about 1 s of data at any rate,
never on live noisy channels, and clear when the channel recovers."""

from __future__ import annotations

import numpy as np
import pytest
from sysid_node.sensor_checks import HEALTH_DEGRADED, HEALTH_FAULT, STUCK_MAX_S, SensorChecks


def _first_flag(fs: float, y: np.ndarray, u: np.ndarray, rng, word: str):
    """Feed in chunks of random size (up to 0.1 s); data time [s] at the end of the first
    chunk after which a fault reason contains ``word`` (None if never), and the faults seen
    before it."""
    checks = SensorChecks(fs)
    a, before = 0, []
    max_chunk = max(1, int(0.1 * fs))
    while a < len(y):
        b = min(len(y), a + int(rng.integers(1, max_chunk + 1)))
        checks.add(y[a:b], u[a:b])
        faults = checks.faults()
        if any(word in why for _, why in faults):
            return (b - 1) / fs, before, checks
        before += faults
        a = b
    return None, before, checks


@pytest.mark.parametrize("seed", range(12))
def test_stuck_output_and_dead_excitation_flagged_within_a_second(seed):
    rng = np.random.default_rng(seed)
    fs = float(np.exp(rng.uniform(np.log(4.0), np.log(4000.0))))  # 4 Hz .. 4 kHz
    n = int(6 * fs)
    onset = int(rng.uniform(2.0, 3.0) * fs)
    y = rng.standard_normal((n, 3))
    u = rng.standard_normal((n, 1))
    kind = ("output", "input")[seed % 2]
    if kind == "output":
        y[onset:, 1] = y[onset, 1]  # frozen at its last value
        word, level = "output channel 1 stuck", HEALTH_FAULT
    else:
        u[onset:, 0] = 0.0  # an excitation channel that went dead while the structure moves
        word, level = "dead excitation", HEALTH_FAULT
    t, before, checks = _first_flag(fs, y, u, rng, word)
    assert not before, before  # nothing flagged on live noisy channels
    assert t is not None, f"{kind} never flagged at {fs:.1f} Hz"
    delay = t - onset / fs
    assert delay <= STUCK_MAX_S + 0.1 + 1 / fs, f"{delay:.2f} s after the onset at {fs:.1f} Hz"
    assert any(lv == level and word in why for lv, why in checks.faults())
    # the channel comes back: the reason disappears
    checks.add(rng.standard_normal((3, 3)), rng.standard_normal((3, 1)))
    assert not any(word in why for _, why in checks.faults())


def test_input_still_while_the_outputs_are_still_too_is_only_degraded():
    fs = 200.0
    checks = SensorChecks(fs)
    y = np.full((400, 2), 0.25)
    checks.add(y, np.zeros((400, 1)))
    levels = {lv for lv, why in checks.faults() if "input channel 0 stuck" in why}
    assert levels == {HEALTH_DEGRADED}
