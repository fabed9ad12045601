"""Flight-control loop margins on the drifting wing: adaptive notch bank vs the static notch that
covers the same drift vs no notch (#16 item 4), with python-control (``core/loop_analysis.py``).

    ros2_ws/env python benchmarks/loop_margins_wing.py [--figure out/loop_margins.png]

The loop (negative feedback): controller -> notch bank -> plant. Plant: a representative
rigid-body attitude response (short-period-like 1.5 Hz, 70 % damped, integrated; actuator lag
20 ms) plus what the
sensor sees of the structure: the symmetric wing beam (SWB, drifting 2.6 -> 3.0 Hz with
airspeed as in ``bags/wing_bending_drift``, true frequency and damping over time) and the wing
torsion (5.18 Hz), with modal gains set so that without a notch the SWB peak of the loop is
+6 dB at the start (the torsion -6 dB). Controller: PI, crossover 0.5 Hz (the
notch node's ``crossover_frequency``). Notches: the adaptive bank driven by the real
identification of the bag (``sysid_node`` processing, the main job's YAML, as in
``wing_notch_figures.py``), the static notch that guarantees the same peak reduction over the
whole 2.6-3.0 Hz drift (``resonance.guaranteeing_notch``, the notch node's ``peak_reduction``
and ``depth``), and none.

Prints margins every 5 s and their worst case over the drift (10-60 s): phase margin at the
crossover, smallest |phase margin| over all gain crossings, gain margin, closed-loop stability
and the notch's phase lag at the crossover.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import control as ct
import numpy as np
import yaml
from notch_filter_node.adaptive import AdaptiveNotchFilter
from sysid_node.core.loop_analysis import loop_margins
from wing_notch_figures import CONFIG, estimates

from notch_filter_node import params as NP
from notch_filter_node import resonance as R
from notch_filter_node import sections as S

REPO = Path(__file__).resolve().parents[1]
BLOCK = 5  # samples per bank call
CROSSOVER_HZ = 0.5


def rigid_plant() -> ct.TransferFunction:
    """Attitude response to the command: short-period-like 1.5 Hz, 70 % damped, integrated,
    20 ms actuator lag."""
    w = 2 * np.pi * 1.5
    return ct.tf([w * w], [1.0, 1.4 * w, w * w]) * ct.tf([1.0], [1.0, 0.0]) * ct.tf(
        [1.0], [0.02, 1.0])


def controller() -> ct.TransferFunction:
    """PI controller (integral corner 0.1 Hz), gain set for a 0.5 Hz crossover."""
    pi = ct.tf([1.0, 2 * np.pi * 0.1], [1.0, 0.0])
    mag = abs(complex(np.asarray((pi * rigid_plant()).frequency_response(
        [2 * np.pi * CROSSOVER_HZ]).complex).ravel()[0]))
    return pi * (1.0 / mag)


def mode_tf(f_hz: float, zeta: float) -> ct.TransferFunction:
    w = 2 * np.pi * f_hz
    return ct.tf([w * w], [1.0, 2 * zeta * w, w * w])


def plant_at(f_swb: float, z_swb: float, g_swb: float, g_swt: float,
             swt=(5.18, 0.0458)) -> ct.TransferFunction:
    return rigid_plant() + g_swb * mode_tf(f_swb, z_swb) + g_swt * mode_tf(*swt)


def peak_gain(sys: ct.LTI, f_hz: float) -> float:
    return abs(complex(np.asarray(sys.frequency_response([2 * np.pi * f_hz]).complex).ravel()[0]))


def _summary(span: str, rows: list[dict]) -> None:
    print(f"\n{span}, worst case:")
    for name in ("adaptive", "static", "none"):
        ms = [r[name] for r in rows]
        ok = [m for m in ms if m.stable]
        if not ok:
            print(f"  {name:<9s} stable 0/{len(ms)}")
            continue
        print(f"  {name:<9s} stable {len(ok)}/{len(ms)}, phase margin at crossover min "
              f"{min(m.phase_margin_deg for m in ok):.2f} deg, smallest |PM| over all crossings "
              f"{min(m.min_phase_margin_deg for m in ok):.2f} deg, gain margin min "
              f"{min(m.gain_margin_db for m in ok):.2f} dB, notch lag at crossover max "
              f"{max(m.notch_phase_lag_deg for m in ms):.3f} deg")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--bag", type=Path, default=REPO / "bags" / "wing_bending_drift")
    ap.add_argument("--figure", type=Path, default=None, help="write PM/GM over time (PNG)")
    args = ap.parse_args(argv)
    truth = json.loads(args.bag.with_name(args.bag.name + ".truth.json").read_text())
    fs, duration = float(truth["sample_rate_hz"]), float(truth["duration_s"])
    est = estimates(args.bag, float(truth["start_time_s"]))
    doc = yaml.safe_load(CONFIG.read_text())
    section = next(v for k, v in doc.items() if k.endswith("notch_filter_node"))  # "/**/..."
    values = {**NP.defaults(), **section["ros__parameters"]}
    cfg = NP.policy_config(values)
    swb = next(m for m in truth["modes"] if m["name"] == "symmetric_wing_beam")

    def swb_at(t: float) -> tuple[float, float]:
        return (float(np.interp(t, swb["t_s"], swb["frequency_hz"])),
                float(np.interp(t, swb["t_s"], swb["damping_ratio"])))

    c = controller()
    f0, z0 = swb_at(0.0)
    g_swb = 2.0 / peak_gain(c * mode_tf(f0, z0), f0)  # +6 dB SWB peak without a notch
    g_swt = 0.5 / peak_gain(c * mode_tf(5.18, 0.0458), 5.18)  # -6 dB

    filt = AdaptiveNotchFilter(cfg, fs, 1)
    static = R.guaranteeing_notch(min(swb["frequency_hz"]), max(swb["frequency_hz"]),
                                  max(swb["damping_ratio"]), cfg.peak_reduction, cfg.depth, fs)
    static_sos = S.notch_sos(static.center, static.bandwidth, static.depth_db, fs)
    times = np.arange(0.5, duration + 1e-9, 0.5)
    rows = []
    k, t_next = 0, 0
    zeros = np.zeros((BLOCK, 1))
    for a in range(0, int(duration * fs), BLOCK):
        t_last = (a + BLOCK - 1) / fs
        while k < len(est) and est[k][0] <= t_last:
            filt.set_estimate(est[k][1])
            k += 1
        filt.process(zeros, t_last)
        if t_next < len(times) and t_last + 0.5 / fs >= times[t_next]:
            t = times[t_next]
            g = plant_at(*swb_at(t), g_swb, g_swt)
            row = {"t": t, "swb_hz": swb_at(t)[0]}
            for name, sos in (("adaptive", filt.bank.sos()), ("static", static_sos),
                              ("none", None)):
                row[name] = loop_margins(g, c, sos, fs)
            rows.append(row)
            t_next += 1
    print(f"wing loop: crossover {CROSSOVER_HZ:g} Hz (PI controller), SWB peak +6 dB and SWT "
          f"-6 dB without a notch at the start; static notch {static.center:.3f} Hz, "
          f"bandwidth {static.bandwidth:.3f} Hz, depth {static.depth_db:g} dB; adaptive bank "
          f"from {len(est)} estimates of the real identification")
    print(f"{'t [s]':>6s} {'SWB Hz':>7s} | {'phase margin at crossover [deg]':^32s} | "
          f"{'gain margin [dB]':^26s} | {'notch lag @xover [deg]':^22s}")
    print(f"{'':>6s} {'':>7s} | {'adaptive':>10s}{'static':>10s}{'none':>12s} | "
          f"{'adaptive':>8s}{'static':>8s}{'none':>10s} | {'adaptive':>11s}{'static':>11s}")

    def pm(m):
        return f"{m.phase_margin_deg:.2f}" if m.stable else "unstable"

    for r in rows:
        if abs(r["t"] % 5.0) > 1e-9 and not (r["t"] < 5.0 and abs(r["t"] % 1.0) < 1e-9):
            continue  # every 5 s, every second during the first 5 s
        a, s, n = r["adaptive"], r["static"], r["none"]
        print(f"{r['t']:6.1f} {r['swb_hz']:7.3f} | {pm(a):>10s}{pm(s):>10s}{pm(n):>12s} | "
              f"{a.gain_margin_db:8.2f}{s.gain_margin_db:8.2f}{n.gain_margin_db:10.2f} | "
              f"{a.notch_phase_lag_deg:11.3f}{s.notch_phase_lag_deg:11.3f}")
    for span, sel in (("start, identification converging (0-10 s)", lambda t: t < 10.0),
                      ("over the drift (10-60 s)", lambda t: t >= 10.0)):
        _summary(span, [r for r in rows if sel(r["t"])])
    if args.figure:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        fig, ax = plt.subplots(2, 1, figsize=(8, 6), sharex=True)
        tt = [r["t"] for r in rows]
        for name, style in (("adaptive", "-"), ("static", "--"), ("none", ":")):
            ax[0].plot(tt, [r[name].phase_margin_deg if r[name].stable else np.nan
                            for r in rows], style, label=name)
            ax[1].plot(tt, [r[name].gain_margin_db if r[name].stable else np.nan
                            for r in rows], style, label=name)
        ax[0].set_ylabel("phase margin at crossover [deg]")
        ax[1].set_ylabel("gain margin [dB]")
        ax[1].set_xlabel("time [s] (SWB 2.6 -> 3.0 Hz over 10-50 s)")
        ax[0].legend()
        ax[0].set_title("wing_bending_drift: flight-control loop margins (unstable: no line)")
        args.figure.parent.mkdir(parents=True, exist_ok=True)
        fig.savefig(args.figure, dpi=110)
        print(f"figure written to {args.figure}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
