"""A lightly damped mode whose young estimate lies just outside the unit circle is reported (as
its reflection), not dropped by the damping bounds (core/modal.extract_modes reflect_unstable)."""

import numpy as np
from sysid_node.core import RecursiveDSRA
from sysid_node.core.lti import simulate
from sysid_node.core.modal import extract_modes
from sysid_node.scenarios.noise import add_output_noise
from sysid_node.scenarios.structures import modal_system

FS = 100.0


def _pole_outside(sigma: float, reflect: bool):
    """A 5 Hz pole pair at radius 1.001 (damping -0.32 %) with cov(vec A) = sigma^2 I."""
    th = 2 * np.pi * 5.0 / FS
    a = 1.001 * np.array([[np.cos(th), -np.sin(th)], [np.sin(th), np.cos(th)]])
    c = np.array([[1.0, 0.0]])
    return extract_modes(a, c, FS, a_cov_rows=sigma**2 * np.eye(2), a_cov_cols=np.eye(2),
                         damping_bounds=(0.0, 0.5), reflect_unstable=reflect)[0]


def test_a_pole_just_outside_within_its_uncertainty_is_reflected():
    kept = _pole_outside(0.01, True)
    assert len(kept) == 1
    md = kept[0]
    assert abs(md.frequency_hz / 5.0 - 1) < 1e-3
    assert 0.0 < md.damping_ratio < 0.005 and md.damping_ratio < md.damping_std
    assert abs(md.pole_discrete) < 1.0
    assert _pole_outside(0.01, False) == []  # the batch default: as before
    assert _pole_outside(1e-7, True) == []  # far outside in its standard deviations
    th = 2 * np.pi * 5.0 / FS  # bounds that admit negative damping get the estimate as it is
    a = 1.001 * np.array([[np.cos(th), -np.sin(th)], [np.sin(th), np.cos(th)]])
    raw = extract_modes(a, np.array([[1.0, 0.0]]), FS, a_cov_rows=1e-4 * np.eye(2),
                        a_cov_cols=np.eye(2), damping_bounds=(-0.01, 0.5),
                        reflect_unstable=True)[0]
    assert len(raw) == 1 and raw[0].damping_ratio < 0


def test_a_lightly_damped_mode_stays_in_the_young_recursive_realizations():
    """One output, a 0.2 %-damped 4 Hz mode beside a 2 %-damped 9 Hz one, 5 % noise, a 4 s
    memory: the 4 Hz mode came out with a damping below zero in over half of the realizations
    and was dropped (share 0.43 over these records; the random suite lost 0.2-0.6 %-damped
    modes for seconds this way); now 0.67 of them hold it, with a small positive damping."""
    shares, zetas = [], []
    for seed in range(4):
        rng = np.random.default_rng(seed)
        system = modal_system([4.0, 9.0], [0.002, 0.02], rng.normal(size=(2, 1)),
                              rng.normal(size=(1, 2)), "displacement")
        y = add_output_noise(simulate(system, rng.normal(size=(1200, 1)), FS), 0.05, rng)
        est = RecursiveDSRA(1, 0, fs=FS, block_rows=30, max_order=12,
                            forgetting_factor=np.exp(-1 / (4.0 * FS)), realization_interval=10)
        models = []
        for k in range(0, len(y), 10):
            models += est.update(None, y[k : k + 10])
        near = [[m for m in mdl.modes if abs(m.frequency_hz / 4.0 - 1) < 0.01] for mdl in models]
        shares.append(np.mean([bool(n) for n in near]))
        zetas += [m.damping_ratio for n in near for m in n]
    assert np.mean(shares) >= 0.6
    assert 0.0 <= np.median(zetas) < 0.01
