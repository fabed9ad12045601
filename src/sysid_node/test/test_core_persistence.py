"""Spurious-mode test 3 over successive realizations (``core/spurious.py``: ``overfit_only``,
:class:`Persistence`): a pole pair below the overfit level alone that stays put over
``PERSIST_REALIZATIONS`` successive realizations is kept; one that wanders, changes shape or
misses a realization is not."""

from __future__ import annotations

import numpy as np
from sysid_node.core import spurious
from sysid_node.core.modal import ModalParameters
from sysid_node.core.spurious import Persistence, flag_spurious

K = spurious.PERSIST_REALIZATIONS


def _mode(f: float, stable: bool = False, overfit: bool = True,
          shape=(1.0,)) -> ModalParameters:
    return ModalParameters(f, 0.01, shape=np.asarray(shape, complex), stable=stable,
                           overfit_only=overfit)


def test_flag_spurious_marks_a_mode_failing_only_the_overfit_level():
    checks = [np.array([10.0, 20.0])] * 3
    below = ModalParameters(10.0, 0.01, contribution=0.01, snr=50.0)
    unstable = ModalParameters(30.0, 0.01, contribution=0.01, snr=50.0)  # in no check order
    strong = ModalParameters(20.0, 0.01, contribution=1.0, snr=50.0)
    flag_spurious([below, unstable, strong], checks, None, 5.0, 0.1)
    assert (below.stable, below.overfit_only) == (False, True)
    assert (unstable.stable, unstable.overfit_only) == (False, False)
    assert (strong.stable, strong.overfit_only) == (True, False)


def test_a_persistent_pole_pair_is_kept_after_k_realizations():
    p = Persistence()
    rng = np.random.default_rng(0)
    kept = []
    for _ in range(K + 3):
        md = _mode(43.8 * (1 + 0.001 * rng.standard_normal()))
        noise = _mode(rng.uniform(20.0, 60.0))  # a noise pole elsewhere each time
        p.apply([noise, md])
        kept.append(md.stable)
        assert not noise.stable
    assert kept == [False] * (K - 1) + [True] * 4


def test_a_run_continues_through_realizations_that_pass_every_test():
    p = Persistence()
    seq = [_mode(43.8, stable=(k % 3 == 1), overfit=(k % 3 != 1)) for k in range(K)]
    for md in seq:
        p.apply([md])
    assert seq[-1].stable


def test_a_wandering_pole_pair_is_not_kept():
    p = Persistence()
    f = 43.8
    for k in range(4 * K):
        f *= 1.0 + 0.6 * spurious.PERSIST_FREQUENCY_TOL * (1 if (k // 2) % 2 else -1) + 0.003
        md = _mode(f)
        p.apply([md])
        assert not md.stable


def test_a_missed_realization_restarts_the_run():
    p = Persistence()
    for k in range(2 * K - 2):
        md = _mode(43.8)
        p.apply([] if k == K - 2 else [md])
        if k != K - 2:
            assert not md.stable


def test_a_pole_pair_whose_shape_changes_is_not_kept():
    p = Persistence()
    for k in range(2 * K):
        md = _mode(43.8, shape=(1.0, 1.0) if k % 2 else (1.0, -1.0))
        p.apply([md])
        assert not md.stable


def test_runs_grow_but_nothing_is_lifted_when_told_not_to():
    p = Persistence()
    for _ in range(K):
        md = _mode(43.8)
        p.apply([md], lift=False)
        assert not md.stable
    md = _mode(43.8)
    p.apply([md])  # the run is K + 1 long: lifted as soon as allowed
    assert md.stable


def test_pipeline_lifts_only_while_the_estimators_memory_fills():
    from types import SimpleNamespace

    from sysid_node.pipeline import _young

    assert _young(SimpleNamespace(forgetting_factor=0.99, samples_seen=99))
    assert not _young(SimpleNamespace(forgetting_factor=0.99, samples_seen=100))


def test_a_weak_pole_pair_beside_a_stronger_mode_is_not_overfit_only():
    """Within SIDEBAND_BINS bins (fs / 2i) of a stronger stable mode a pole pair below the
    overfit level is not resolved from it (random suite draw 6: 77.6 Hz beside 73.2 Hz at a
    2.46 Hz resolution); farther away, or beside no stable mode, it stays a candidate."""
    res = 2.46
    checks = [np.array([73.2, 77.6, 100.0, 130.0, 134.9])] * 3
    strong = ModalParameters(73.2, 0.01, contribution=5.0, snr=50.0)
    side = ModalParameters(77.6, 0.01, contribution=0.05, snr=50.0)
    far = ModalParameters(100.0, 0.01, contribution=0.05, snr=50.0)
    weak = ModalParameters(130.0, 0.01, contribution=0.08, snr=50.0)
    beside_weak = ModalParameters(134.9, 0.01, contribution=0.05, snr=50.0)
    modes = [strong, side, far, weak, beside_weak]
    flag_spurious(modes, checks, None, 5.0, 0.1, None, res)
    assert strong.stable and not side.overfit_only
    assert far.overfit_only
    assert weak.overfit_only and beside_weak.overfit_only  # beside no stable mode
    side2 = ModalParameters(77.6, 0.01, contribution=0.05, snr=50.0)
    flag_spurious([ModalParameters(73.2, 0.01, contribution=5.0, snr=50.0), side2], checks,
                  None, 5.0, 0.1)
    assert side2.overfit_only  # resolution not given: no sideband test


def test_a_pole_pair_where_the_input_has_not_excited_is_not_overfit_only():
    """With a measured input, a pole pair in a band the input has not excited over the memory
    (a sweep that has not got there: swept-input seed 705, 104 Hz at 5.4 s) is no candidate."""
    checks = [np.array([40.0, 104.0])] * 3
    modes = [ModalParameters(f, 0.01, contribution=0.01, snr=50.0) for f in (40.0, 104.0)]
    flag_spurious(modes, checks, None, 5.0, 0.1, None, 0.0, np.array([True, False]))
    assert [md.overfit_only for md in modes] == [True, False]


def test_input_excited_level_lies_between_a_white_input_and_a_band_not_swept_yet():
    from sysid_node.core.spurious import INPUT_EXCITED_LEVEL, input_concentration

    fs, n = 294.0, 140  # the swept-input record's rate and window 2i
    rng = np.random.default_rng(3)
    t = np.arange(int(5.4 * fs)) / fs
    sweep = np.sin(2 * np.pi * (5.0 * t + 0.5 * 11.0 * t**2))  # at 64 Hz by 5.4 s
    white = rng.standard_normal(t.size)
    f = np.array([20.0, 50.0, 104.0, 130.0])
    assert np.all(input_concentration(_window_cov(white, n), 1, f, fs) > INPUT_EXCITED_LEVEL)
    q = input_concentration(_window_cov(sweep, n), 1, f, fs)
    assert np.all(q[:2] > INPUT_EXCITED_LEVEL) and np.all(q[2:] < INPUT_EXCITED_LEVEL)


def _window_cov(u: np.ndarray, n: int) -> np.ndarray:
    """Covariance of the n-sample windows of u (equal weights: a filling memory)."""
    rows = np.lib.stride_tricks.sliding_window_view(u, n)
    return rows.T @ rows
