"""Both nodes over real DDS on a drifting lightly damped mode, quiet or with CPU hogs: how far the
published notch bank lowers the true mode's resonance peak, and its phase lag against the
oracle notch and the static notch with the same guarantee.

    ros2_ws/env python benchmarks/notch_drift_figures.py [--seed 3] [--fs 200] [--duration 40]
                                                          [--hogs 2] [--json FILE] [--out DIR]

1. ``sysid_node.scenarios.drifting_mode`` (seeded): a 1-3 %-damped mode drifting by 5-20 %,
   broadband-excited, with a rigid-body mode below it; written as a rosbag2 (``/vibration``,
   ``/excitation``).
2. ``ros2_ws/demo``'s pipeline: ``sysid_node`` and ``notch_filter_node`` (one YAML: sysid band
   0 .. 0.3 fs, which holds any draw; notch ``freq_min`` between the rigid-body and the
   structural mode and ``crossover_frequency`` at the rigid-body mode, as the flight-control
   engineer sets them; the fallback is the static notch with the same guarantee over the
   drift), ``replay`` at real time, ``record``. With ``--hogs N``, N busy-loop processes run
   meanwhile (no other dependency), stopped by their process ids afterwards.
3. Every recorded ``/notch_bank`` message from the first estimate that tracks the mode plus the
   notch's fade-in (``fade_time``) on: the true mode at the message's time times the published
   sections (mode x bank frequency response) gives the peak reduction; the rigid-body mode's
   change too; ``fallback_active`` where the latest estimate tracks the mode; the claimed
   ``Notch.peak_reduction`` against the delivered one; the phase lag at the crossover against
   the oracle notch (true frequency and damping at that time: the narrowest single notch of
   ``depth`` that reduces the peak by ``peak_reduction``), the oracle pair (the least lagging
   notch or notch pair that knows the mode: the lower bound for a bank that may pair its
   sections) and the static notch.

Prints a table; ``--json`` writes the figures. Exit status 0 always when the run completed
(figures are judged by test/test_notch_drift.py), 2 on a failure to run.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np
import yaml

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "ros2_ws" / "tools"))

from demo import DemoError, run_pipeline  # noqa: E402
from demo_report import analyse  # noqa: E402
from sysid_node.bag_io import write_signals  # noqa: E402
from sysid_node.scenarios import drifting_mode  # noqa: E402
from sysid_node.scenarios.bags import START_TIME_S  # noqa: E402

from notch_filter_node import params as NP  # noqa: E402
from notch_filter_node import resonance as R  # noqa: E402
from notch_filter_node import sections as S  # noqa: E402

MATCH = 0.05  # an estimate tracks the mode when a tracked mode is within 5 % of it


def scenario_files(seed: int, fs: float | None, duration: float, out: Path,
                   extra: dict | None = None):
    """Draw the scenario (``fs`` None: its sample rate too), write its bag, truth and the YAML
    for both nodes (``extra``: more notch_filter_node parameters)."""
    scn = drifting_mode(np.random.default_rng(seed), fs=fs, duration_s=duration)
    fs = scn.fs
    bag = out / "drifting_mode"
    write_signals(bag, {"/vibration": (START_TIME_S + scn.t, scn.y, ["acc_z[m/s^2]"]),
                        "/excitation": (START_TIME_S + scn.t, scn.u, ["force[N]"])})
    truth = {"modes": [m.as_dict() for m in scn.modes], "sample_rate_hz": fs}
    (out / "drifting_mode.truth.json").write_text(json.dumps(truth))
    f_struct = np.array(scn.modes[0].frequency_hz)
    f_rigid = scn.modes[1].frequency_hz[0]
    zeta = max(scn.modes[0].damping_ratio)
    depth = NP.defaults()["depth"]
    static = R.guaranteeing_notch(f_struct.min(), f_struct.max(), zeta,
                                  NP.defaults()["peak_reduction"], depth, fs)
    params = {
        "sysid_node": {"ros__parameters": {"freq_min": 0.0, "freq_max": 0.3 * fs}},
        "notch_filter_node": {"ros__parameters": {
            "freq_min": float(np.sqrt(f_rigid * f_struct.min())),
            "crossover_frequency": float(f_rigid),
            "fallback_center": static.center, "fallback_bandwidth": static.bandwidth,
            "fallback_depth": depth, **(extra or {})}},
    }
    (out / "params.yaml").write_text(yaml.safe_dump(params))
    return scn, bag, out / "params.yaml", static


def start_hogs(n: int) -> list[subprocess.Popen]:
    return [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(n)]


def stop_hogs(hogs: list[subprocess.Popen]) -> None:
    for p in hogs:
        p.kill()
        p.wait(timeout=10)


def lag_deg(centre, bw, depth, fs, crossover, shape=None) -> float:
    c, zp, zz = R.section_damping(centre, bw, depth, fs, shape)
    return float(np.sum(S.damping_lag_deg(crossover, c, zp, zz, fs)))


def oracle_pair_lag(oracle, zeta: float, required: float, fs: float, crossover: float) -> float:
    """Phase lag [deg] of the least lagging notch pair that knows the mode (``oracle``: the
    single oracle notch, its centre the mode's frequency); inf when no pair meets it."""
    c = np.array([oracle.center])
    zp, _ = S.pole_zero_damping(c, oracle.bandwidth, oracle.depth_db, fs)
    pair = R.design_pair(c, c, c, np.array([zeta]), required, oracle.depth_db, fs, zp, crossover)
    return float(pair.lag_deg[0])


def figures(scn, res, params: Path, static) -> dict:
    """The figures over the bank messages that count (see the module docstring)."""
    cfg = {**NP.defaults(), **yaml.safe_load(params.read_text())["notch_filter_node"][
        "ros__parameters"]}
    fs, crossover, required = scn.fs, cfg["crossover_frequency"], cfg["peak_reduction"]
    f_rigid, z_rigid = scn.modes[1].frequency_hz[0], scn.modes[1].damping_ratio[0]

    def tracks(est: dict) -> bool:
        f, _ = scn.mode_at(est["t"])
        return any(m[1] == 1 and abs(m[2] / f - 1.0) <= MATCH for m in est["modes"])

    first = next((e["t"] for e in res.estimates if tracks(e)), None)
    if first is None:  # what was seen instead, for the reader of a failed run
        seen = sorted({round(m[2], 2) for e in res.estimates for m in e["modes"] if m[1] == 1})
        return {"error": f"the mode was never tracked ({len(res.estimates)} estimates recorded, "
                         f"tracked frequencies seen [Hz]: {seen[:12] or 'none'})"}
    start = first + cfg["fade_time"]
    ests = [(e["t"], tracks(e)) for e in res.estimates]
    est_t = np.array([t for t, _ in ests])
    rows = []
    for b in res.banks:
        if b["t"] < start or b["t"] > scn.t[-1]:
            continue
        n = b["notches"]
        f, z = scn.mode_at(b["t"])
        sec = R.section_damping([x[2] for x in n], [x[3] for x in n], [x[4] for x in n], fs,
                                [x[5] for x in n])
        pr = R.peak_reduction_db(np.array([float(f), f_rigid]), np.array([float(z), z_rigid]),
                                 *sec, fs)
        k = int(np.searchsorted(est_t, b["t"], side="right")) - 1
        tracked = k >= 0 and ests[k][1]
        claimed = [x[6] for x in n if x[1] in (0, 1) and abs(x[2] / f - 1.0) <= 0.2
                   and np.isfinite(x[6])]
        oracle = R.guaranteeing_notch(float(f), float(f), float(z), required, cfg["depth"], fs)
        lags = S.damping_lag_deg(crossover, *sec, fs) if sec[0].size else np.zeros(1)
        mode_lag = 0.0
        if sec[0].size:  # the sections of the notch (one, or a pair) nearest the mode
            on = [x for x in n if x[4] > S.DEPTH_OFF_DB]
            near = on[int(np.argmin(np.abs(sec[0] - f)))][0]
            mode_lag = float(np.sum(lags[[x[0] == near for x in on]])) if near else float(
                lags[np.argmin(np.abs(sec[0] - f))])
        rows.append((b["t"], pr[0], pr[1], b["fallback"], tracked, b["state"],
                     max(claimed) if claimed else np.nan, float(np.sum(lags)),
                     lag_deg(oracle.center, oracle.bandwidth, oracle.depth_db, fs, crossover),
                     b.get("age", np.nan), mode_lag,
                     oracle_pair_lag(oracle, float(z), required, fs, crossover)))
    if not rows:
        return {"error": "no /notch_bank message after the first tracked estimate"}
    cols = [np.array(v, dtype=float) for v in zip(*rows, strict=True)]
    t, pr, rigid, fb, tracked, state, claimed, lag, olag, age, mlag, plag = cols
    plag = np.minimum(plag, olag)  # the least lagging notch or pair that knows the mode
    ok = np.isfinite(claimed)
    f_struct = np.array(scn.modes[0].frequency_hz)
    return {
        "seed_scenario": {"fs": fs, "f_from": f_struct[0], "f_to": f_struct[-1],
                          "zeta": scn.modes[0].damping_ratio[0], "rigid_hz": f_rigid,
                          "rigid_zeta": z_rigid, "crossover_hz": crossover},
        "messages": len(rows), "first_tracked_s": first,
        "estimates": len(res.estimates),
        "pr_share": float(np.mean(pr >= required)), "pr_min": float(pr.min()),
        "pr_median": float(np.median(pr)),
        "rigid_max_abs_db": float(np.max(np.abs(rigid))),
        "fallback_while_tracked": int(np.sum((fb > 0) & (tracked > 0))),
        # ... and the estimate fresh (age <= stale_timeout): an estimate seconds old on a
        # saturated machine is meant to end in the fallback (fallback_timeout), even if it tracks
        "fallback_while_tracked_fresh": int(np.sum((fb > 0) & (tracked > 0)
                                                   & (age <= cfg["stale_timeout"]))),
        "fallback_messages": int(np.sum(fb > 0)),
        "holding_share": float(np.mean(state == 1)),
        "claimed_over_delivered": int(np.sum(claimed[ok] > pr[ok] + 0.5)),
        "claimed_messages": int(ok.sum()),
        # where the claim failed, for the reader of a failed run: data time [s], the estimate's
        # age [s], the bank's state (0 tracking, 1 holding), claimed and delivered [dB]
        "over_delivered_at": [[round(float(v), 2) for v in r] for r in zip(
            t[ok], age[ok], state[ok], claimed[ok], pr[ok], strict=True)
            if r[3] > r[4] + 0.5],
        # the probability the claim's region covers the true mode (the guarantee's confidence)
        "claim_confidence": R.region_confidence(cfg["sigma_k"], cfg["damping_sigma_k"]),
        "lag_median_deg": float(np.median(lag)), "oracle_lag_median_deg": float(np.median(olag)),
        "lag_ratio_median": float(np.median(lag / olag)),
        "lag_ratio_p95": float(np.percentile(lag / olag, 95)),
        # while the bank tracks a current estimate: the widths the identification's stds give,
        # without the deliberate widening of notches held on a late one (holding_share)
        "lag_ratio_tracking_median": float(np.median((lag / olag)[state == 0]))
        if np.any(state == 0) else float("nan"),
        "mode_lag_ratio_median": float(np.median(mlag / olag)),
        "mode_lag_ratio_p95": float(np.percentile(mlag / olag, 95)),
        "oracle_pair_lag_median_deg": float(np.median(plag)),
        "lag_ratio_to_pair_median": float(np.median(lag / plag)),
        "static_lag_deg": lag_deg(static.center, static.bandwidth, static.depth_db, fs,
                                  crossover),
        "static_bandwidth_hz": static.bandwidth,
        "age_median_s": float(np.nanmedian(age)), "age_p95_s": float(np.nanpercentile(age, 95)),
    }


def print_log_tails(logs: Path, lines: int = 12) -> None:
    """The last lines of each node's and tool's log, on stderr (a failed run says why)."""
    for log in sorted(logs.glob("*.log")):
        tail = log.read_text(errors="replace").splitlines()[-lines:]
        print(f"--- {log.name} (last {len(tail)} lines)", *tail, sep="\n", file=sys.stderr)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seed", type=int, default=3)
    ap.add_argument("--fs", type=float, default=200.0)
    ap.add_argument("--duration", type=float, default=40.0, help="[s] of data")
    ap.add_argument("--hogs", type=int, default=0, help="busy-loop processes during the run")
    ap.add_argument("--rate", type=float, default=1.0, help="replay speed factor")
    ap.add_argument("--json", type=Path, help="write the figures here")
    ap.add_argument("--out", type=Path, help="keep the bag, YAML, logs and recording here")
    ap.add_argument("--set", nargs="*", default=[], metavar="NAME=VALUE",
                    help="more notch_filter_node parameters (YAML values)")
    args = ap.parse_args(argv)
    os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    os.environ.setdefault("ROS_DOMAIN_ID", str(10 + os.getpid() % 80))
    with tempfile.TemporaryDirectory() as tmp:
        out = args.out or Path(tmp)
        out.mkdir(parents=True, exist_ok=True)
        extra = {k: yaml.safe_load(v) for k, v in (a.split("=", 1) for a in args.set)}
        scn, bag, params, static = scenario_files(args.seed, args.fs, args.duration, out, extra)
        hogs = start_hogs(args.hogs)
        try:
            recorded = run_pipeline(bag, out / "run", params, args.rate)
        except DemoError as err:
            print(f"notch_drift_figures: error: {err}", file=sys.stderr)
            print_log_tails(out / "run" / "logs")
            return 2
        finally:
            stop_hogs(hogs)
        res = analyse(bag, recorded, params)
        fig = figures(scn, res, params, static)
        fig["hogs"] = args.hogs
        if "error" in fig:
            print(f"notch_drift_figures: error: {fig['error']}", file=sys.stderr)
            print_log_tails(out / "run" / "logs")
            if args.json:
                args.json.write_text(json.dumps(fig, indent=1))
            return 2
    s = fig["seed_scenario"]
    print(f"drifting mode (seed {args.seed}): {s['f_from']:.2f} -> {s['f_to']:.2f} Hz, damping "
          f"{100 * s['zeta']:.1f} %, rigid body {s['rigid_hz']:.2f} Hz / "
          f"{100 * s['rigid_zeta']:.0f} %, {s['fs']:g} Hz; {args.hogs} CPU hog(s); "
          f"{fig['estimates']} estimates, {fig['messages']} bank messages from "
          f"{fig['first_tracked_s']:.2f} s + fade-in")
    rows = [
        ("peak reduction >= 15 dB [% messages]", 100 * fig["pr_share"], ".1f"),
        ("peak reduction min / median [dB]", f"{fig['pr_min']:.1f} / {fig['pr_median']:.1f}",
         ""),
        ("rigid-body mode |change| max [dB]", fig["rigid_max_abs_db"], ".2f"),
        ("fallback while the estimate tracks [msgs]", fig["fallback_while_tracked"], "d"),
        ("... and is fresh (age <= stale_timeout) [msgs]", fig["fallback_while_tracked_fresh"],
         "d"),
        ("holding [% messages]", 100 * fig["holding_share"], ".1f"),
        ("claimed > delivered + 0.5 dB [msgs]",
         f"{fig['claimed_over_delivered']} of {fig['claimed_messages']}", ""),
        ("phase lag median: bank / oracle [deg]",
         f"{fig['lag_median_deg']:.2f} / {fig['oracle_lag_median_deg']:.2f}", ""),
        ("whole bank lag / oracle's, median / p95 [-]",
         f"{fig['lag_ratio_median']:.2f} / {fig['lag_ratio_p95']:.2f}", ""),
        ("whole bank lag / oracle's while tracking, median", fig["lag_ratio_tracking_median"],
         ".2f"),
        ("the mode's notch lag / oracle's, median / p95",
         f"{fig['mode_lag_ratio_median']:.2f} / {fig['mode_lag_ratio_p95']:.2f}", ""),
        ("oracle pair: lag [deg], bank lag / it, median",
         f"{fig['oracle_pair_lag_median_deg']:.2f} / {fig['lag_ratio_to_pair_median']:.2f}", ""),
        ("static same guarantee: lag [deg] (width)",
         f"{fig['static_lag_deg']:.2f} ({fig['static_bandwidth_hz']:.2f} Hz)", ""),
        ("estimate age median / p95 [s]",
         f"{fig['age_median_s']:.2f} / {fig['age_p95_s']:.2f}", ""),
    ]
    for label, value, fmt in rows:
        print(f"  {label:<44}{format(value, fmt):>20}")
    if args.json:
        args.json.write_text(json.dumps(fig, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
