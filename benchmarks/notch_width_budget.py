"""Where a drifting mode's notch width (and its phase lag at the crossover) comes from, and
whether the frequency / damping standard deviations it is built on are calibrated.

    ros2_ws/env python benchmarks/notch_width_budget.py DIR [DIR ...] [--age 0.1]
        [--estimates BAG [BAG ...]] [--damping-window S] [--delay S]

``DIR`` is the ``--out`` directory of a ``benchmarks/notch_drift_figures.py`` run (its bag,
truth, YAML and recording); ``--estimates`` takes the estimates from other bags instead (one per
``DIR``, e.g. ``sysid_node``'s ``offline`` output on ``DIR/drifting_mode``: deterministic, no
DDS); ``--damping-window`` tries a damping median over a window of its own, ``--delay`` a mode
model extrapolated by its drift rate times that delay, beyond the identifier's own lag that the
node's model already takes from each estimate (``smoothing.estimator_memory``).
Offline, no DDS: the recorded ``/modal_estimate`` messages are fed to the notch policy's mode
model (:mod:`notch_filter_node.smoothing`, the window, memory and lag the node uses)
for the estimate that tracks the true mode, and at every estimate after the first tracking one
plus ``fade_time``:

1. calibration: ``(estimate - truth) / std`` of frequency and damping, raw (sysid's reported
   std) and after the mode model (what the notch width is built on); a calibrated std gives a
   standard deviation of about 1 and about 5 % beyond 1.96;
2. the width budget: the narrowest notch (``resonance.design_zp``, the node's depth and
   required peak reduction) for uncertainty regions growing one term at a time, from the oracle
   (true frequency and damping) to the node's region, with the median phase lag at the crossover
   over the estimates and its ratio to the oracle's:

   - ``estimate``: centred at the estimate, damping the estimate (no uncertainty);
   - ``+ damping``: damping up to ``zeta + damping_sigma_k * sigma_zeta``;
   - ``+ frequency``: ``+- sigma_k * sigma_f``;
   - ``+ age``: ``+- drift bound * (age + design_horizon)`` (``--age``: the estimate age);
   - ``as a pair``: the node's region (``+ age/drift``) with a notch pair where that lags
     less (``resonance.design_pair``; width: of each section);
   - ``box``: the whole damping interval at every frequency (no joint region);
   - ``chance P`` (``--chance P ...``): no region at all, the narrowest notch whose peak
     reduction meets the requirement with probability ``P`` when frequency and damping are
     independent Gaussians of the model's stds (cells of a 33 x 33 grid over +-4.5 stds, the
     worst of the two drift shifts ``+- drift bound * (age + design_horizon)``), on every
     ``--every``-th estimate: what an exact chance constraint would save over the region.

The figures depend on the recording; the script tunes nothing.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np
import yaml
from notch_filter_node.policy import DRIFT_MEMORIES
from rosbags.highlevel import AnyReader
from sysid_node.bag_io import typestore

from notch_filter_node import params as NP
from notch_filter_node import resonance as R
from notch_filter_node import sections as S
from notch_filter_node import smoothing as SM

MATCH = 0.05  # a tracked mode within 5 % of the truth tracks it


def _truth_at(truth: dict, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    m = truth["modes"][0]
    return (np.interp(t, m["t_s"], m["frequency_hz"]),
            np.interp(t, m["t_s"], m["damping_ratio"]))


def read_estimates(out: Path, recorded: Path | None = None) -> tuple[list[tuple], float]:
    """(t, [(id, status, f, f_std, zeta, zeta_std)], (memory, lag)) per /modal_estimate, t from
    the bag start (``recorded``: another bag with /modal_estimate, e.g. sysid_node's offline
    output); memory and lag: the identifier's (``smoothing.estimator_memory``)."""
    from sysid_node.bag_io import read_signals

    t0 = float(read_signals(out / "drifting_mode", ["/vibration"])["/vibration"].t[0])
    rows = []
    with AnyReader([recorded or out / "run" / "recorded"], default_typestore=typestore()) as reader:
        conns = [c for c in reader.connections if c.topic == "/modal_estimate"]
        for conn, _, raw in reader.messages(connections=conns):
            msg = reader.deserialize(raw, conn.msgtype)
            t = msg.header.stamp.sec + 1e-9 * msg.header.stamp.nanosec - t0
            if msg.health != 0 or not msg.converged:
                continue
            rows.append((t, [(m.id, m.status, m.frequency, m.frequency_std, m.damping_ratio,
                              m.damping_ratio_std) for m in msg.modes],
                         SM.estimator_memory(msg.forgetting_factor, msg.sample_rate,
                                             msg.block_rows)))
    rows.sort(key=lambda r: r[0])
    return rows, t0


def series(out: Path, recorded: Path | None = None, damping_window: float | None = None,
           delay: float = 0.0) -> dict:
    """The tracking mode's raw estimates and mode models, with the truth, per estimate."""
    truth = json.loads((out / "drifting_mode.truth.json").read_text())
    cfg = {**NP.defaults(), **yaml.safe_load((out / "params.yaml").read_text())[
        "notch_filter_node"]["ros__parameters"]}
    rows, _ = read_estimates(out, recorded)
    zwin = cfg["drift_window"] if damping_window is None else damping_window
    hist: dict[int, list] = {}
    rec = []
    first = None
    for t, modes, (memory, lag) in rows:
        win = max(cfg["drift_window"], DRIFT_MEMORIES * memory) if np.isfinite(memory) else \
            cfg["drift_window"]  # the node's window (policy.NotchPolicy._window)
        ft, _ = _truth_at(truth, np.array(t))
        for mid, status, f, sf, z, sz in modes:
            if status == 1 and np.isfinite(f):
                hist.setdefault(mid, []).append((t, f, sf, z, sz))
        for mid in list(hist):
            hist[mid] = [p for p in hist[mid] if p[0] >= t - max(win, zwin)]
        hit = [m for m in modes if m[1] == 1 and abs(m[2] / ft - 1.0) <= MATCH]
        if not hit:
            continue
        if first is None:
            first = t
        if t < first + cfg["fade_time"]:
            continue
        m = hit[0]
        h = np.array(hist[m[0]], dtype=float)
        mm = SM.model(*h[h[:, 0] >= t - win].T, win, memory, lag)
        if damping_window is not None:  # damping from a window of its own
            mz = SM.model(*h[h[:, 0] >= t - zwin].T, zwin)
            mm = SM.ModeModel(mm.frequency, mm.frequency_std, mz.damping, mz.damping_std,
                              mm.drift, mm.drift_std, mm.n_eff)
        rec.append((t, m[2], m[3], m[4], m[5], mm.frequency + mm.drift * delay,
                    mm.frequency_std, mm.damping, mm.damping_std,
                    abs(mm.drift) + cfg["sigma_k"] * mm.drift_std))
    a = np.array(rec, dtype=float)
    ft, zt = _truth_at(truth, a[:, 0])
    return {"cfg": cfg, "fs": truth["sample_rate_hz"], "t": a[:, 0], "f_true": ft, "z_true": zt,
            "f": a[:, 1], "sf": a[:, 2], "z": a[:, 3], "sz": a[:, 4], "mf": a[:, 5],
            "msf": a[:, 6], "mz": a[:, 7], "msz": a[:, 8], "drift": a[:, 9],
            "rigid_hz": truth["modes"][1]["frequency_hz"][0]}


def calibration(s: dict) -> dict:
    out = {}
    for name, e, sd, true in (("f raw", s["f"], s["sf"], s["f_true"]),
                              ("f model", s["mf"], s["msf"], s["f_true"]),
                              ("zeta raw", s["z"], s["sz"], s["z_true"]),
                              ("zeta model", s["mz"], s["msz"], s["z_true"])):
        q = (e - true) / sd
        q = q[np.isfinite(q)]
        out[name] = {"n": int(q.size), "mean": float(np.mean(q)), "std": float(np.std(q)),
                     "beyond_1.96": float(np.mean(np.abs(q) > 1.96)),
                     "median_rel_std": float(np.nanmedian(sd / np.abs(true)))}
    return out


def lag_of(center, zp, depth, fs, crossover) -> np.ndarray:
    g = 10.0 ** (-depth / 20.0)
    return S.damping_lag_deg(crossover, center, zp, g * zp, fs)


def narrowest(center, f_lo, f_hi, zeta_hi, zeta_c, cfg, fs) -> np.ndarray:
    zp_min, _ = S.pole_zero_damping(center, np.full(center.shape, 1e-3), cfg["depth"], fs)
    widest = cfg["bandwidth_max"] if cfg["bandwidth_max"] > 0 else center  # policy.widest
    zp_max, _ = S.pole_zero_damping(center, np.full(center.shape, widest),
                                    cfg["depth"], fs)
    zp, _ = R.design_zp(center, f_lo, f_hi, zeta_hi, cfg["peak_reduction"], cfg["depth"], fs,
                        zp_min, zp_max, passes=3, zeta_c=zeta_c)
    return zp


def budget(s: dict, age: float) -> list[tuple[str, float, float]]:
    cfg, fs = s["cfg"], s["fs"]
    xo = cfg["crossover_frequency"]
    kf, kz = cfg["sigma_k"], cfg["damping_sigma_k"]
    f, z = s["mf"], s["mz"]
    zhi = np.minimum(z + kz * s["msz"], cfg["damping_max"])
    hf = kf * s["msf"]
    ha = np.maximum(s["drift"], cfg["drift_rate_min"] * f) * (age + cfg["design_horizon"])
    steps = [
        ("oracle (truth)", s["f_true"], s["f_true"], s["z_true"], s["z_true"], s["f_true"]),
        ("estimate, no uncertainty", f, f, z, z, f),
        ("+ damping (damping_sigma_k)", f, f, zhi, z, f),
        ("+ frequency (sigma_k)", f - hf, f + hf, zhi, z, f),
        ("+ age/drift", f - hf - ha, f + hf + ha, zhi, z, f),
        ("box (no joint region)", f - hf - ha, f + hf + ha, zhi, zhi, f),
    ]
    rows = []
    base = None
    for name, lo, hi, zh, zc, c in steps:
        zp = narrowest(c, lo, hi, zh, zc, cfg, fs)
        lag = lag_of(c, zp, cfg["depth"], fs, xo)
        bw = S.bandwidth_from_zp(c, zp, cfg["depth"], fs)
        if base is None:
            base = lag
        rows.append((name, float(np.median(lag)), float(np.median(lag / base)),
                     float(np.median(bw))))
        if name == "+ age/drift":  # the node's region: its pair (resonance.design_pair)
            pair = R.design_pair(c, lo, hi, zh, cfg["peak_reduction"], cfg["depth"], fs, zp,
                                 xo, zeta_c=zc)
            plag = np.minimum(pair.lag_deg, lag)  # a pair where it lags less
            pbw = S.bandwidth_from_zp(c, pair.zp, cfg["peak_reduction"], fs)
            rows.append(("  as a pair, where it lags less", float(np.median(plag)),
                         float(np.median(plag / base)),
                         float(np.median(np.where(pair.lag_deg < lag, pbw, bw)))))
    return rows


def _cells(n: int = 33, span: float = 4.5) -> tuple[np.ndarray, np.ndarray]:
    """Standard normal nodes and the probability of the cell around each (ends: the tails)."""
    from scipy.special import ndtr

    u = np.linspace(-span, span, n)
    edges = np.concatenate([[-np.inf], 0.5 * (u[1:] + u[:-1]), [np.inf]])
    return u, np.diff(ndtr(edges))


def failure_probability(center, zp, f, sf, shift, z, sz, cfg, fs) -> float:
    """P(peak reduction < required) of one notch for a Gaussian mode (worst over shifts)."""
    u, w = _cells()
    g = 10.0 ** (-cfg["depth"] / 20.0)
    ww = np.outer(w, w)
    worst = 0.0
    for sh in shift:
        fm, zm = np.meshgrid(f + sh + u * sf, np.maximum(z + u * sz, R.ZETA_FLOOR),
                             indexing="ij")
        pr = R.peak_reduction_db(fm, zm, np.array([center]), np.array([zp]),
                                 np.array([g * zp]), fs, cfg["depth"] + 6.0)
        worst = max(worst, float(np.sum(ww[pr < cfg["peak_reduction"]])))
    return worst


def chance_rows(s: dict, age: float, probs: list[float], every: int) -> list[tuple]:
    cfg, fs = s["cfg"], s["fs"]
    xo = cfg["crossover_frequency"]
    idx = np.arange(0, s["t"].size, max(every, 1))
    f_t, z_t = s["f_true"][idx], s["z_true"][idx]
    base = lag_of(f_t, narrowest(f_t, f_t, f_t, z_t, z_t, cfg, fs), cfg["depth"], fs, xo)
    rows = []
    for p in probs:
        lags, bws = [], []
        for i in idx:
            f, sf, z, sz = s["mf"][i], s["msf"][i], s["mz"][i], s["msz"][i]
            ha = max(s["drift"][i], cfg["drift_rate_min"] * f) * (age + cfg["design_horizon"])
            lo, hi = np.log(1e-4), np.log(1.0)
            for _ in range(16):  # bisection on log zp: about 1 % of zp
                mid = 0.5 * (lo + hi)
                if failure_probability(f, np.exp(mid), f, sf, (-ha, ha), z, sz, cfg,
                                       fs) <= 1.0 - p:
                    hi = mid
                else:
                    lo = mid
            lags.append(float(lag_of(f, np.exp(hi), cfg["depth"], fs, xo)))
            bws.append(float(S.bandwidth_from_zp(f, np.exp(hi), cfg["depth"], fs)))
        lags = np.array(lags)
        rows.append((f"chance {p:g} (every {every}th)", float(np.median(lags)),
                     float(np.median(lags / base)), float(np.median(bws))))
    return rows


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("dirs", nargs="+", type=Path)
    ap.add_argument("--age", type=float, default=0.1, help="estimate age [s] for the age term")
    ap.add_argument("--estimates", type=Path, nargs="*",
                    help="per DIR: another bag with /modal_estimate (sysid offline output)")
    ap.add_argument("--damping-window", type=float, help="[s] damping median window")
    ap.add_argument("--delay", type=float, default=0.0, help="[s] extrapolate the model by it")
    ap.add_argument("--chance", type=float, nargs="*", default=[],
                    help="chance-constrained designs at these probabilities (slow)")
    ap.add_argument("--every", type=int, default=5, help="--chance on every n-th estimate")
    args = ap.parse_args(argv)
    for i, d in enumerate(args.dirs):
        s = series(d, args.estimates[i] if args.estimates else None, args.damping_window,
                   args.delay)
        print(f"{d}: {s['t'].size} estimates, f {s['f_true'].min():.2f}-{s['f_true'].max():.2f}"
              f" Hz, zeta {100 * s['z_true'][0]:.2f} %, fs {s['fs']:g} Hz")
        print(f"  {'(estimate - truth) / std':<28}{'n':>5}{'mean':>8}{'std':>8}{'>1.96':>8}"
              f"{'std/value':>11}")
        for name, c in calibration(s).items():
            print(f"  {name:<28}{c['n']:>5}{c['mean']:>8.2f}{c['std']:>8.2f}"
                  f"{c['beyond_1.96']:>8.2f}{c['median_rel_std']:>11.4f}")
        print(f"  {'region':<36}{'lag [deg]':>10}{'/ oracle':>10}{'width [Hz]':>12}")
        for name, lag, ratio, bw in budget(s, args.age) + chance_rows(s, args.age, args.chance,
                                                                      args.every):
            print(f"  {name:<36}{lag:>10.2f}{ratio:>10.2f}{bw:>12.3f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
