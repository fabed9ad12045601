"""Endurance of sysid_node's processing: a long run (drift, then steady) with memory and accuracy.

Feeds the pure pipeline (what the node's worker and ``offline`` run) with a 2-mode structure
(the paper's Sec. II example) whose first mode drifts by ``--drift`` (relative) over the first
half of the run and then stays put, in blocks as the node receives them, as fast as possible,
and prints one table row per tenth of the run: data time, resident memory (RSS) of the process,
Python heap in use (tracemalloc, with ``--heap``), estimated frequencies against the truth,
wall time. At the end: RSS growth over the second half, and the final modes' errors (the issue
asks < 2 %).

    ros2_ws/env python benchmarks/endurance.py              # full hour of data (several minutes)
    ros2_ws/env python benchmarks/endurance.py --hours 0.05  # smoke run (CI-sized)

The data are simulated in pieces (the state carried over), so memory does not grow with the
length of the run either.
"""

from __future__ import annotations

import argparse
import math
import resource
import sys
import time
import tracemalloc
from pathlib import Path

import numpy as np
from scipy import signal

FS = 100.0
F1, F2, ZETA = 2.0, 4.0, 0.02


def rss_mb() -> float:
    """Resident set size now [MB] (/proc; ru_maxrss is a peak)."""
    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith("VmRSS:"):
                return float(line.split()[1]) / 1024.0
    except OSError:
        pass
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


class Structure:
    """Two modes (f1 drifting, f2 fixed) driven by white noise, simulated piece by piece."""

    def __init__(self, seed: int = 0) -> None:
        self.rng = np.random.default_rng(seed)
        self.zi: list[np.ndarray | None] = [None, None]

    def piece(self, n: int, f1: float) -> tuple[np.ndarray, np.ndarray]:
        u = self.rng.standard_normal(n)
        y = np.zeros(n)
        for k, f in enumerate((f1, F2)):
            w = 2 * math.pi * f / FS
            r = math.exp(-ZETA * w)
            a = [1.0, -2 * r * math.cos(w * math.sqrt(1 - ZETA**2)), r * r]
            b = [0.0, (1 - r) ** 2]
            if self.zi[k] is None:
                self.zi[k] = np.zeros(2)
            out, self.zi[k] = signal.lfilter(b, a, u, zi=self.zi[k])
            y += out * (1.0 if k == 0 else 0.7)
        y += 0.02 * np.std(y) * self.rng.standard_normal(n)
        return u[:, None], y[:, None]


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--hours", type=float, default=1.0, help="data time [h] (default 1)")
    ap.add_argument("--drift", type=float, default=0.1,
                    help="relative drift of the first mode over the first half (default 0.1)")
    ap.add_argument("--block", type=int, default=10, help="samples per message block")
    ap.add_argument("--heap", action="store_true",
                    help="also trace the Python heap (tracemalloc; slows the run several times)")
    args = ap.parse_args()
    from sysid_node.pipeline import Pipeline

    total = int(args.hours * 3600 * FS)
    piece = int(10 * FS)  # simulate 10 s at a time
    rows = 10
    pl = Pipeline({"sample_rate": FS, "freq_max": 10.0, "residual_spectrum_rate": 0.0})
    sim = Structure()
    t0_ns = 1_700_000_000 * 10**9
    if args.heap:
        tracemalloc.start()
    wall0 = time.perf_counter()
    print(f"endurance: {args.hours:g} h of data at {FS:g} Hz, mode 1 drifts {F1:g} -> "
          f"{F1 * (1 + args.drift):g} Hz over the first half, mode 2 at {F2:g} Hz")
    head = (f"{'data h':>7}{'RSS MB':>8}{'heap MB':>9}{'f1 true':>9}{'f1 est':>9}{'err %':>7}"
            f"{'f2 est':>9}{'err %':>7}{'wall s':>8}")
    print(head)
    print("-" * len(head))
    rss_half = math.nan
    last = None
    done = 0
    next_row = total // rows
    while done < total:
        n = min(piece, total - done)
        frac = min(done / max(total / 2, 1), 1.0)
        f1 = F1 * (1 + args.drift * frac)
        u, y = sim.piece(n, f1)
        stamps = t0_ns + np.round((done + np.arange(n)) * 1e9 / FS).astype(np.int64)
        for a in range(0, n, args.block):
            pl.push_output(stamps[a:a + args.block], y[a:a + args.block])
            pl.push_input(stamps[a:a + args.block], u[a:a + args.block])
            recs = pl.step()
            if recs:
                last = recs[-1]
        done += n
        if done >= next_row or done >= total:
            next_row += total // rows
            if done >= total / 2 and math.isnan(rss_half):
                rss_half = rss_mb()
            heap = tracemalloc.get_traced_memory()[0] / 1e6 if args.heap else math.nan
            est1 = est2 = e1 = e2 = math.nan
            if last is not None and last.modes:
                est1 = min((m.frequency_hz for m in last.modes), key=lambda f: abs(f - f1))
                est2 = min((m.frequency_hz for m in last.modes), key=lambda f: abs(f - F2))
                e1, e2 = abs(est1 - f1) / f1, abs(est2 - F2) / F2
            print(f"{done / FS / 3600:>7.3f}{rss_mb():>8.1f}{heap:>9.1f}{f1:>9.3f}{est1:>9.3f}"
                  f"{100 * e1:>7.2f}{est2:>9.3f}{100 * e2:>7.2f}"
                  f"{time.perf_counter() - wall0:>8.0f}", flush=True)
    end_rss = rss_mb()
    ok = last is not None and e1 < 0.02 and e2 < 0.02
    print(f"RSS growth over the steady second half: {end_rss - rss_half:+.1f} MB "
          f"({rss_half:.1f} -> {end_rss:.1f}); final errors {100 * e1:.2f} % / {100 * e2:.2f} % "
          f"({'within' if ok else 'NOT within'} 2 %); counters {pl.counters}")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
