"""suite.ambient_ceiling: the chance an efficient estimator has an ambient mode within the
tolerance, checked against least squares AR(2) fits of simulated ambient records (seeded)."""

import math

import numpy as np
import pytest
from scipy import signal
from sysid_node.suite import ambient_ceiling


def _ar2_frequency_errors(f: float, zeta: float, fs: float, data_s: float, trials: int,
                          seed: int) -> np.ndarray:
    """Relative errors of the frequency of a least squares AR(2) fit of ``trials`` ambient
    records of one mode (white-noise-driven, stationary start)."""
    rng = np.random.default_rng(seed)
    w, dt = 2 * math.pi * f, 1.0 / fs
    pole = np.exp((-zeta * w + 1j * w * math.sqrt(1 - zeta**2)) * dt)
    burn, n = int(10.0 / (zeta * w * dt)), int(data_s * fs)
    y = signal.lfilter([1.0], [1.0, -2 * pole.real, abs(pole) ** 2],
                       rng.standard_normal((trials, burn + n)), axis=1)[:, burn:]
    x1, x2, t = y[:, 1:-1], y[:, :-2], y[:, 2:]
    g = np.stack([np.stack([(x1 * x1).sum(1), (x1 * x2).sum(1)], -1),
                  np.stack([(x1 * x2).sum(1), (x2 * x2).sum(1)], -1)], -2)
    rhs = np.stack([(x1 * t).sum(1), (x2 * t).sum(1)], -1)[..., None]
    a1, a2 = np.linalg.solve(g, rhs)[..., 0].T
    root = (a1 + np.sqrt((a1**2 + 4 * a2).astype(complex))) / 2
    return np.abs(np.angle(root)) / (2 * math.pi * dt) / f - 1.0


@pytest.mark.parametrize("f, zeta, fs, data_s",
                         [(10.0, 0.02, 200.0, 10.0), (4.0, 0.01, 100.0, 30.0)])
def test_the_ceiling_is_the_share_an_efficient_fit_reaches(f, zeta, fs, data_s):
    # many decay times in the record (zeta 2 pi f T >> 1): the asymptotics hold
    err = _ar2_frequency_errors(f, zeta, fs, data_s, 400, seed=1)
    tol = 1.2 * math.sqrt(zeta / (2 * math.pi * f * data_s))  # P about 0.77
    share = float(np.mean(np.abs(err) <= tol))
    assert abs(ambient_ceiling([(f, zeta)], data_s, tol) - share) < 0.07, share


def test_the_ceiling_of_several_modes_is_the_product_and_falls_with_damping():
    one = ambient_ceiling([(3.0, 0.02)], 4.0)
    assert ambient_ceiling([(3.0, 0.02), (3.0, 0.02)], 4.0) == pytest.approx(one**2)
    assert ambient_ceiling([(3.0, 0.05)], 4.0) < one < ambient_ceiling([(3.0, 0.02)], 8.0)
