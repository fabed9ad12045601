"""Table 1 / Fig. 3 of the paper: the modified Prony method (industry practice) against the batch
DSRA on sine-dwell and sine-sweep tests of the V-22-like wing (``scenarios/v22_wing.py``).

    ros2_ws/env python benchmarks/prony_vs_dsra.py [--runs 10] [--turbulence 0.1] [--noise 0.05]

Per airspeed, ``--runs`` repeated flight tests (new turbulence and sensor noise each):

* sine dwell at the symmetric wing beam (SWB; and the wing torsion, SWT, at 150 kn), 8 s, then
  12 s of free decay. Prony (modified, order 6, common poles of the two wing-tip
  accelerometers) on the decay; DSRA (batch, input-output, order 6, all three accelerometers)
  on the whole record. One dwell gives one mode.
* one sine sweep 0.5 -> 8 Hz over 60 s, then 10 s of decay. DSRA on the whole record gets every
  mode of the band at once; Prony has no free decay of each mode (N/A), and on the decay after
  the sweep it finds what rang last.

Prints frequency and damping as mean (empirical standard deviation) over the runs, like Table
1, with the truth and the number of runs in which the mode was found (within 10 % of the true
frequency), and the cost per fit. Timings on a shared machine are indicative only.
"""

from __future__ import annotations

import argparse
import sys
import time

import numpy as np
from sysid_node.core import identify
from sysid_node.core.inputs import InputError
from sysid_node.core.prony import prony
from sysid_node.scenarios.v22_wing import sine_dwell_test, sine_sweep_test

AIRSPEEDS = (150.0, 200.0, 250.0)
BAND = (0.5, 8.0)


def nearest(modes, f_true: float):
    """(f, zeta) of the mode nearest ``f_true`` if within 10 %, else None."""
    if not modes:
        return None
    m = min(modes, key=lambda x: abs(x.frequency_hz - f_true))
    return (m.frequency_hz, m.damping_ratio) if abs(m.frequency_hz / f_true - 1) < 0.1 else None


def stats(found: list) -> str:
    ok = np.array([x for x in found if x is not None])
    if ok.size == 0:
        return f"{'not found':>27s} {0:>3d}/{len(found)}"
    f, z = ok[:, 0], 100 * ok[:, 1]
    return (f"{f.mean():6.3f} ({f.std():.3f}) {z.mean():6.2f} ({z.std():.2f})"
            f" {len(ok):>3d}/{len(found)}")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=10)
    ap.add_argument("--turbulence", type=float, default=0.1)
    ap.add_argument("--noise", type=float, default=0.05)
    args = ap.parse_args(argv)
    rng = np.random.default_rng(2004)
    cost = {"prony": [], "dsra_dwell": [], "dsra_sweep": []}
    print(f"Table 1 analogue: {args.runs} runs per test, turbulence {args.turbulence:g}, sensor "
          f"noise {100 * args.noise:g} %; frequency [Hz] (std), damping [%] (std), runs found")
    head = f"{'mode':<5s}{'airspeed':>9s}  {'method':<28s}"
    print(head + f"{'sine dwell':>37s}   {'sine sweep':>37s}")
    cases = [(kn, "SWB") for kn in AIRSPEEDS] + [(150.0, "SWT")]
    sweep_by_kn: dict[float, dict] = {}
    for kn in AIRSPEEDS:  # one sweep per test gives every mode
        res = {"dsra": {"SWB": [], "SWT": []}, "prony": {"SWB": [], "SWT": []}}
        for _ in range(args.runs):
            t = sine_sweep_test(kn, rng, turbulence=args.turbulence, noise=args.noise)
            t0 = time.perf_counter()
            model = identify(t.y, t.u, fs=t.fs, order=6, block_rows=20, band=BAND)
            cost["dsra_sweep"].append(time.perf_counter() - t0)
            for name in res["dsra"]:
                res["dsra"][name].append(nearest(model.modes, t.truth[name][0]))
            try:
                pr = prony(t.y[t.decay_start + 10 :, :2], t.fs, 6, band=BAND)
                pm = pr.modes
            except InputError:
                pm = []
            for name in res["prony"]:
                res["prony"][name].append(nearest(pm, t.truth[name][0]))
        sweep_by_kn[kn] = res
    for kn, mode in cases:
        prony_dwell, dsra_dwell = [], []
        truth = None
        for _ in range(args.runs):
            t = sine_dwell_test(kn, rng, mode=mode, turbulence=args.turbulence, noise=args.noise)
            truth = t.truth[mode]
            t0 = time.perf_counter()
            try:
                pr = prony(t.y[t.decay_start + 10 :, :2], t.fs, 6,
                           band=(0.75 * truth[0], 1.25 * truth[0]))
                prony_dwell.append(nearest(pr.modes, truth[0]))
            except InputError:
                prony_dwell.append(None)
            cost["prony"].append(time.perf_counter() - t0)
            t0 = time.perf_counter()
            model = identify(t.y, t.u, fs=t.fs, order=6, block_rows=20, band=BAND)
            cost["dsra_dwell"].append(time.perf_counter() - t0)
            dsra_dwell.append(nearest(model.modes, truth[0]))
        sw = sweep_by_kn[kn]
        print(f"{mode:<5s}{kn:>6.0f} kn  {'truth':<28s}{truth[0]:>9.3f}{100 * truth[1]:>15.2f}"
              f"{'':>13s}   {truth[0]:>9.3f}{100 * truth[1]:>15.2f}")
        print(f"{'':14s}  {'Prony (decay, wing tips)':<28s}{stats(prony_dwell):>37s}   "
              f"{'N/A; after the sweep: ' + stats(sw['prony'][mode]).split()[-1]:>37s}")
        print(f"{'':14s}  {'DSRA (record, 3 acc.)':<28s}{stats(dsra_dwell):>37s}   "
              f"{stats(sw['dsra'][mode]):>37s}")
    found = [sum(sweep_by_kn[k]["dsra"][n][i] is not None for n in ("SWB", "SWT"))
             for k in AIRSPEEDS for i in range(args.runs)]
    print(f"\nstructural modes per experiment: sine dwell 1 (one dwell per mode); sine sweep "
          f"{np.mean(found):.2f} of 2 (SWB and SWT) with DSRA")
    print("cost per fit [ms] (shared machine): " + ", ".join(
        f"{k} {1e3 * np.median(v):.1f}" for k, v in cost.items()))
    return 0


if __name__ == "__main__":
    sys.exit(main())
