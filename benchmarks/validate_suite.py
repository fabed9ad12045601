#!/usr/bin/env python3
"""The randomized hidden-effect suite of ``validate`` (issue #11): prints the confusion matrix
(effect drawn vs effect ranked first), the share ranked right and the median drop of the
validation error per effect, the clean cases' additions, every gate's false-alarm rate on the
clean cases and the time per case.

    ros2_ws/env python benchmarks/validate_suite.py [--per-effect 15] [--clean 40] [--workers 2]
        [--failures] [--ceiling] [--input-noise 0.01] [--json PATH]

The issue's suite (15 cases per effect, 40 clean); ``src/sysid_node/test/test_validation_suite.py``
runs its first 6 cases per effect and all 40 clean ones (seeded draws of
``sysid_node.scenarios.draw_effects``; see ``sysid_node.validation.suite``). ``--failures``
prints the per-case breakdown of the effect cases not ranked right. ``--ceiling`` also validates
every effect case's clean twin (the same draw without the effect) and prints, per effect, the
median ceiling (how far the baseline's error falls without the effect: the error the effect
adds, what adding it can be expected to remove; for feedback, which has no twin, the drop of
the input's held-out error the true loop gives, ``suite.loop_ceiling``) and the share ranked
right among the cases whose ceiling is at least 10 %.
``--input-noise F`` measures every case's input with white noise of F x its RMS (the generator's
inputs are exact; a measured force or command is not): the gates' false-alarm rates on the clean
cases with a measured input.
``--json`` writes the summary and every case's result.
"""

from __future__ import annotations

import argparse
import json
import time
from dataclasses import asdict

from sysid_node.validation import suite as S


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--per-effect", type=int, default=S.CASES_PER_EFFECT)
    ap.add_argument("--clean", type=int, default=S.CLEAN_CASES)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--failures", action="store_true",
                    help="one line per effect case not ranked right (gate, trial drop, note)")
    ap.add_argument("--ceiling", action="store_true",
                    help="also the clean twin's baseline error: the error each effect adds")
    ap.add_argument("--input-noise", type=float, default=0.0, metavar="F",
                    help="measure the input with white noise of F x its RMS (default 0: exact)")
    ap.add_argument("--json", metavar="PATH", help="write the summary and every case's result")
    args = ap.parse_args()
    t0 = time.perf_counter()
    results = S.run_suite(S.cases(args.per_effect, args.clean), args.workers, args.ceiling,
                           args.input_noise)
    wall = time.perf_counter() - t0
    sm = S.summary(results)
    print(S.confusion_table(results))
    print(f"\n{'effect':22s} {'cases':>5s} {'right first':>12s} {'median drop':>12s} "
          f"{'median size':>12s} {'short of size':>14s}")
    for eff, row in sm["effects"].items():
        print(
            f"{eff:22s} {row['cases']:5d} {100 * row['right_first']:11.0f}% "
            f"{100 * row['median_drop']:11.0f}% {row['median_size']:12.1f} "
            f"{row['short_of_size']:14d}"
        )
    print("(size: x the output noise, the disturbance's response + the measurement noise; short "
          "of size: under 90 % of the size drawn, the strength at its bound)")
    if args.ceiling:
        print(f"\n{'effect':22s} {'median ceiling':>15s} {'detectable':>11s} "
              f"{'right first of them':>20s} {'their median drop':>18s}")
        for eff, row in sm["effects"].items():
            if "detectable" in row:
                print(f"{eff:22s} {100 * row['median_ceiling']:14.0f}% {row['detectable']:11d} "
                      f"{100 * row['right_first_detectable']:19.0f}% "
                      f"{100 * row['median_drop_detectable']:17.0f}%")
        print(f"(detectable: ceiling >= {100 * S.DETECTABLE:.0f} %)")
    print(f"\nmedian drop of the validation error over the effect cases: "
          f"{100 * sm['median_drop']:.0f} %")
    print(f"clean cases: {sm['clean_cases']}, nothing added in "
          f"{100 * sm['clean_nothing_added']:.0f} % (added: {sm['clean_added'] or 'none'})")
    print("gate false-alarm rate on the clean cases (p < 0.01 before the trial): "
          + ", ".join(f"{g} {100 * r:.0f} %" for g, r in sm["gate_false_alarm"].items()))
    print(f"{len(results)} cases in {wall:.0f} s on {args.workers} workers "
          f"({sm['seconds_per_case']:.2f} s of validate per case, draws excluded)")
    for err in sm["errors"]:
        print("error:", err)
    if args.failures:
        print("\neffect cases not ranked right:\n" + S.failures(results))
    if args.json:
        with open(args.json, "w") as f:
            json.dump({"summary": sm, "cases": [asdict(r) for r in results]}, f, indent=1,
                      default=float)


if __name__ == "__main__":
    main()
