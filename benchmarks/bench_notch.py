"""Cost per sample of the adaptive notch bank (6 channels x 5 notches) and the highest sample rate
it sustains on one core, for several block sizes, with the notches fixed and while all of them
retune; then the cost of the width design and the other per-event paths.

    ros2_ws/env python benchmarks/bench_notch.py [--fs 1000] [--seconds 0.4] [--substep 8]

Cost = wall time of AdaptiveNotchFilter.process (policy + bank) per sample of all channels,
median of 5 repeats; "max rate" = 1 / cost: the highest sample rate one core doing nothing else
sustains at that block size ("retuning" = all five notches slewing all the time, each estimate
moving every centre, so every estimate re-designs every width).

Second table (median of 20 calls): the width design of 1 and 5 notches (resonance.design_zp over
the uncertainty region), a whole estimate through the policy (mode models, design, budget), the
peak reductions the node publishes with every /notch_bank (whole bank x each mode's region), the
phase lag of the bank, and the node's per-message stamp/rate check.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time

import numpy as np
from notch_filter_node.adaptive import AdaptiveNotchFilter
from notch_filter_node.policy import EstimateInput, ModeInput, PolicyConfig

CHANNELS, NOTCHES = 6, 5
MODES_HZ = (3.0, 6.0, 9.0, 12.0, 15.0)
BLOCKS = (1, 8, 32, 128, 512)


def estimate(t: float, retune: bool, k: int) -> EstimateInput:
    shift = (0.5 if k % 2 else -0.5) if retune else 0.0
    modes = [ModeInput(i + 1, "tracked", f + shift, 0.01, 0.02, 0.003)
             for i, f in enumerate(MODES_HZ)]
    return EstimateInput(t, True, modes)


def measure(
    fs: float, block: int, retune: bool, seconds: float, seed: int = 0, substep: int = 8
) -> float:
    """Seconds of wall time per sample (all channels)."""
    cfg = PolicyConfig(max_notches=NOTCHES, slew_rate=2.0, phase_lag_budget=180.0,
                       fallback_depth=0.0, stale_timeout=100.0)
    flt = AdaptiveNotchFilter(cfg, fs, CHANNELS, substep)
    rng = np.random.default_rng(seed)
    n = max(int(seconds * fs) // block, 20) * block
    x = rng.normal(size=(n, CHANNELS))
    flt.set_estimate(estimate(0.0, retune, 0))
    warm = int(2 * fs)  # notches faded in before timing
    xw = rng.normal(size=(warm, CHANNELS))
    for a in range(0, warm, 64):
        flt.process(xw[a : a + 64], (a + 63) / fs)
    k, next_est = 1, 0.2
    elapsed = 0.0
    for a in range(0, n, block):
        t_last = (warm + a + block - 1) / fs
        t0 = time.perf_counter()
        if t_last >= next_est:
            flt.set_estimate(estimate(t_last, retune, k))
            k, next_est = k + 1, next_est + 0.2
        flt.process(x[a : a + block], t_last)
        elapsed += time.perf_counter() - t0
    active = len({n.mode_id for n in flt.status().notches})  # a pair is one notch
    if active != NOTCHES:
        raise SystemExit(f"bench_notch: error: {active} notches active, expected {NOTCHES}")
    return elapsed / n


def per_event(fs: float) -> list[tuple[str, float]]:
    """Median wall time [us] of the per-event paths (see the module docstring)."""
    import math

    from notch_filter_node.stream import StampCheck

    from notch_filter_node import resonance as R
    from notch_filter_node import sections as S

    def median_us(fn, n: int = 20) -> float:
        times = []
        for _ in range(n):
            t0 = time.perf_counter()
            fn()
            times.append(time.perf_counter() - t0)
        return 1e6 * statistics.median(times)

    rows = []
    for k in (1, NOTCHES):
        f = np.array(MODES_HZ[:k])
        zp_min, _ = S.pole_zero_damping(f, 0.05, 30.0, fs)
        zp_max, _ = S.pole_zero_damping(f, 5.0, 30.0, fs)
        rows.append((f"width design, {k} notch(es)", median_us(lambda f=f, a=zp_min, b=zp_max: (
            R.design_zp(f, 0.99 * f, 1.01 * f, np.full(f.size, 0.03), 15.0, 30.0, fs, a, b,
                        zeta_c=np.full(f.size, 0.02))))))
        zp, _ = R.design_zp(f, 0.99 * f, 1.01 * f, np.full(f.size, 0.03), 15.0, 30.0, fs, zp_min,
                            zp_max, zeta_c=np.full(f.size, 0.02))
        rows.append((f"pair design, {k} notch(es)", median_us(lambda f=f, zp=zp: (
            R.design_pair(f, 0.99 * f, 1.01 * f, np.full(f.size, 0.03), 15.0, 30.0, fs, zp, 0.5,
                          zeta_c=np.full(f.size, 0.02))))))
    cfg = PolicyConfig(max_notches=NOTCHES, phase_lag_budget=180.0, fallback_depth=0.0,
                       stale_timeout=100.0, fallback_timeout=200.0)
    flt = AdaptiveNotchFilter(cfg, fs, CHANNELS)
    counter = iter(range(10**9))

    def one_estimate() -> None:
        k = next(counter)
        flt.set_estimate(estimate(0.1 * k, True, k))

    rows.append((f"an estimate through the policy ({NOTCHES} modes, all moved)",
                 median_us(one_estimate)))
    last = flt.policy.estimate.stamp
    flt.process(np.zeros((int(2 * fs), CHANNELS)), last + 0.05)  # notches faded in
    if len({n.mode_id for n in flt.status().notches}) != NOTCHES:
        raise SystemExit("bench_notch: error: the notches did not come up for the second table")
    rows.append(("peak reductions for /notch_bank (whole bank)", median_us(flt.peak_reductions)))
    rows.append(("phase lag of the bank", median_us(flt.phase_lag)))
    chk = StampCheck()
    ns = iter(range(0, 10**15, int(1e9 / fs)))

    def stamp() -> None:
        t = next(ns)
        chk.check(t)
        chk.accept(t, 1)
        if not math.isnan(chk.rate()):
            pass

    rows.append(("stamp order + rate check, per message", median_us(stamp, 200)))
    return rows


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--fs", type=float, default=1000.0, help="sample rate of the data [Hz]")
    ap.add_argument("--seconds", type=float, default=0.4, help="data per repeat [s]")
    ap.add_argument("--substep", type=int, default=8,
                    help="samples per coefficient step while notches move (node: substep)")
    args = ap.parse_args(argv)
    if args.substep < 1:
        print("bench_notch: error: --substep must be at least 1", file=sys.stderr)
        return 1
    if not args.fs > 2 * max(MODES_HZ) / 0.4:
        print(f"bench_notch: error: --fs must exceed {2 * max(MODES_HZ) / 0.4:g} Hz",
              file=sys.stderr)
        return 1
    print(f"adaptive notch bank: {CHANNELS} channels x {NOTCHES} notches, fs = {args.fs:g} Hz, "
          f"substep {args.substep}, policy + bank, median of 5 repeats")
    print(f"{'block':>6} {'notches':>9} {'us/sample':>10} {'us/ch-sample':>13} "
          f"{'us/block':>10} {'max rate [kHz]':>15}")
    for retune in (False, True):
        for block in BLOCKS:
            cost = statistics.median(
                measure(args.fs, block, retune, args.seconds, seed, args.substep)
                for seed in range(5)
            )
            print(f"{block:>6} {'retuning' if retune else 'fixed':>9} {cost * 1e6:>10.2f} "
                  f"{cost * 1e6 / CHANNELS:>13.2f} {cost * 1e6 * block:>10.1f} "
                  f"{1e-3 / cost:>15.1f}")
    print(f"\nper event (fs = {args.fs:g} Hz), median of 20 calls")
    for label, us in per_event(args.fs):
        print(f"  {label:<58}{us:>10.1f} us")
    return 0


if __name__ == "__main__":
    sys.exit(main())
