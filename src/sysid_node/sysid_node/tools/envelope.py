"""envelope: the paper's Sec. IV procedure (iterative closed-loop identification and controller
design toward an instability) on the rotor-speed cobra stick model, with the LPV model (2) as
its product.

    ros2_ws/run sysid_node envelope [--start 32] [--stop 38] [--step 1] [--duration 60]
        [--seed 0] [--order 6] [--control-band 30 40] [--control-weight 10] [--disturbance 0.2]
        [--noise 0.05] [--output csm.lpv.npz] [--json run.json] [--controllers DIR] [--quiet]

Prints the run (one line per operating point or rejected step), the Table-2 analogue (per
rotor speed: open-loop truth, the open-loop modes identified from the closed-loop data, the
naive direct DSRA on the same data, and the true closed-loop poles), and the LPV model's
predicted modes against the truth between the operating points. Exit status 0 when the range
was covered without ever closing an unstable loop, 1 otherwise, 2 on bad arguments or files.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

from ..core.controller import closed_loop_poles, plant_ss
from ..core.envelope import EnvelopeRun, EnvelopeSettings, expand_envelope
from ..core.lpv import lpv_errors, match_modes
from ..core.lti import discretize
from ..scenarios.csm_rotor import CSM_FS, CSM_RANGE, closed_loop_experiment, csm_at
from . import fail

PROG = "envelope"


class _Parser(argparse.ArgumentParser):
    def error(self, message: str) -> None:  # one line, no usage block
        print(f"{PROG}: error: {message}", file=sys.stderr)
        raise SystemExit(2)


def build_parser() -> argparse.ArgumentParser:
    ap = _Parser(prog=PROG, description=__doc__.splitlines()[0])
    ap.add_argument("--start", type=float, default=CSM_RANGE[0], help="first rotor speed [Hz]")
    ap.add_argument("--stop", type=float, default=CSM_RANGE[1], help="last rotor speed [Hz]")
    ap.add_argument("--step", type=float, default=1.0, help="rotor-speed step [Hz] [1]")
    ap.add_argument("--min-step", type=float, default=0.125, help="smallest step [Hz] [0.125]")
    ap.add_argument("--duration", type=float, default=60.0, help="experiment length [s] [60]")
    ap.add_argument("--seed", type=int, default=0, help="noise seed [0]")
    ap.add_argument("--order", type=int, default=6, help="plant model order [6]")
    ap.add_argument("--block-rows", type=int, default=20, help="block rows i of (A1) [20]")
    ap.add_argument("--control-band", type=float, nargs=2, default=(30.0, 40.0),
                    metavar=("LO", "HI"), help="modes the controller damps [Hz] [30 40]")
    ap.add_argument("--control-weight", type=float, default=10.0,
                    help="LQG control weight, channels scaled by their std [10]")
    ap.add_argument("--disturbance", type=float, default=0.2,
                    help="unmeasured input disturbance, std relative to the test input [0.2]")
    ap.add_argument("--noise", type=float, default=0.05, help="sensor noise fraction [0.05]")
    ap.add_argument("--output", default=None, help="write the LPV model (.npz)")
    ap.add_argument("--json", default=None, help="write the run as JSON")
    ap.add_argument("--controllers", default=None,
                    help="directory for the controllers designed at each point (.npz)")
    ap.add_argument("--quiet", action="store_true", help="no per-step log")
    return ap


def _check_args(a: argparse.Namespace) -> None:
    if not (a.step > 0 and a.min_step > 0 and a.min_step <= a.step):
        raise ValueError("need 0 < --min-step <= --step")
    if not (a.duration > 0 and a.order >= 2 and a.block_rows >= 2):
        raise ValueError("need --duration > 0, --order >= 2, --block-rows >= 2")
    if not a.control_band[0] < a.control_band[1]:
        raise ValueError("--control-band LO must be below HI")
    if not (a.disturbance >= 0 and a.noise >= 0 and a.control_weight > 0):
        raise ValueError("--disturbance and --noise must be >= 0, --control-weight > 0")
    for path, flag in ((a.output, "--output"), (a.json, "--json")):
        if path is not None and not Path(path).resolve().parent.is_dir():
            raise ValueError(f"{flag} {path}: directory {Path(path).parent} does not exist")
    if a.controllers is not None and not Path(a.controllers).is_dir():
        raise ValueError(f"--controllers {a.controllers} is not a directory")


def _modes(ms) -> list[tuple[float, float]]:
    return [(m.frequency_hz, m.damping_ratio) for m in ms]


def table_rows(run: EnvelopeRun) -> list[dict]:
    """The Table-2 analogue: per operating point, lists of (f [Hz], zeta) matched to the
    open-loop truth's modes (None where nothing matched)."""
    rows = []
    for p in run.points:
        truth = csm_at(p.theta).modes()
        row = {"theta": p.theta, "closed_loop": p.closed_loop, "designed_at": p.designed_at,
               "true_spectral_radius": p.record.true_spectral_radius, "truth": truth,
               "identified": match_modes(_modes(p.model.modes), truth)}
        if p.result is not None:
            row["naive"] = match_modes(_modes(p.result.naive.modes), truth)
            k = next(q.controller_out for q in run.points if q.theta == p.designed_at)
            poles = closed_loop_poles(plant_ss(*discretize(csm_at(p.theta), CSM_FS), CSM_FS), k)
            s = np.log(poles[poles.imag > 1e-9].astype(complex)) * CSM_FS
            row["closed_loop_poles"] = match_modes(
                [(abs(x) / (2 * np.pi), -x.real / abs(x)) for x in s], truth)
        rows.append(row)
    return rows


def _fmt(m) -> str:
    return f"{'-':>17s}" if m is None else f"{m[0]:8.3f} {100 * m[1]:6.3f}% "


def print_table(rows: list[dict]) -> None:
    print("Table 2 analogue (modes: frequency [Hz] damping [%]; identified = open-loop modes "
          "from the closed-loop data, direct PEM)")
    print(f"{'rotor':>6s}  {'experiment':<22s}{'source':<22s}"
          + "".join(f"{'mode ' + str(i + 1):>18s}" for i in range(len(rows[0]["truth"]))))
    for r in rows:
        exp = ("open loop" if not r["closed_loop"] else f"closed, K from {r['designed_at']:g}")
        lines = [("open-loop truth", r["truth"]), ("identified", r["identified"])]
        if "naive" in r:
            lines += [("naive direct DSRA", r["naive"]),
                      ("closed-loop poles", r["closed_loop_poles"])]
        for j, (label, ms) in enumerate(lines):
            head = f"{r['theta']:6.2f}  {exp:<22s}" if j == 0 else " " * 30
            print(head + f"{label:<22s}" + "".join(f"{_fmt(m):>18s}" for m in ms))


def run(args: argparse.Namespace) -> tuple[EnvelopeRun, dict]:
    settings = EnvelopeSettings(
        args.start, args.stop, args.step, args.min_step, args.order, args.block_rows,
        tuple(args.control_band), args.control_weight)

    def experiment(theta, controller, rng):
        return closed_loop_experiment(csm_at(theta), controller, args.duration, rng,
                                      disturbance_std=args.disturbance,
                                      noise_fraction=args.noise)

    log = None if args.quiet else (lambda line: print(line, flush=True))
    env = expand_envelope(experiment, settings, np.random.default_rng(args.seed), log)
    rows = table_rows(env)
    print_table(rows)
    unstable = env.unstable_closures()
    print(f"run: {'covered' if env.completed else 'stopped'} {args.start:g} -> "
          f"{env.points[-1].theta:g} Hz in {len(env.points)} experiments "
          f"({sum(p.closed_loop for p in env.points)} closed loop), "
          f"{len(env.rejected_steps)} step(s) rejected by the check, {unstable} unstable "
          f"closed loop(s), largest true closed-loop spectral radius "
          f"{max(p.record.true_spectral_radius for p in env.points):.5f}"
          + (f"; {env.stop_reason}" if env.stop_reason else ""))
    lpv_summary = {}
    if env.lpv is not None and len(env.points) >= 2:
        env.lpv.scheduling, env.lpv.unit = "rotor_speed", "Hz"
        env.lpv.source = (f"envelope seed {args.seed}: cobra stick model, {args.duration:g} s "
                          "experiments, closed-loop identification (direct PEM)")
        pts = env.lpv.points
        mids = 0.5 * (pts[1:] + pts[:-1])
        grid = np.linspace(pts[0], pts[-1], 8 * (len(pts) - 1) + 1)
        ef_m, ez_m = lpv_errors(env.lpv, lambda t: csm_at(t).modes(), mids)
        ef_g, ez_g = lpv_errors(env.lpv, lambda t: csm_at(t).modes(), grid)
        lpv_summary = {"points": pts.tolist(), "midpoint_freq_error_max": float(ef_m.max()),
                       "midpoint_damping_error_max": float(ez_m.max()),
                       "grid_freq_error_max": float(ef_g.max()),
                       "grid_damping_error_max": float(ez_g.max())}
        print(f"LPV model (2): {len(pts)} operating points, {env.lpv.n_modes} modes; predicted "
              f"modes against the truth: midpoints max frequency error "
              f"{100 * ef_m.max():.3f} %, damping {100 * ez_m.max():.3f} pp; grid of "
              f"{grid.size} speeds {100 * ef_g.max():.3f} % / {100 * ez_g.max():.3f} pp")
        if args.output:
            env.lpv.save(args.output)
            print(f"LPV model written to {args.output}")
    if args.controllers:
        for p in env.points:
            if p.controller_out is not None:
                p.controller_out.save(Path(args.controllers) / f"controller_{p.theta:g}Hz.npz")
    summary = {"completed": env.completed, "stop_reason": env.stop_reason,
               "unstable_closures": unstable, "rejected_steps": env.rejected_steps,
               "rows": rows, "lpv": lpv_summary, "settings": vars(args)}
    if args.json:
        Path(args.json).write_text(json.dumps(summary, indent=1, default=_json_default))
    return env, summary


def _json_default(x):
    if isinstance(x, np.generic):
        return x.item()
    if isinstance(x, tuple):
        return list(x)
    raise TypeError(type(x).__name__)


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        _check_args(args)
        env, _ = run(args)
    except (ValueError, OSError) as err:
        return fail(PROG, str(err), 2)
    return 0 if env.completed and env.unstable_closures() == 0 else 1


if __name__ == "__main__":
    sys.exit(main())
