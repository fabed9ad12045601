"""suite.ambient_ceiling: the chance an efficient estimator has an ambient mode within the
tolerance, checked against least squares AR(2) fits of simulated ambient records (seeded);
suite.ambient_realistic: the same for records a few decay times long."""

import math

import numpy as np
import pytest
from scipy import signal
from sysid_node.suite import WIDENING_INF, ambient_ceiling, ambient_realistic


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


def test_the_realistic_figure_claims_no_more_than_a_fit_of_a_short_record_reaches():
    """Half a decay time in the record (zeta 2 pi f T = 0.5): least squares AR(2) fits of pure
    AR(2) records (the estimator knows the model class and there is no noise: no output-only
    fit of modal data does better) have the frequency within 2 sd of the asymptotic bound in
    fewer records than ambient_ceiling claims; ambient_realistic claims no more."""
    f, zeta, fs, data_s = 4.0, 0.005, 40.0, 4.0
    err = _ar2_frequency_errors(f, zeta, fs, data_s, 1000, seed=1)
    tol = 2 * math.sqrt(zeta / (2 * math.pi * f * data_s))
    share = float(np.mean(np.abs(err) <= tol))
    assert ambient_ceiling([(f, zeta)], data_s, tol) > share + 0.05, share
    assert ambient_realistic([(f, zeta)], data_s, tol) <= share, share


def test_the_realistic_figure_widens_short_records_most():
    """At a tolerance of 2 bound sds the ceiling is the same for every record length (0.954);
    the realistic figure is lower, the more so the fewer decay times the record holds, and
    for a long record it is the bound widened by WIDENING_INF alone."""
    f, zeta = 3.0, 0.01
    shares = []
    two_sd = math.erf(2 / math.sqrt(2))
    for data_s in (1.0, 4.0, 40.0, 4000.0):
        tol = 2 * math.sqrt(zeta / (2 * math.pi * f * data_s))
        assert ambient_ceiling([(f, zeta)], data_s, tol) == pytest.approx(two_sd)
        shares.append(ambient_realistic([(f, zeta)], data_s, tol))
    assert shares == sorted(shares) and shares[0] < shares[-1] - 0.1, shares
    assert shares[-1] == pytest.approx(math.erf(2 / (WIDENING_INF * math.sqrt(2))), abs=0.01)
