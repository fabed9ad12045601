"""Cost of the recursive DSRA against re-running batch DSRA on a sliding window, on one core.

    ros2_ws/env python benchmarks/bench_dsra.py [--seconds 10] [--quick]

Cases (simulated wideband data, 5 % output noise, fixed seed):
  * SISO, block rows i = 20: the paper's Sec. II system (2, 4, 6 Hz) at 100 Hz, and four
    rotor-induced modes (47 .. 210 Hz) at 1 kHz;
  * 1 input / 6 outputs at 1 kHz, i = 20, five structural modes (2.8 .. 37 Hz).
``modes`` = modes in the final estimate (all of the system's are found in every case).

Columns, per case (median of repeats, BLAS and OpenMP limited to one thread):
  * ``upd us/smp``: ``RecursiveDSRA.update`` per sample, realizations excluded, called with one
    sample at a time (the paper's per-sample form) and with one realization interval per call
    (how the node feeds it);
  * ``realize ms``: one SVD-based realization from the RLS factor ((A2)-(A4) and modes);
  * ``RTF``: data time / wall time of the whole recursive estimator with a realization every
    ``1/rate`` s of data (``rate`` = the node's default 20 Hz), i.e. updates + realizations,
    for both ways of calling it;
  * ``window ms`` / ``window RTF``: ``identify`` (batch DSRA, Appendix A, same i and order) on
    a sliding window of 2 / (1 - lambda) samples (the rectangular window with the RLS memory's
    variance) re-run at the same 20 Hz: what a user would otherwise do;
  * ``speed-up``: window cost / recursive cost at the same update rate.
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[_var] = "1"  # one core, before numpy loads its BLAS

import argparse  # noqa: E402
import statistics  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from dataclasses import dataclass  # noqa: E402

import numpy as np  # noqa: E402
from sysid_node.core import RecursiveDSRA, identify  # noqa: E402
from sysid_node.core.lti import ContinuousSystem, simulate  # noqa: E402
from sysid_node.scenarios.excitations import white  # noqa: E402
from sysid_node.scenarios.noise import add_output_noise  # noqa: E402
from sysid_node.scenarios.paper import paper_example_systems  # noqa: E402
from sysid_node.scenarios.structures import modal_system  # noqa: E402

REALIZATION_RATE_HZ = 20.0
BLOCK_ROWS = 20


@dataclass(frozen=True)
class Case:
    name: str
    system: ContinuousSystem
    fs: float
    lam: float  # forgetting factor: 1 s of memory at fs
    band: tuple[float, float]
    max_modes: int


def cases() -> list[Case]:
    _, paper = paper_example_systems()
    # lightly damped modes, one input driving all of them, velocity sensors
    rotor = modal_system([47.0, 95.0, 142.0, 210.0], [0.02, 0.015, 0.02, 0.01], np.ones((4, 1)),
                         np.ones((1, 4)), output="velocity")
    wing = modal_system(
        [2.8, 7.1, 12.5, 23.1, 36.6],
        [0.02, 0.015, 0.02, 0.01, 0.012],
        np.ones((5, 1)),
        np.random.default_rng(7).normal(size=(6, 5)),
        output="velocity",
    )
    return [
        Case("SISO i=20 @100 Hz (paper Sec. II)", paper, 100.0, 0.99, (0.0, 10.0), 5),
        Case("SISO i=20 @1 kHz (47-210 Hz modes)", rotor, 1000.0, 0.999, (0.0, 400.0), 5),
        Case("1 in / 6 out i=20 @1 kHz", wing, 1000.0, 0.999, (0.0, 45.0), 5),
    ]


def data(case: Case, seconds: float) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(0)
    n = int(round(seconds * case.fs))
    u = white(n, case.system.n_inputs, rng)
    y = add_output_noise(simulate(case.system, u, case.fs), 0.05, rng)
    return u, y


def estimator(case: Case, interval: int) -> RecursiveDSRA:
    return RecursiveDSRA(
        case.system.n_outputs,
        case.system.n_inputs,
        fs=case.fs,
        block_rows=BLOCK_ROWS,
        max_modes=case.max_modes,
        max_order=2 * case.max_modes,
        forgetting_factor=case.lam,
        realization_interval=interval,
        band=case.band,
    )


@dataclass(frozen=True)
class Run:
    wall_s: float  # all update() calls, realizations included
    realize_s: list[float]  # wall time of each realization
    samples: int
    modes: int  # modes in the final model

    @property
    def update_per_sample_s(self) -> float:
        return (self.wall_s - sum(self.realize_s)) / self.samples


def run(case: Case, u: np.ndarray, y: np.ndarray, interval: int, block: int) -> Run:
    """Feed all samples in blocks of ``block`` with a realization every ``interval`` samples."""
    est = estimator(case, interval)
    costs = []
    t0 = time.perf_counter()
    for a in range(0, len(y), block):
        if est.update(u[a : a + block], y[a : a + block]):
            costs.append(est.last_realization_cost_s)
    wall = time.perf_counter() - t0
    if not costs:
        raise SystemExit(f"bench_dsra: error: no realization in case {case.name!r}")
    return Run(wall, costs, len(y), len(est.modes()))


def window_cost(case: Case, u: np.ndarray, y: np.ndarray, interval: int, updates: int) -> float:
    """Median seconds of one batch identify() on the sliding window ending at each update."""
    win = int(round(2.0 / (1.0 - case.lam)))
    ends = range(win, len(y) + 1, interval)
    costs = []
    for end in list(ends)[:updates]:
        t0 = time.perf_counter()
        identify(
            y[end - win : end],
            u[end - win : end],
            fs=case.fs,
            order=2 * case.max_modes,
            block_rows=BLOCK_ROWS,
            band=case.band,
            max_modes=case.max_modes,
        )
        costs.append(time.perf_counter() - t0)
    return statistics.median(costs)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=10.0, help="data per case [s]")
    ap.add_argument("--repeats", type=int, default=3, help="repeats per figure (median)")
    ap.add_argument("--quick", action="store_true", help="2 s of data, 1 repeat (smoke run)")
    args = ap.parse_args(argv)
    if args.quick:
        args.seconds, args.repeats = 2.0, 1
    if args.seconds < 2.0 or args.repeats < 1:
        print("bench_dsra: error: need --seconds >= 2 and --repeats >= 1", file=sys.stderr)
        return 1
    print(
        f"recursive DSRA vs sliding-window batch DSRA: {args.seconds:g} s of data per case, "
        f"realization/update rate {REALIZATION_RATE_HZ:g} Hz, 1 thread, median of "
        f"{args.repeats}"
    )
    print(
        f"{'case':<36} {'dim':>4} {'upd 1':>7} {'upd blk':>8} {'realize':>8} "
        f"{'RTF 1':>7} {'RTF blk':>7} {'window':>8} {'win RTF':>8} {'speed-up':>9} "
        f"{'modes':>6}"
    )
    print(
        f"{'':<36} {'':>4} {'us/smp':>7} {'us/smp':>8} {'ms':>8} {'':>7} {'':>7} {'ms':>8} "
        f"{'':>8} {'':>9} {'':>6}"
    )
    for case in cases():
        u, y = data(case, args.seconds)
        interval = int(round(case.fs / REALIZATION_RATE_HZ))
        ones = [run(case, u, y, interval, 1) for _ in range(args.repeats)]
        blks = [run(case, u, y, interval, interval) for _ in range(args.repeats)]
        one = statistics.median(r.update_per_sample_s for r in ones)
        blk = statistics.median(r.update_per_sample_s for r in blks)
        realize = statistics.median(c for r in blks for c in r.realize_s)
        rtf = args.seconds / statistics.median(r.wall_s for r in blks)
        rtf1 = args.seconds / statistics.median(r.wall_s for r in ones)
        win = window_cost(case, u, y, interval, updates=5 * args.repeats)
        win_rtf = 1.0 / (win * REALIZATION_RATE_HZ)
        dim = estimator(case, interval).layout.dim
        print(
            f"{case.name:<36} {dim:>4} {one * 1e6:>7.2f} {blk * 1e6:>8.2f} "
            f"{realize * 1e3:>8.2f} {rtf1:>7.1f} {rtf:>7.1f} {win * 1e3:>8.1f} "
            f"{win_rtf:>8.2f} {rtf / win_rtf:>9.1f} {blks[-1].modes:>6}"
        )
    print(
        "dim = rows of [U_p; Y_p; U_f; Y_f] = 2 i (m + l); upd = update() per sample without "
        "the realizations, fed 1 sample per call (1) or one realization interval per call "
        "(blk); RTF = data s / wall s of the whole estimator (updates + realizations); "
        "window = one batch identify() on the sliding window; speed-up = RTF blk / win RTF"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
