"""Cost of the mode tracker per realization (``core.tracking.ModeTracker.update``: matching,
status rules, ranking) inside the node's own ``Pipeline`` on drawn random-suite scenarios.

Per draw: sample rate, outputs, tracker updates, stable modes offered per update, and thread CPU
time per update (median and 95th percentile over the updates, ms). The tracker runs once per
realization (``realization_rate_hz``), so per second of data it costs updates/s x ms/update.

    ros2_ws/env python benchmarks/bench_tracker.py [--seeds 16 27 30 1 12] [--seconds 30]

Thread CPU time excludes other processes' load but not cache effects: compare runs made on
the same machine state. Figures for information; nothing is asserted.
"""

from __future__ import annotations

import argparse
import time

import numpy as np
from sysid_node.core import tracking
from sysid_node.scenarios import draw_modal_scenario
from sysid_node.suite import run_pipeline

_TIMES: list[tuple[float, int]] = []
_update = tracking.ModeTracker.update


def _timed_update(self, modes, t, excited=None):
    """ModeTracker.update, timed (thread CPU time) into _TIMES."""
    t0 = time.thread_time()
    out = _update(self, modes, t, excited)
    _TIMES.append((time.thread_time() - t0, sum(1 for m in modes if m.stable)))
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, nargs="+", default=[16, 27, 30, 1, 12])
    ap.add_argument("--seconds", type=float, default=30.0)
    args = ap.parse_args()
    tracking.ModeTracker.update = _timed_update
    print(f"{'seed':>4} {'fs [Hz]':>8} {'outputs':>7} {'updates':>7} {'modes/upd':>9} "
          f"{'p50 [ms]':>8} {'p95 [ms]':>8}")
    every = []
    for seed in args.seeds:
        scn = draw_modal_scenario(np.random.default_rng(seed), duration_s=args.seconds)
        _TIMES.clear()
        run_pipeline(scn)
        ms = 1e3 * np.array([t for t, _ in _TIMES])
        every.append(ms)
        modes = np.mean([n for _, n in _TIMES]) if _TIMES else float("nan")
        p50, p95 = (np.percentile(ms, [50, 95]) if ms.size else (float("nan"),) * 2)
        print(f"{seed:4d} {scn.fs:8.0f} {scn.y.shape[1]:7d} {len(_TIMES):7d} {modes:9.1f} "
              f"{p50:8.3f} {p95:8.3f}")
    ms = np.concatenate(every) if every else np.zeros(0)
    if ms.size:
        p50, p95 = np.percentile(ms, [50, 95])
        print(f"{'all':>4} {'':>8} {'':>7} {ms.size:7d} {'':>9} {p50:8.3f} {p95:8.3f}")


if __name__ == "__main__":
    main()
