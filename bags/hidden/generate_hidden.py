#!/usr/bin/env python3
"""Write the hidden-effect scenario bags (one per effect plus a clean control), fixed seeds.

Usage: ros2_ws/env python bags/hidden/generate_hidden.py [--out bags/hidden] [--force | --check]

Each bag holds /vibration and /excitation (sysid_msgs/SignalSample, 50 Hz) and the slow
candidate signals of its scenario (/airspeed, /rotor_speed at 10 Hz); see
sysid_node.scenarios.bags (hidden_effect) for what is hidden in each. The nominal model is the
2-mode structure of Sec. II: validate them with ``--order 4``.
"""

from __future__ import annotations

import argparse
import shutil
import sys
from pathlib import Path

import numpy as np
from sysid_node.bag_io import BagError, read_signals, write_signals
from sysid_node.scenarios.bags import HIDDEN_SCENARIOS, HIDDEN_SEEDS, hidden_effect


def check(where: Path) -> int:
    """Print max |new - committed| / max |committed| per bag (1 if a bag is missing)."""
    print(f"{'bag':<22} {'max |new - bag| / max |bag|':>28}")
    status = 0
    for name in HIDDEN_SCENARIOS:
        sc = hidden_effect(name, seed=HIDDEN_SEEDS[name])
        try:
            old = read_signals(where / name)
        except BagError as err:
            print(f"{name:<22} missing: {err}")
            status = 1
            continue
        err = max(float(np.max(np.abs(v - old[t].values)) / np.max(np.abs(old[t].values)))
                  for t, v in (("/vibration", sc.y), ("/excitation", sc.u)))
        print(f"{name:<22} {err:>28.2e}")
    return status


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default=str(Path(__file__).resolve().parent))
    ap.add_argument("--force", action="store_true", help="overwrite existing bags")
    ap.add_argument("--check", action="store_true",
                    help="write nothing: print how far freshly simulated data lies from the bags")
    args = ap.parse_args(argv)
    out = Path(args.out)
    if args.check:
        return check(out)
    out.mkdir(parents=True, exist_ok=True)
    for name in HIDDEN_SCENARIOS:
        path = out / name
        if path.exists():
            if not args.force:
                print(f"{path} exists (use --force)")
                continue
            shutil.rmtree(path)
        sc = hidden_effect(name, seed=HIDDEN_SEEDS[name])
        topics = {"/vibration": (sc.t, sc.y, ["y0"]), "/excitation": (sc.t, sc.u, ["u0"])}
        for topic, (ts, v) in sc.signals.items():
            topics[topic] = (ts, v[:, None], [topic.strip("/")])
        write_signals(path, topics, storage="mcap", compress=True)
        size = sum(f.stat().st_size for f in path.rglob("*") if f.is_file())
        print(f"{name:22s} {size / 1024:7.1f} KB  truth {sc.truth}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
