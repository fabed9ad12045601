"""Generate the scenario bags of bags/ (fixed seeds): ``ros2_ws/env python bags/generate_bags.py``.

Each scenario is a rosbag2 directory ``bags/<name>`` (mcap, zstd file compression unless
``--no-compress``) with ``sysid_msgs/SignalSample`` topics ``/vibration`` (outputs),
``/excitation`` (inputs, absent when output-only) and scheduling signals (``/airspeed`` [m/s],
``/rotor_speed`` [Hz]), plus ``bags/<name>.truth.json`` with the true modes over time.

Scenarios (Mehra & Prasanth, J. Aircraft 41(4) 2004):

* ``paper_example``: Sec. II, system (1) with 2 and 4 Hz modes, a 6 Hz mode appearing at 20 s;
  100 Hz, wideband input, 5 % output noise (the shipped default bag).
* ``wing_bending_drift``: a V-22-like symmetric wing beam (SWB) mode drifting 2.6 -> 3.0 Hz
  with airspeed 150 -> 250 kn (damping 2.1 -> 3.6 %, the trend of Table 1), the symmetric wing
  torsion mode (5.18 Hz, 4.6 %, Table 1) and a lightly damped 1 Hz rigid-body mode that the
  flight controller must keep; 100 Hz, 60 s, 3 accelerometers.
* ``cobra_stick``: the Sec. IV cobra stick model (3), 2 wideband inputs, 2 outputs, 256 Hz.
* ``output_only``: four structural modes driven by unmeasured turbulence, 4 accelerometers,
  no ``/excitation``.

A time-varying system is simulated as piecewise LTI over short segments carrying the modal state
(each segment vectorised by ``core.systems.simulate_with_state``).
"""

from __future__ import annotations

import argparse
import json
import shutil
import sys
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from sysid_node.bag_io import BagError, write_signals
from sysid_node.core.systems import (
    PAPER_EXAMPLE_SWITCH_TIME_S,
    ContinuousSystem,
    add_output_noise,
    cobra_stick_model,
    paper_example_data,
    simulate,
    simulate_with_state,
    wideband_input,
)

BAGS = Path(__file__).resolve().parent
T0 = 1_700_000_000.0  # stamp of the first sample [s since epoch]
KNOT = 0.514444  # [m/s]
SCHEDULE_RATE = 10.0  # rate of /airspeed and /rotor_speed [Hz]
NOISE = 0.05  # output noise, fraction of each channel's std


@dataclass
class Scenario:
    """Signals of one bag (``{topic: (t [s from start], values (N, c), channel names)}``)."""

    name: str
    description: str
    fs: float
    seed: int
    signals: dict[str, tuple[np.ndarray, np.ndarray, list[str]]]
    modes: list[dict]
    extra: dict = field(default_factory=dict)

    @property
    def duration(self) -> float:
        return max(float(t[-1]) for t, _, _ in self.signals.values()) + 1.0 / self.fs

    def truth(self) -> dict:
        topics = {
            topic: {
                "channels": names,
                "rate_hz": float(np.round(1.0 / np.median(np.diff(t)), 6)),
                "samples": int(len(t)),
            }
            for topic, (t, _, names) in self.signals.items()
        }
        return {
            "name": self.name,
            "description": self.description,
            "seed": self.seed,
            "sample_rate_hz": self.fs,
            "duration_s": self.duration,
            "start_time_s": T0,
            "noise_fraction": NOISE,
            "output_only": "/excitation" not in self.signals,
            "topics": topics,
            "modes_note": (
                "t_s is time since start_time_s; frequency_hz and damping_ratio are linear "
                "between the t_s points; a mode exists from t_s[0] to t_s[-1]"
            ),
            "modes": self.modes,
            **self.extra,
        }


def _mode(name: str, kind: str, t: list[float], f: list[float], zeta: list[float]) -> dict:
    return {
        "name": name,
        "kind": kind,
        "t_s": [round(float(x), 6) for x in t],
        "frequency_hz": [round(float(x), 6) for x in f],
        "damping_ratio": [round(float(x), 6) for x in zeta],
    }


def _schedule(fs_sched: float, duration: float, values: np.ndarray) -> tuple[np.ndarray, ...]:
    t = np.arange(int(round(duration * fs_sched))) / fs_sched
    return t, values


def modal_system(
    freqs: np.ndarray, zetas: np.ndarray, b: np.ndarray, shapes: np.ndarray
) -> ContinuousSystem:
    """Modal model, state [q_1, dq_1, q_2, dq_2, ...], accelerometer outputs.

    Mode i: ddq + 2 zeta w dq + w^2 q = b_i . u; output y = sum_i shape_i ddq_i, so
    C = shape (x) [-w^2, -2 zeta w] and D = shape b (acceleration feed-through).
    """
    w = 2 * np.pi * np.asarray(freqs, dtype=float)
    z = np.asarray(zetas, dtype=float)
    b = np.atleast_2d(np.asarray(b, dtype=float))  # (modes, inputs)
    shapes = np.atleast_2d(np.asarray(shapes, dtype=float))  # (outputs, modes)
    n = w.size
    a = np.zeros((2 * n, 2 * n))
    bb = np.zeros((2 * n, b.shape[1]))
    c = np.zeros((shapes.shape[0], 2 * n))
    for i in range(n):
        a[2 * i, 2 * i + 1] = 1.0
        a[2 * i + 1, 2 * i] = -(w[i] ** 2)
        a[2 * i + 1, 2 * i + 1] = -2 * z[i] * w[i]
        bb[2 * i + 1] = b[i]
        c[:, 2 * i] = -shapes[:, i] * w[i] ** 2
        c[:, 2 * i + 1] = -shapes[:, i] * 2 * z[i] * w[i]
    return ContinuousSystem(a, bb, c, shapes @ b)


def simulate_varying(
    system_at: Callable[[float], ContinuousSystem], u: np.ndarray, fs: float, segment_s: float
) -> np.ndarray:
    """Piecewise-LTI simulation: ``system_at(t_mid)`` on each segment, state carried over."""
    n = u.shape[0]
    step = max(1, int(round(segment_s * fs)))
    out, x = [], None
    for k0 in range(0, n, step):
        k1 = min(n, k0 + step)
        sysk = system_at(0.5 * (k0 + k1 - 1) / fs)
        y, x = simulate_with_state(sysk, u[k0:k1], fs, x)
        out.append(y)
    return np.vstack(out)


def paper_example(seed: int = 1) -> Scenario:
    """Sec. II: 2 and 4 Hz, a 6 Hz mode from 20 s; 100 Hz, 40 s, wideband input, 5 % noise."""
    from sysid_node.core.systems import paper_example_systems

    fs, duration = 100.0, 40.0
    t, u, y = paper_example_data(duration_s=duration, fs=fs, noise_fraction=NOISE, seed=seed)
    sys_a, sys_b = paper_example_systems()
    ts = PAPER_EXAMPLE_SWITCH_TIME_S
    modes_a, modes_b = sys_a.modes(), sys_b.modes()
    modes = []
    for i, (f, z) in enumerate(modes_b):
        if i < len(modes_a):
            fa, za = modes_a[i]
            modes.append(
                _mode(
                    f"mode_{i + 1}",
                    "structural",
                    [0, ts, ts, duration],
                    [fa, fa, f, f],
                    [za, za, z, z],
                )
            )
        else:
            modes.append(_mode(f"mode_{i + 1}", "structural", [ts, duration], [f, f], [z, z]))
    return Scenario(
        "paper_example",
        "Sec. II example: modes at 2 and 4 Hz, a 6 Hz mode appears at 20 s (system (1)); "
        "wideband input, 5 % output noise, 100 Hz",
        fs,
        seed,
        {"/vibration": (t, y, ["y"]), "/excitation": (t, u, ["u"])},
        modes,
        {"switch_time_s": ts},
    )


def wing_bending_drift(seed: int = 2) -> Scenario:
    """V-22-like SWB mode drifting 2.6 -> 3.0 Hz with airspeed, SWT 5.18 Hz, 1 Hz rigid body."""
    fs, duration, segment = 100.0, 60.0, 0.25
    rng = np.random.default_rng(seed)
    n = int(round(duration * fs))

    def airspeed_kn(t: np.ndarray | float) -> np.ndarray:
        return np.interp(t, [0.0, 10.0, 50.0, duration], [150.0, 150.0, 250.0, 250.0])

    def swb(t: np.ndarray | float) -> tuple[np.ndarray, np.ndarray]:
        s = (airspeed_kn(t) - 150.0) / 100.0
        return 2.6 + 0.4 * s, 0.021 + 0.015 * s

    rigid = (1.0, 0.05)
    swt = (5.18, 0.0458)
    b = np.array([[0.4], [1.0], [0.8]])  # flaperon command -> rigid body, SWB, SWT
    shapes = np.array(  # wing tip left, wing tip right, fuselage (vertical accelerations)
        [[1.0, 1.0, 0.6], [1.0, 1.0, -0.6], [1.0, -0.25, 0.05]]
    )

    def system_at(t: float) -> ContinuousSystem:
        f, z = swb(t)
        return modal_system(
            [rigid[0], float(f), swt[0]], [rigid[1], float(z), swt[1]], b, shapes * 0.05
        )

    u = wideband_input(n, 1, rng)
    y = add_output_noise(simulate_varying(system_at, u, fs, segment), NOISE, rng)
    t = np.arange(n) / fs
    t_s, _ = _schedule(SCHEDULE_RATE, duration, None)
    v = airspeed_kn(t_s) * KNOT + 0.2 * rng.standard_normal(t_s.size)  # [m/s], sensor noise
    nr = 333.0 / 60.0 + 0.005 * rng.standard_normal(t_s.size)  # proprotor 333 rpm [Hz]
    bp = np.array([0.0, 10.0, 50.0, duration])
    f_b, z_b = swb(bp)
    modes = [
        _mode("rigid_body_1hz", "rigid_body", [0, duration], [rigid[0]] * 2, [rigid[1]] * 2),
        _mode("symmetric_wing_beam", "structural", bp, f_b, z_b),
        _mode("symmetric_wing_torsion", "structural", [0, duration], [swt[0]] * 2, [swt[1]] * 2),
    ]
    return Scenario(
        "wing_bending_drift",
        "V-22-like symmetric wing beam mode drifting 2.6 -> 3.0 Hz as airspeed ramps "
        "150 -> 250 kn (10-50 s), wing torsion 5.18 Hz, 1 Hz rigid-body mode to keep; "
        "flaperon wideband input, 3 accelerometers, 5 % noise, 100 Hz",
        fs,
        seed,
        {
            "/vibration": (
                t,
                y,
                ["wing_tip_left_z[m/s^2]", "wing_tip_right_z[m/s^2]", "fuselage_z[m/s^2]"],
            ),
            "/excitation": (t, u, ["flaperon_cmd[rad]"]),
            "/airspeed": (t_s, v[:, None], ["airspeed[m/s]"]),
            "/rotor_speed": (t_s, nr[:, None], ["rotor_speed[Hz]"]),
        },
        modes,
        {
            "scheduling": {
                "signal": "/airspeed",
                "airspeed_mps": [round(float(x * KNOT), 4) for x in airspeed_kn(bp)],
                "t_s": bp.tolist(),
                "mode": "symmetric_wing_beam",
                "frequency_hz_per_mps": round(0.4 / (100.0 * KNOT), 6),
            },
            "simulation_segment_s": segment,
        },
    )


def cobra_stick(seed: int = 3) -> Scenario:
    """Sec. IV cobra stick model (3), open loop at 32 Hz rotor speed: 2 in, 2 out, 256 Hz."""
    fs, duration = 256.0, 30.0
    rng = np.random.default_rng(seed)
    n = int(round(duration * fs))
    csm = cobra_stick_model()
    u = wideband_input(n, 2, rng)
    y = add_output_noise(simulate(csm, u, fs), NOISE, rng)
    t = np.arange(n) / fs
    t_s, _ = _schedule(SCHEDULE_RATE, duration, None)
    nr = 32.0 + 0.01 * rng.standard_normal(t_s.size)
    modes = [
        _mode(f"csm_mode_{i + 1}", "structural", [0, duration], [f, f], [z, z])
        for i, (f, z) in enumerate(csm.modes())
    ]
    return Scenario(
        "cobra_stick",
        "Sec. IV cobra stick model (3), open loop at 32 Hz rotor speed: 2 wideband inputs, "
        "2 accelerometers, 5 % noise, 256 Hz",
        fs,
        seed,
        {
            "/vibration": (t, y, ["acc_1", "acc_2"]),
            "/excitation": (t, u, ["shaker_1", "shaker_2"]),
            "/rotor_speed": (t_s, nr[:, None], ["rotor_speed[Hz]"]),
        },
        modes,
    )


def output_only(seed: int = 4) -> Scenario:
    """Four structural modes driven by unmeasured turbulence; 4 accelerometers, no input topic."""
    fs, duration = 100.0, 40.0
    rng = np.random.default_rng(seed)
    n = int(round(duration * fs))
    freqs = np.array([1.8, 3.4, 5.9, 8.2])
    zetas = np.array([0.02, 0.015, 0.03, 0.02])
    b = np.array([[1.0, 0.3], [0.5, 1.0], [0.8, -0.6], [0.4, 0.7]])  # two gust inputs
    shapes = 0.02 * np.array(
        [[1.0, 0.8, 0.5, 0.3], [1.0, -0.8, 0.5, -0.3], [0.6, 0.3, -1.0, 0.6], [0.2, 0.5, 0.4, 1.0]]
    )
    system = modal_system(freqs, zetas, b, shapes)
    w = wideband_input(n, 2, rng)  # turbulence, not recorded
    y = add_output_noise(simulate(system, w, fs), NOISE, rng)
    t = np.arange(n) / fs
    t_s, _ = _schedule(SCHEDULE_RATE, duration, None)
    v = 100.0 + 0.3 * rng.standard_normal(t_s.size)
    modes = [
        _mode(f"mode_{i + 1}", "structural", [0, duration], [f, f], [z, z])
        for i, (f, z) in enumerate(system.modes())
    ]
    return Scenario(
        "output_only",
        "Output-only: 4 structural modes (1.8, 3.4, 5.9, 8.2 Hz) driven by unmeasured "
        "turbulence, 4 accelerometers, 5 % noise, 100 Hz, no /excitation topic",
        fs,
        seed,
        {
            "/vibration": (
                t,
                y,
                ["wing_left_z[m/s^2]", "wing_right_z[m/s^2]", "tail_z[m/s^2]", "nacelle_z[m/s^2]"],
            ),
            "/airspeed": (t_s, v[:, None], ["airspeed[m/s]"]),
        },
        modes,
    )


SCENARIOS: dict[str, Callable[[], Scenario]] = {
    "paper_example": paper_example,
    "wing_bending_drift": wing_bending_drift,
    "cobra_stick": cobra_stick,
    "output_only": output_only,
}


def write(scn: Scenario, out: Path, storage: str = "mcap", compress: bool = True) -> Path:
    """Write ``out/<name>`` (replacing it) and ``out/<name>.truth.json``."""
    bag = out / scn.name
    if bag.exists():
        shutil.rmtree(bag)
    write_signals(
        bag,
        {topic: (T0 + t, v, names) for topic, (t, v, names) in scn.signals.items()},
        storage=storage,
        compress=compress,
    )
    (out / f"{scn.name}.truth.json").write_text(json.dumps(scn.truth(), indent=1) + "\n")
    return bag


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument(
        "names", nargs="*", metavar="NAME", help=f"of {', '.join(SCENARIOS)}; default all"
    )
    ap.add_argument("--out", type=Path, default=BAGS, help="output directory (default bags/)")
    ap.add_argument("--storage", choices=("mcap", "sqlite3"), default="mcap")
    ap.add_argument("--no-compress", action="store_true", help="plain files (for viewers)")
    args = ap.parse_args(argv)
    unknown = [n for n in args.names if n not in SCENARIOS]
    if unknown:
        ap.error(f"unknown scenario {', '.join(unknown)}; choose from {', '.join(SCENARIOS)}")
    try:
        args.out.mkdir(parents=True, exist_ok=True)
        print(f"{'bag':<20} {'duration':>9} {'messages':>9} {'size':>9}  topics")
        for name in args.names or SCENARIOS:
            scn = SCENARIOS[name]()
            bag = write(scn, args.out, args.storage, not args.no_compress)
            size = sum(p.stat().st_size for p in bag.iterdir())
            count = sum(len(t) for t, _, _ in scn.signals.values())
            print(
                f"{name:<20} {scn.duration:>8.1f}s {count:>9d} {size / 1024:>7.0f}kB  "
                + " ".join(scn.signals)
            )
    except BagError as err:
        print(f"generate_bags: error: {err}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
