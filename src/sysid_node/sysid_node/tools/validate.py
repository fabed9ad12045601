"""validate: compare a DSRA model with a measurement, see where it fails, name the missing
physical effect, add it and re-fit.

    ros2_ws/run sysid_node validate (--bag BAG | --data FILE.npy|.csv --rate FS
        [--inputs COLS] [--outputs COLS] [--signals COLS] [--rows A:B] [--remove-mean])
        [--order N] [--block-rows I] [--split 0.6] [--add EFFECT[:k=v,...]] [--auto]
        [--signal NAME] [--model FILE] [--save-model FILE] [--report OUT.html] [--json OUT.json]

Errors (missing topics or columns, a record too short to split, a saved model of other
dimensions, an output file that cannot be written) print one line on stderr and exit with
status 2.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
from pathlib import Path

from ..bag_io import BagError
from ..core.inputs import InputError
from ..core.model import IdentifiedModel
from ..validation.augment import EFFECTS
from ..validation.data import ValidationData, ValidationError, load_arrays, load_bag
from ..validation.diagnose import verdict
from ..validation.workflow import Options, Outcome, run_validation


class _Parser(argparse.ArgumentParser):
    def error(self, message: str) -> None:  # one line, no usage block
        print(f"validate: error: {message}", file=sys.stderr)
        raise SystemExit(2)


def build_parser() -> argparse.ArgumentParser:
    ap = _Parser(prog="validate", description=__doc__.splitlines()[0])
    src = ap.add_mutually_exclusive_group(required=True)
    src.add_argument("--bag", help="rosbag2 directory (mcap or sqlite3)")
    src.add_argument("--data", help="plain arrays: .npy (N, columns) or .csv/.txt (header ok)")
    ap.add_argument("--rate", type=float, default=None, help="sample rate of --data [Hz]")
    ap.add_argument("--inputs", default=None, help="--data input columns (indices or names)")
    ap.add_argument("--outputs", default=None, help="--data output columns [all the others]")
    ap.add_argument("--signals", default=None, help="--data candidate signal columns [none]")
    ap.add_argument("--rows", default=None, help="--data rows START:STOP (0-based, half-open)")
    ap.add_argument(
        "--remove-mean", action="store_true", help="--data: subtract each column's mean"
    )
    ap.add_argument("--output", default="/vibration", help="output topic [/vibration]")
    ap.add_argument(
        "--input",
        default="/excitation",
        help="input topic [/excitation]; absent in the bag: output-only; '' forces it",
    )
    ap.add_argument(
        "--signal",
        default=None,
        help="the one candidate explanatory signal (default: every other topic; '' = none)",
    )
    ap.add_argument(
        "--split",
        type=float,
        default=0.6,
        help="estimation fraction, or the first validation sample when > 1 [0.6]",
    )
    ap.add_argument(
        "--split-mode",
        default="auto",
        choices=["auto", "chronological", "interleaved"],
        help="chronological, or interleaved blocks (auto: interleaved when the input's spectrum "
        "changes over the record, e.g. a sweep) [auto]",
    )
    ap.add_argument("--order", type=int, default=None, help="model order (default: chosen)")
    ap.add_argument(
        "--block-rows", type=int, default=None, help="block rows i of (A1) (default: chosen)"
    )
    ap.add_argument(
        "--order-method",
        default="validation",
        choices=["validation", "gap", "aic", "bic", "mdl"],
        help="order selection: held-out prediction error [validation] or the core's criteria",
    )
    ap.add_argument("--model", default=None, help="load the model from FILE instead of identifying")
    ap.add_argument("--save-model", default=None, help="save the final DSRA model to FILE (.npz)")
    ap.add_argument(
        "--add",
        action="append",
        default=[],
        metavar="EFFECT[:k=v,...]",
        help=f"add an effect and re-fit (repeatable); one of {', '.join(EFFECTS)}",
    )
    ap.add_argument(
        "--auto",
        action="store_true",
        help="add the top-ranked significant effects while the error keeps falling",
    )
    ap.add_argument("--max-lag", type=int, default=20, help="lags of the correlation tests [20]")
    ap.add_argument("--report", default=None, help="write an HTML report")
    ap.add_argument("--json", default=None, help="write the results as JSON")
    return ap


def parse_add(text: str) -> tuple[str, dict]:
    """'effect:key=value,key=value' -> (effect, {key: value}) with numbers converted."""
    name, _, rest = text.partition(":")
    name = name.strip()
    if name not in EFFECTS:
        raise ValidationError(f"unknown effect {name!r} in --add; one of {', '.join(EFFECTS)}")
    params: dict = {}
    for item in filter(None, (s.strip() for s in rest.split(","))):
        k, eq, v = item.partition("=")
        if not eq:
            raise ValidationError(f"--add {text}: expected key=value, got {item!r}")
        try:
            params[k.strip()] = int(v) if v.strip().lstrip("-").isdigit() else float(v)
        except ValueError:
            params[k.strip()] = v.strip()
    if "harmonics" in params:
        h = params["harmonics"]
        params["harmonics"] = (
            [int(h)]
            if isinstance(h, int | float)
            else [int(x) for x in str(h).replace("/", " ").replace("+", " ").split()]
        )
    return name, params


def check_output_path(path: str | None, flag: str) -> None:
    """Refuse an output file that cannot be written, before any work (one-line reason)."""
    if path is None:
        return
    p = Path(path)
    if p.is_dir():
        raise ValidationError(f"{flag} {path} is a directory, not a file")
    parent = p.parent
    existing = next(a for a in (parent, *parent.parents) if a.exists())
    if not existing.is_dir():
        raise ValidationError(f"{flag} {path}: {existing} is a file, not a directory")
    if existing != parent:
        raise ValidationError(f"{flag} {path}: directory {parent} does not exist")
    if not os.access(parent, os.W_OK):
        raise ValidationError(f"{flag} {path}: directory {parent} is not writable")


def _write_text(path: str, text: str, flag: str) -> None:
    try:
        with open(path, "w") as fh:
            fh.write(text)
    except OSError as err:
        raise ValidationError(f"{flag} {path}: cannot write ({err.strerror})") from None


def _load_model(path: str, data: ValidationData) -> IdentifiedModel:
    try:
        m = IdentifiedModel.load(path)
    except InputError as err:
        raise ValidationError(str(err)) from None
    except (OSError, ValueError, KeyError, TypeError) as err:
        raise ValidationError(f"cannot load model {path}: {' '.join(str(err).split())}") from None
    if m.n_outputs != data.n_outputs or m.n_inputs != data.n_inputs:
        raise ValidationError(
            f"saved model {path} has {m.n_outputs} output(s) and {m.n_inputs} input(s), the data "
            f"has {data.n_outputs} and {data.n_inputs}"
        )
    if abs(m.fs - data.fs) > 0.01 * data.fs:
        raise ValidationError(f"saved model {path} is at {m.fs:g} Hz, the data at {data.fs:g} Hz")
    return m


def load_data(args: argparse.Namespace) -> ValidationData:
    """The record named by --bag or --data."""
    if args.bag is not None:
        return load_bag(args.bag, output_topic=args.output, input_topic=args.input or None)
    if args.rate is None:
        raise ValidationError("--data needs --rate (the sample rate [Hz])")
    return load_arrays(
        args.data, args.rate, args.outputs, args.inputs, args.signals, args.rows, args.remove_mean
    )


def run(args: argparse.Namespace) -> dict:
    """Run validate as the CLI does; returns the JSON result."""
    adds = [parse_add(text) for text in args.add]  # refuse a bad --add before any work
    for path, flag in (
        (args.report, "--report"),
        (args.json, "--json"),
        (args.save_model, "--save-model"),
    ):
        check_output_path(path, flag)
    data = load_data(args)
    opts = Options(
        split=args.split,
        split_mode=args.split_mode,
        order=args.order,
        block_rows=args.block_rows,
        order_method=args.order_method,
        add=adds,
        auto=args.auto,
        signal=args.signal,
        max_lag=args.max_lag,
        model=_load_model(args.model, data) if args.model else None,
    )
    out = run_validation(data, opts, source=str(args.bag or args.data))
    result = out.result()
    _print(out, result)
    if args.save_model:
        if out.current.model is None or out.current.locals:
            raise ValidationError("--save-model: the final structure is not a single DSRA model")
        try:
            out.current.model.save(args.save_model)
        except OSError as err:
            raise ValidationError(
                f"--save-model {args.save_model}: cannot write ({err.strerror})"
            ) from None
    if args.json:
        _write_text(args.json, json.dumps(result, indent=1, allow_nan=False), "--json")
    if args.report:
        from ..validation.report import write_report

        try:
            write_report(args.report, out)
        except OSError as err:
            raise ValidationError(
                f"--report {args.report}: cannot write ({err.strerror})"
            ) from None
    return result


def _fmt(values, width: int = 6) -> str:
    if values is None:
        return "-"
    return " ".join(f"{v:{width}.1f}" if v is not None else "-" for v in values)


def _print(out: Outcome, r: dict) -> None:
    sp = r["split"]
    print(
        f"validate {r['source']}: {r['n_estimation']} estimation + {r['n_validation']} "
        f"validation samples at {r['fs']:.6g} Hz ({sp['mode']}"
        + (f": {sp['reason']}" if sp["reason"] else "")
        + f"), inputs {r['inputs'] or 'none (output-only)'}, "
        f"candidate signals {r['candidate_signals'] or 'none'}"
    )
    if r["baseline"]:
        b = r["baseline"]
        print(f"baseline: {b['note']}")
    what = "free-run" if r["primary"] == "free_run" else "one-step"
    print(f"scored on the {what} prediction (primary)" + (
        f": {r['primary_note']}" if r["primary_note"] else ""))
    print("\nhypotheses (score = trial drop of the primary validation error; feedback: of the "
          "input's one-step error):")
    for k, h in enumerate(r["diagnoses"], 1):
        mark = "*" if h["significant"] else " "
        params = json.dumps(h["parameters"])
        ranked = (f" (ranked on the loop model's output drop {h['rank_score']:.2f})"
                  if h["rank_score"] != h["score"] else "")
        print(f" {k}.{mark} {h['effect']:21s} score {h['score']:5.2f}{ranked}  {params}")
        print(f"       {h['evidence']}")
    print(f"\nverdict: {verdict(out.before, out.hyps)['text']}")
    names = out.data.output_names
    print(f"\n{'model':34s} {'channel':>10s} {'fit free-run %':>15s} {'fit 1-step %':>13s}")
    rows = [("before", r["before"])] + (
        [("after +" + "+".join(r["added"]), r["after"])] if r["added"] else []
    )
    for label, s in rows:
        for c in range(len(names)):
            free = s["fit_free_run_percent"]
            fv = "-" if free is None or free[c] is None else f"{free[c]:.1f}"
            ov = s["fit_percent"][c]
            print(
                f"{label if c == 0 else '':34s} {names[c][:10]:>10s} {fv:>15s} "
                f"{'-' if ov is None else f'{ov:.1f}':>13s}"
            )
        if s["free_run_note"]:
            print(f"{'':34s} ({s['free_run_note']})")
    if r["added"]:
        for st in r["steps"]:
            print(
                f"+{st['model']}: {what} NRMSE {100 * st['primary_nrmse']:.2f} % "
                f"({100 * st['drop']:.0f} % lower)"
            )
        print(f"{what} validation error drop: {100 * r['error_drop']:.1f} %")
    print(f"({r['seconds']:.2f} s)")


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        run(args)
    except (BagError, ValidationError, InputError) as err:
        print(f"validate: error: {' '.join(str(err).split())}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("validate: interrupted", file=sys.stderr)
        return 130
    return 0


if __name__ == "__main__":
    sys.exit(main())
