"""Shared fixtures for the DSRA core tests (fixed seeds; data generated in the repo)."""

from __future__ import annotations

import numpy as np
import pytest
from sysid_node.core import SEED_EXAMPLE_SETTINGS, ModeTracker, RecursiveDSRA
from sysid_node.scenarios.paper import (
    PAPER_EXAMPLE_SWITCH_TIME_S,
    cobra_example_data,
    paper_example_data,
)

SEED_EXAMPLE_SEEDS = range(10)
#: Sample rate chosen for the cobra stick model: 256 Hz (about 7 samples per period of the
#: 36.6 Hz mode, Nyquist 128 Hz well above it).
COBRA_FS = 256.0


def run_seed_example(seed: int) -> list[tuple[float, list[tuple[int, str, float, float]]]]:
    """The Sec. II scenario through RecursiveDSRA + ModeTracker with the documented settings;
    returns (time, [(id, status, frequency_hz, damping_ratio)]) per realization. Blocks of
    random length 1..25 samples exercise the any-length block interface."""
    _, u, y = paper_example_data(duration_s=40.0, fs=100.0, noise_fraction=0.05, seed=seed)
    est = RecursiveDSRA(1, 1, fs=100.0, **SEED_EXAMPLE_SETTINGS)
    tracker = ModeTracker()
    lengths = np.random.default_rng(1000 + seed).integers(1, 26, size=len(y))
    records = []
    k = 0
    for n in lengths:
        if k >= len(y):
            break
        for model in est.update(u[k : k + n], y[k : k + n]):
            tracks = tracker.update(model.modes, model.time_s)
            records.append(
                (
                    model.time_s,
                    [(t.id, t.status, t.frequency_hz, t.damping_ratio) for t in tracks],
                )
            )
        k += n
    return records


@pytest.fixture(scope="session")
def seed_example_runs():
    assert PAPER_EXAMPLE_SWITCH_TIME_S == 20.0
    return {seed: run_seed_example(seed) for seed in SEED_EXAMPLE_SEEDS}


@pytest.fixture(scope="session")
def cobra_data():
    """60 s of the cobra stick model at 256 Hz, two white inputs, 5 % output noise."""
    return cobra_example_data(duration_s=60.0, fs=COBRA_FS, noise_fraction=0.05, seed=7)
