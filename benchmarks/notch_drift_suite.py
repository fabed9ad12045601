"""A seeded suite of drifting modes through the identification and the adaptive notch bank,
offline (no DDS, deterministic): per draw and over all, how often the true resonance stays
``peak_reduction`` down, whether the bank's claims hold, and its phase lag against the oracle.

    ros2_ws/env python benchmarks/notch_drift_suite.py [--draws 8] [--first-seed 0]
        [--duration 40] [--fs 0] [--json FILE]

Per draw (``sysid_node.scenarios.drifting_mode`` with ``default_rng(seed)``: sample rate
100-1000 Hz unless ``--fs``, a 1-3 %-damped mode between 2 Hz and 0.2 fs drifting by 5-20 %,
broadband-excited, a rigid-body mode below it): the bag and the YAML of
``benchmarks/notch_drift_figures.py`` (sysid band 0 .. 0.3 fs; notch ``freq_min`` between the
rigid-body and the structural mode, ``crossover_frequency`` at the rigid-body mode, as the
flight-control engineer sets them), sysid_node's processing over the bag (the ``offline`` tool,
identical to the node), each estimate handed to notch_filter_node's pure filter
(``AdaptiveNotchFilter``, what the node runs) ``DELIVERY_S`` after its data, the bank advanced in
blocks of ``BLOCK_S``. From the first estimate that tracks the mode (a tracked mode within 5 %)
plus ``fade_time``, at every block: the true mode (frequency and damping then) times the bank's
sections gives the peak reduction; the bank's own claim for that mode
(``peak_reductions``: guaranteed over the mode's uncertainty box) is compared with it; the lag
of the whole bank at the crossover is compared with the oracle notch's (the narrowest single
notch that knows the mode; ``oracle pair``: the least lagging notch or pair that knows it).

Prints a table, one line per draw and a summary; ``--json`` writes the figures. The figures
depend on the draws; the script tunes nothing. Exit status 0 when every draw ran, 2 otherwise.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path

import numpy as np
import yaml
from notch_filter_node.adaptive import AdaptiveNotchFilter
from notch_filter_node.policy import EstimateInput, ModeInput
from sysid_node.tools.offline import OfflineError, load_params_file, run

from notch_filter_node import params as NP
from notch_filter_node import resonance as R
from notch_filter_node import sections as S
from notch_filter_node import smoothing as SM

sys.path.insert(0, str(Path(__file__).resolve().parent))
from notch_drift_figures import MATCH, oracle_pair_lag, scenario_files

DELIVERY_S = 0.05  # [s] estimate -> bank (a quiet machine)
BLOCK_S = 0.02  # [s] of data per bank call
ORACLE_STEP_S = 0.2  # [s] the oracle notch is designed on this grid, interpolated between


def estimates(bag: Path, params: Path, t0: float) -> list[EstimateInput]:
    """The identification's estimates as the bank receives them (data time since ``t0``)."""
    records, _, _ = run(bag, load_params_file(params, "sysid_node"))
    out = []
    for r in records:
        memory, lag = SM.estimator_memory(r.forgetting_factor, r.sample_rate, r.block_rows)
        modes = [ModeInput(m.id, m.status, m.frequency_hz, m.frequency_std_hz, m.damping_ratio,
                           m.damping_std, m.amplitude) for m in r.modes]
        t = r.stamp_ns * 1e-9 - t0
        out.append(EstimateInput(t, r.converged, modes, r.health, r.health_reason,
                                 t + DELIVERY_S, (), memory, lag))
    return out


def draw(seed: int, fs: float | None, duration: float, work: Path) -> dict:
    """One draw's figures (see the module docstring)."""
    scn, bag, params, _ = scenario_files(seed, fs, duration, work)
    fs = scn.fs
    cfg = NP.policy_config({**NP.defaults(), **yaml.safe_load(params.read_text())[
        "notch_filter_node"]["ros__parameters"]})
    from sysid_node.scenarios.bags import START_TIME_S

    est = estimates(bag, params, START_TIME_S)

    def tracks(e: EstimateInput) -> bool:
        f, _ = scn.mode_at(e.stamp)
        return any(m.status == "tracked" and abs(m.frequency_hz / f - 1.0) <= MATCH
                   for m in e.modes)

    first = next((e.stamp for e in est if tracks(e)), None)
    if first is None:
        return {"seed": seed, "fs": fs, "error": "the mode was never tracked"}
    start = first + cfg.fade_time
    grid = np.append(np.arange(start, scn.t[-1], ORACLE_STEP_S), scn.t[-1])
    modes = [scn.mode_at(t) for t in grid]
    oracle = [R.guaranteeing_notch(float(f), float(f), float(z), cfg.peak_reduction, cfg.depth,
                                   fs) for f, z in modes]
    o_lag = np.array([float(np.sum(S.damping_lag_deg(cfg.crossover_frequency, *R.section_damping(
        o.center, o.bandwidth, o.depth_db, fs), fs))) for o in oracle])
    p_lag = np.minimum(o_lag, [oracle_pair_lag(o, float(z), cfg.peak_reduction, fs,
                                               cfg.crossover_frequency)
                               for o, (_, z) in zip(oracle, modes, strict=True)])
    flt = AdaptiveNotchFilter(cfg, fs, 1)
    block = max(int(round(BLOCK_S * fs)), 1)
    x = np.zeros((block, 1))  # the bank's coefficients do not depend on the signal
    k, rows = 0, []
    for b in range(block, scn.t.size + 1, block):
        t = float(scn.t[b - 1])
        while k < len(est) and est[k].received <= t:
            flt.set_estimate(est[k])
            k += 1
        flt.process(x, t)
        if t < start:
            continue
        f, z = scn.mode_at(t)
        p = flt.bank.params
        sec = R.section_damping(p.center, p.bandwidth, p.depth_db, fs, p.shape_depth_db)
        pr = float(R.peak_reduction_db(np.array(float(f)), np.array(float(z)), *sec, fs))
        claimed = [g for n, g in zip(flt.status().notches, flt.peak_reductions()[0], strict=True)
                   if n.mode_id and abs(n.center / f - 1.0) <= 0.2 and np.isfinite(g)]
        lag = float(np.sum(S.damping_lag_deg(cfg.crossover_frequency, *sec, fs)))
        rows.append((pr, max(claimed) if claimed else np.nan, lag,
                     float(np.interp(t, grid, o_lag)), float(np.interp(t, grid, p_lag))))
    pr, claimed, lag, olag, plag = (np.array(v) for v in zip(*rows, strict=True))
    ok = np.isfinite(claimed)
    f_struct = np.array(scn.modes[0].frequency_hz)
    return {
        "seed": seed, "fs": fs, "f_from": float(f_struct[0]), "f_to": float(f_struct[-1]),
        "zeta": float(scn.modes[0].damping_ratio[0]), "blocks": int(pr.size),
        "first_tracked_s": first, "pr_share": float(np.mean(pr >= cfg.peak_reduction)),
        "pr_min": float(pr.min()), "pr_median": float(np.median(pr)),
        "claimed_over_delivered_share": float(np.mean(claimed[ok] > pr[ok] + 0.5))
        if ok.any() else 0.0,
        "lag_ratio_median": float(np.median(lag / olag)),
        "lag_ratio_to_pair_median": float(np.median(lag / plag)),
    }


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--draws", type=int, default=8)
    ap.add_argument("--first-seed", type=int, default=0)
    ap.add_argument("--duration", type=float, default=40.0, help="[s] of data per draw")
    ap.add_argument("--fs", type=float, default=0.0, help="[Hz] sample rate; 0 = drawn")
    ap.add_argument("--json", type=Path, help="write the figures here")
    args = ap.parse_args(argv)
    figs = []
    print(f"{'seed':>5} {'fs':>6} {'mode [Hz]':>15} {'zeta':>6} {'>=15 dB':>8} {'min':>6} "
          f"{'median':>7} {'claim>got':>9} {'lag/oracle':>10} {'/pair':>6}")
    for seed in range(args.first_seed, args.first_seed + args.draws):
        with tempfile.TemporaryDirectory() as tmp:
            try:
                fig = draw(seed, args.fs or None, args.duration, Path(tmp))
            except (OSError, ValueError, OfflineError) as err:
                print(f"notch_drift_suite: error: draw {seed}: {err}", file=sys.stderr)
                return 2
        figs.append(fig)
        if "error" in fig:
            print(f"{seed:>5} {fig['fs']:>6.0f}  {fig['error']}")
            continue
        print(f"{seed:>5} {fig['fs']:>6.0f} {fig['f_from']:>7.2f}->{fig['f_to']:<6.2f} "
              f"{100 * fig['zeta']:>5.1f}% {100 * fig['pr_share']:>7.1f}% {fig['pr_min']:>6.1f} "
              f"{fig['pr_median']:>7.1f} {100 * fig['claimed_over_delivered_share']:>8.1f}% "
              f"{fig['lag_ratio_median']:>10.2f} {fig['lag_ratio_to_pair_median']:>6.2f}")
    done = [f for f in figs if "error" not in f]
    if done:
        share = np.array([f["pr_share"] for f in done])
        honest = np.array([f["claimed_over_delivered_share"] for f in done])
        print(f"{len(done)} of {len(figs)} draws tracked; >= 15 dB in >= 99 % of blocks: "
              f"{np.sum(share >= 0.99)}, >= 95 %: {np.sum(share >= 0.95)}; median share "
              f"{100 * np.median(share):.1f} %, worst {100 * share.min():.1f} %; draws with no "
              f"claim above delivery: {np.sum(honest == 0)}; lag / oracle median "
              f"{np.median([f['lag_ratio_median'] for f in done]):.2f}")
    if args.json:
        args.json.write_text(json.dumps(figs, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
