"""Cost of the scenario generators (sysid_node.scenarios) that the randomized suites call.

    ros2_ws/env python benchmarks/bench_scenarios.py [--seeds 5] [--duration 40]

Per generator: wall time per draw over ``--seeds`` seeds (median and worst), samples per draw
(median) and samples per millisecond. The draws' rate and size are drawn from the seed; the
record length is ``--duration`` seconds (drifting_mode: 60 s, its default). One BLAS thread.
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[_var] = "1"

import argparse  # noqa: E402
import statistics  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402

import numpy as np  # noqa: E402
from sysid_node.scenarios import (  # noqa: E402
    EFFECTS,
    draw_clean,
    draw_hidden_effect,
    draw_modal_scenario,
    drifting_mode,
)
from sysid_node.scenarios.bags import (  # noqa: E402
    BAG_SCENARIOS,
    HIDDEN_SCENARIOS,
    HIDDEN_SEEDS,
    hidden_effect,
)


def timed(fn, seeds: int) -> tuple[list[float], list[int]]:
    walls, sizes = [], []
    for seed in range(seeds):
        t0 = time.perf_counter()
        out = fn(np.random.default_rng(seed))
        walls.append(time.perf_counter() - t0)
        sizes.append(int(np.asarray(out.y).shape[0]))
    return walls, sizes


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=5)
    ap.add_argument("--duration", type=float, default=40.0, help="record length [s]")
    args = ap.parse_args(argv)
    if args.seeds < 1 or args.duration <= 0:
        print("bench_scenarios: error: --seeds >= 1 and --duration > 0", file=sys.stderr)
        return 1
    d = args.duration
    cases = [
        ("draw_modal_scenario", lambda r: draw_modal_scenario(r, duration_s=d)),
        ("drifting_mode", lambda r: drifting_mode(r)),
        ("draw_clean", lambda r: draw_clean(r, duration_s=d)),
        *((f"draw_hidden_effect {e}", lambda r, e=e: draw_hidden_effect(e, r, duration_s=d))
          for e in EFFECTS),
    ]
    print(f"{'generator':<42} {'median ms':>10} {'worst ms':>9} {'samples':>8} {'smp/ms':>7}")
    for name, fn in cases:
        walls, sizes = timed(fn, args.seeds)
        med = statistics.median(walls) * 1e3
        n = statistics.median(sizes)
        print(f"{name:<42} {med:>10.1f} {max(walls) * 1e3:>9.1f} {n:>8.0f} {n / med:>7.0f}")
    for name, fn in BAG_SCENARIOS.items():
        t0 = time.perf_counter()
        out = fn()
        wall = (time.perf_counter() - t0) * 1e3
        n = out.signals["/vibration"][1].shape[0]
        print(f"{'bag ' + name:<42} {wall:>10.1f} {wall:>9.1f} {n:>8d} {n / wall:>7.0f}")
    for name in HIDDEN_SCENARIOS:
        t0 = time.perf_counter()
        out = hidden_effect(name, HIDDEN_SEEDS[name])
        wall = (time.perf_counter() - t0) * 1e3
        n = out.y.shape[0]
        print(f"{'bag hidden/' + name:<42} {wall:>10.1f} {wall:>9.1f} {n:>8d} {n / wall:>7.0f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
