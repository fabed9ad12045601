"""Online identification of the real steel frame (issue #10 item 6): ``../shared/realdata/
steel_frame`` setups 1 and 8 (5 channels at 256 Hz, output-only ambient, 240 s) through the
node's own ``Pipeline`` (what ``ros2_ws/run sysid_node offline`` and the live node drive),
once with ``freq_max: 12, max_modes: 10`` and once with all defaults (only ``output_only``).

Per setup and case, one row per reference mode: the error of the nearest tracked mode in the
final estimate, the share of the estimates of the last 120 s with a tracked mode within 1 %,
and the data time of the first estimate with one within 1 %; then the tracked count and the
false tracked count (farther than 2 % from every reference mode) per estimate after 30 s.

    ros2_ws/env python benchmarks/steel_frame_online.py [--setups 1 8] [--cases a b]

Exits with a message when the data are absent. Wall time is printed for information only
(contaminated by the machine's load).
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np
from sysid_node.suite import T0_NS as T0
from sysid_node.suite import run_output_only

ROOT = Path(__file__).resolve().parents[1].parent / "shared" / "realdata" / "steel_frame"
REFERENCE_HZ = np.array([1.229, 1.436, 2.100, 4.017, 4.769, 6.683, 7.616, 9.664])
FS = 256.0
CASES = {"a": {"freq_max": 12.0, "max_modes": 10}, "b": {}}


def load(setup: int) -> np.ndarray | None:
    path = ROOT / f"measurement_{setup}" / f"measurement_{setup}.npy"
    return np.load(path)[:, :5] if path.is_file() else None


def run(y: np.ndarray, params: dict, block: int = 64) -> tuple[list, list[str]]:
    """Records of the pipeline over ``y`` pushed in messages of ``block`` samples."""
    logs: list[str] = []
    _, recs = run_output_only(y, FS, params, block, logs.append)
    return recs, logs


def tracked(r) -> np.ndarray:
    return np.array([m.frequency_hz for m in r.modes if m.status == "tracked"])


def errors(freqs: np.ndarray) -> np.ndarray:
    """Relative error of the nearest of ``freqs`` to each reference mode (inf when none)."""
    if freqs.size == 0:
        return np.full(REFERENCE_HZ.size, np.inf)
    return np.min(np.abs(freqs[None, :] / REFERENCE_HZ[:, None] - 1), axis=1)


def table(recs: list) -> dict:
    t = np.array([(r.stamp_ns - T0) * 1e-9 for r in recs])
    err = np.array([errors(tracked(r)) for r in recs])
    ok = err <= 0.01
    late = t >= t[-1] - 120.0
    after = t >= 30.0
    first = [float(t[np.argmax(ok[:, k])]) if ok[:, k].any() else float("nan")
             for k in range(REFERENCE_HZ.size)]
    false = [int(np.sum(errors_from(tracked(r)) > 0.02)) for r, a in zip(recs, after,
                                                                        strict=True) if a]
    ntr = [tracked(r).size for r, a in zip(recs, after, strict=True) if a]
    return {"final_err": err[-1], "late_share": ok[late].mean(axis=0), "first_s": first,
            "tracked_max": max(ntr), "ref_min": int(ok[after].sum(axis=1).min()),
            "false_mean": float(np.mean(false)), "false_max": max(false),
            "final_tracked": tracked(recs[-1])}


def errors_from(freqs: np.ndarray) -> np.ndarray:
    """Relative distance of each of ``freqs`` to the nearest reference mode."""
    if freqs.size == 0:
        return np.zeros(0)
    return np.min(np.abs(freqs[:, None] / REFERENCE_HZ[None, :] - 1), axis=1)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--setups", type=int, nargs="+", default=[1, 8])
    ap.add_argument("--cases", nargs="+", default=list(CASES), choices=list(CASES))
    a = ap.parse_args()
    for setup in a.setups:
        y = load(setup)
        if y is None:
            print(f"steel frame setup {setup} not found under {ROOT}")
            return
        for case in a.cases:
            t0 = time.perf_counter()
            recs, logs = run(y, CASES[case])
            wall = time.perf_counter() - t0
            s = table(recs)
            name = "freq_max 12, max_modes 10" if case == "a" else "defaults"
            print(f"\nsetup {setup}, case ({case}) {name}: {len(recs)} estimates, wall "
                  f"{wall:.0f} s; band log: "
                  + "; ".join(m for m in logs if "band" in m and "started" not in m))
            print(f"{'ref [Hz]':>9} {'final err %':>12} {'last 120 s within 1 %':>22} "
                  f"{'first within 1 % [s]':>21}")
            for k, f in enumerate(REFERENCE_HZ):
                e = s["final_err"][k]
                print(f"{f:9.3f} {100 * e:12.3f} {s['late_share'][k]:22.2f} "
                      f"{s['first_s'][k]:21.1f}")
            print(f"after 30 s: tracked max {s['tracked_max']}, reference modes within 1 % "
                  f"min {s['ref_min']}, false tracked (> 2 % from every reference) mean "
                  f"{s['false_mean']:.2f} max {s['false_max']}; final tracked "
                  f"{np.round(np.sort(s['final_tracked']), 3).tolist()}")


if __name__ == "__main__":
    main()
