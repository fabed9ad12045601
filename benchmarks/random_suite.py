"""Randomized identification suite (issue #10): the sysid pipeline with DEFAULT parameters on
drawn modal records (``scenarios.draw_modal_scenario``: 100-1000 Hz, 1-8 modes, 1-3 outputs,
input-output or output-only, half of them with a mode appearing or jumping at 40-60 %).

Prints one row per draw and the aggregate rates (definitions: ``sysid_node/suite.py``).

    ros2_ws/env python benchmarks/random_suite.py [--draws 50] [--first-seed 0] [--duration 30]
        [--json FILE]

Wall-clock time per draw is printed for information only (contaminated by the machine's load).
"""

from __future__ import annotations

import argparse
import json
import time
from dataclasses import asdict

from sysid_node.suite import DURATION_S, run_draw, summary


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--draws", type=int, default=50)
    ap.add_argument("--first-seed", type=int, default=0)
    ap.add_argument("--duration", type=float, default=DURATION_S)
    ap.add_argument("--json", default="")
    a = ap.parse_args()
    head = ("seed", "fs", "modes", "out", "oo", "change", "2%@3s", "1%@3s", "t_all",
            "false_mean", "false_max", "settled", "pickup_s", "after", "kept", "wall_s")
    print(" ".join(f"{h:>10}" for h in head), flush=True)
    results = []
    for seed in range(a.first_seed, a.first_seed + a.draws):
        t0 = time.perf_counter()
        r = run_draw(seed, duration_s=a.duration)
        wall = time.perf_counter() - t0
        results.append(r)
        row = (r.seed, f"{r.fs:.0f}", r.n_modes, r.n_outputs, int(r.output_only), r.change,
               int(r.found_by_3s), int(r.found_1pct_by_3s), f"{r.time_all_s:.2f}",
               f"{r.false_mean:.2f}", r.false_max, f"{r.settled_share:.2f}",
               f"{r.pickup_s:.2f}", f"{r.after_share:.2f}", f"{r.kept_share:.2f}",
               f"{wall:.1f}")
        print(" ".join(f"{x!s:>10}" for x in row), flush=True)
    s = summary(results)
    print()
    for k, v in s.items():
        print(f"{k:>26}: {v:.3f}" if isinstance(v, float) else f"{k:>26}: {v}")
    if a.json:
        with open(a.json, "w") as fh:
            json.dump({"summary": s, "draws": [asdict(r) for r in results]}, fh, indent=1,
                      default=float)


if __name__ == "__main__":
    main()
