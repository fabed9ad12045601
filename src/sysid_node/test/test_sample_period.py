"""The period the stamps measure (sample_period.unit_period): lost samples make intervals
whole multiples of it, late samples sorted in make a few short ones; neither may move it."""

import numpy as np
import pytest
from sysid_node.sample_period import unit_period


@pytest.mark.parametrize("lost", [0.0, 0.5, 0.9])
@pytest.mark.parametrize("off_grid", [0, 10])
def test_period_with_losses_and_samples_off_the_grid(lost, off_grid):
    rng = np.random.default_rng(int(lost * 10) + off_grid)
    fs = float(rng.uniform(50.0, 2000.0))
    n = 3000
    t = (np.arange(n) + rng.normal(0.0, 0.02, n)) / fs  # stamps jitter by 2 % of a period
    t = t[rng.random(n) >= lost]
    late = (rng.integers(0, n, off_grid) + 0.5) / fs  # half a period off the grid
    t = np.sort(np.concatenate((t, late)))[-513:]
    assert 1.0 / unit_period(np.diff(t)) == pytest.approx(fs, rel=0.005)


def test_heavy_jitter_falls_back_to_the_typical_interval():
    rng = np.random.default_rng(1)
    p = 0.01 * (1.0 + rng.uniform(-0.45, 0.45, 500))  # no lattice: the typical interval
    assert unit_period(p) == pytest.approx(0.01, rel=0.15)
