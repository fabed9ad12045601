"""Write the scenario bags of bags/ (fixed seeds): ``ros2_ws/env python bags/generate_bags.py``.

Each scenario is a rosbag2 directory ``bags/<name>`` (mcap, zstd file compression unless
``--no-compress``) with ``sysid_msgs/SignalSample`` topics ``/vibration`` (outputs),
``/excitation`` (inputs, absent when output-only) and scheduling signals (``/airspeed`` [m/s],
``/rotor_speed`` [Hz]), plus ``bags/<name>.truth.json`` with the true modes over time. The
scenarios themselves (what is simulated, seeds, truth) are ``sysid_node.scenarios.bags``.
"""

from __future__ import annotations

import argparse
import json
import shutil
import sys
from pathlib import Path

import numpy as np
from sysid_node.bag_io import BagError, read_signals, write_signals
from sysid_node.scenarios.bags import BAG_SCENARIOS as SCENARIOS
from sysid_node.scenarios.bags import START_TIME_S, BagScenario

BAGS = Path(__file__).resolve().parent


def write(scn: BagScenario, out: Path, storage: str = "mcap", compress: bool = True) -> Path:
    """Write ``out/<name>`` (replacing it) and ``out/<name>.truth.json``."""
    bag = out / scn.name
    if bag.exists():
        shutil.rmtree(bag)
    write_signals(
        bag,
        {topic: (START_TIME_S + t, v, names) for topic, (t, v, names) in scn.signals.items()},
        storage=storage,
        compress=compress,
    )
    (out / f"{scn.name}.truth.json").write_text(json.dumps(scn.truth(), indent=1) + "\n")
    return bag


def check(names: list[str], where: Path) -> int:
    """Print max |new - committed| / max |committed| per bag (1 if a bag is missing)."""
    print(f"{'bag':<20} {'max |new - bag| / max |bag|':>28}")
    status = 0
    for name in names:
        scn = SCENARIOS[name]()
        try:
            old = read_signals(where / name)
        except BagError as err:
            print(f"{name:<20} {'missing: ' + str(err)[:60]:>28}")
            status = 1
            continue
        err = max(float(np.max(np.abs(v - old[topic].values)) / np.max(np.abs(old[topic].values)))
                  for topic, (_, v, _) in scn.signals.items())
        print(f"{name:<20} {err:>28.2e}")
    return status


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument(
        "names", nargs="*", metavar="NAME", help=f"of {', '.join(SCENARIOS)}; default all"
    )
    ap.add_argument("--out", type=Path, default=BAGS, help="output directory (default bags/)")
    ap.add_argument("--storage", choices=("mcap", "sqlite3"), default="mcap")
    ap.add_argument("--no-compress", action="store_true", help="plain files (for viewers)")
    ap.add_argument("--check", action="store_true",
                    help="write nothing: print how far freshly simulated data lies from the bags")
    args = ap.parse_args(argv)
    unknown = [n for n in args.names if n not in SCENARIOS]
    if unknown:
        ap.error(f"unknown scenario {', '.join(unknown)}; choose from {', '.join(SCENARIOS)}")
    if args.check:
        return check(args.names or list(SCENARIOS), args.out)
    try:
        args.out.mkdir(parents=True, exist_ok=True)
        print(f"{'bag':<20} {'duration':>9} {'messages':>9} {'size':>9}  topics")
        for name in args.names or SCENARIOS:
            scn = SCENARIOS[name]()
            bag = write(scn, args.out, args.storage, not args.no_compress)
            size = sum(p.stat().st_size for p in bag.iterdir())
            count = sum(len(t) for t, _, _ in scn.signals.values())
            print(
                f"{name:<20} {scn.duration:>8.1f}s {count:>9d} {size / 1024:>7.0f}kB  "
                + " ".join(scn.signals)
            )
    except BagError as err:
        print(f"generate_bags: error: {err}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
