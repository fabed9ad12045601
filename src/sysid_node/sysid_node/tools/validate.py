"""validate: compare a DSRA model with a bag, see where it fails, name the missing physical
effect, add it and re-fit.

    ros2_ws/run sysid_node validate --bag BAG [--order 4] [--split 0.6] [--add EFFECT[:k=v,...]]
        [--auto] [--signal TOPIC] [--model FILE] [--save-model FILE] [--report OUT.html]
        [--json OUT.json]

Errors (missing topics, a record too short to split, a saved model of other dimensions) print
one line on stderr and exit with status 2.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
from pathlib import Path

import numpy as np

from ..bag_io import BagError
from ..core.inputs import InputError
from ..core.model import IdentifiedModel
from ..validation.augment import EFFECTS, FittedModel, ModelSpec, fit
from ..validation.data import ValidationData, ValidationError, load_bag
from ..validation.diagnose import Assessment, Hypothesis, _jsonable, assess, diagnose

AUTO_MIN_GAIN = 0.05  # --auto keeps adding while the residual RMS falls by at least 5 %


class _Parser(argparse.ArgumentParser):
    def error(self, message: str) -> None:  # one line, no usage block
        print(f"validate: error: {message}", file=sys.stderr)
        raise SystemExit(2)


def build_parser() -> argparse.ArgumentParser:
    ap = _Parser(prog="validate", description=__doc__.splitlines()[0])
    ap.add_argument("--bag", required=True, help="rosbag2 directory (mcap or sqlite3)")
    ap.add_argument("--output", default="/vibration", help="output topic [/vibration]")
    ap.add_argument(
        "--input",
        default="/excitation",
        help="input topic [/excitation]; absent in the bag: output-only; '' forces it",
    )
    ap.add_argument(
        "--signal",
        default=None,
        help="the one candidate explanatory signal (default: every other topic)",
    )
    ap.add_argument("--split", type=float, default=0.6, help="estimation fraction [0.6]")
    ap.add_argument("--order", type=int, default=None, help="model order (default: gap method)")
    ap.add_argument("--block-rows", type=int, default=20, help="block rows i of (A1) [20]")
    ap.add_argument("--order-method", default="gap", choices=["gap", "aic", "bic", "mdl"])
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


def _load_model(path: str, data: ValidationData, spec: ModelSpec) -> FittedModel:
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
    return FittedModel(spec, m.order, model=m, n_outputs=data.n_outputs)


def _mean_ratio(after: np.ndarray, before: np.ndarray) -> float:
    return float(np.mean(np.asarray(after) / np.asarray(before)))


def _row(label: str, a: Assessment) -> str:
    def fmt(v) -> str:
        return "  -  " if v is None else " ".join(f"{x:6.1f}" for x in v)

    return (
        f"{label:28s} {fmt(a.fit_percent):>12s} {fmt(a.fit_free_run_percent):>12s} "
        f"{' '.join(f'{x:10.4g}' for x in a.residual_rms):>12s} "
        f"{min(w.p_value for w in a.whiteness):10.2g} "
        + (
            f"{min(min(x.p_past, x.p_future) for x in a.xcorr.values()):10.2g}"
            if a.xcorr
            else "      -   "
        )
    )


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


def run(args: argparse.Namespace) -> dict:
    adds = [parse_add(text) for text in args.add]  # refuse a bad --add before any work
    for path, flag in (
        (args.report, "--report"),
        (args.json, "--json"),
        (args.save_model, "--save-model"),
    ):
        check_output_path(path, flag)
    data = load_bag(
        args.bag,
        output_topic=args.output,
        input_topic=args.input or None,
        signal_topics=None,
    )
    if args.signal is not None and args.signal not in data.signals:
        raise ValidationError(
            f"no candidate signal {args.signal} in bag {args.bag}; available: "
            + (", ".join(sorted(data.signals)) or "-")
        )
    br = args.block_rows
    n_est = data.split_index(args.split, 2 * br * (1 + data.n_inputs + data.n_outputs) + 50)
    spec = ModelSpec(order=args.order, block_rows=br, order_method=args.order_method)
    if args.model:
        base = _load_model(args.model, data, spec)
    else:
        base = fit(spec, data, n_est)
    spec.order = base.order
    base.spec = spec
    before = assess(base, data, n_est, args.max_lag)
    hyps = diagnose(data, n_est, spec, base, before, signal=args.signal)
    current, cur_a, cur_spec = base, before, spec
    added: list[str] = []
    for name, params in adds:
        diag = next(h for h in hyps if h.effect == name)
        merged = {**{k: v for k, v in diag.parameters.items() if v is not None}, **params}
        if name == "input_delay":
            merged.setdefault("fs", data.fs)
        cur_spec = cur_spec.with_effect(name, merged)
        added.append(name)
    if len(adds) == 1 and not adds[0][1]:
        diag = next(h for h in hyps if h.effect == adds[0][0])
        if diag.trial is not None:  # the diagnosis already re-fitted exactly this structure
            current = diag.trial
            cur_spec = current.spec
    if added:
        if current is base:
            current = fit(cur_spec, data, n_est)
        cur_a = assess(current, data, n_est, args.max_lag)
    if args.auto:
        cur_hyps = (
            hyps if not added else diagnose(data, n_est, cur_spec, current, cur_a, args.signal)
        )
        for _ in range(len(EFFECTS)):
            top = next((h for h in cur_hyps if h.significant and h.trial is not None), None)
            if top is None:
                break
            cand_a = assess(top.trial, data, n_est, args.max_lag)
            if _mean_ratio(cand_a.residual_rms, cur_a.residual_rms) > 1 - AUTO_MIN_GAIN:
                break
            current, cur_a = top.trial, cand_a
            cur_spec = current.spec
            added.append(top.effect)
            cur_hyps = diagnose(data, n_est, cur_spec, current, cur_a, args.signal)
    result = {
        "bag": str(args.bag),
        "fs": data.fs,
        "n_estimation": n_est,
        "n_validation": data.n - n_est,
        "outputs": data.output_names,
        "inputs": data.input_names,
        "candidate_signals": sorted(data.signals),
        "order": base.order,
        "before": before.summary(),
        "diagnoses": [h.to_dict() for h in hyps],
        "added": added,
        "after": cur_a.summary(),
        "residual_rms_reduction": 1 - _mean_ratio(cur_a.residual_rms, before.residual_rms),
    }
    _print(result, before, cur_a, hyps, added)
    if args.save_model:
        if current.model is None:
            raise ValidationError("--save-model: the final structure is not a single DSRA model")
        try:
            current.model.save(args.save_model)
        except OSError as err:
            raise ValidationError(
                f"--save-model {args.save_model}: cannot write ({err.strerror})"
            ) from None
    if args.json:
        _write_text(args.json, json.dumps(_jsonable(result), indent=1), "--json")
    if args.report:
        from ..validation.report import write_report

        try:
            write_report(args.report, data, n_est, base, before, current, cur_a, hyps, added)
        except OSError as err:
            raise ValidationError(
                f"--report {args.report}: cannot write ({err.strerror})"
            ) from None
    return result


def _print(result, before, after, hyps: list[Hypothesis], added) -> None:
    print(
        f"validate {result['bag']}: {result['n_estimation']} estimation + "
        f"{result['n_validation']} validation samples at {result['fs']:.4g} Hz, "
        f"order {result['order']}, inputs {result['inputs'] or 'none (output-only)'}, "
        f"candidate signals {result['candidate_signals'] or 'none'}"
    )
    print("\nhypotheses (score = trial drop of the validation residual RMS):")
    for k, h in enumerate(hyps, 1):
        mark = "*" if h.significant else " "
        params = json.dumps(_jsonable(h.parameters))
        print(f" {k}.{mark} {h.effect:21s} score {h.score:5.2f}  {params}")
        print(f"       {h.evidence}")
    if not any(h.significant for h in hyps):
        print(" no significant hypothesis")
    print(
        f"\n{'model':28s} {'fit 1-step %':>12s} {'fit free %':>12s} {'resid RMS':>12s} "
        f"{'white p':>10s} {'xcorr p':>10s}"
    )
    print(_row("before", before))
    if added:
        print(_row("after +" + "+".join(added), after))
        print(f"residual RMS reduction: {100 * result['residual_rms_reduction']:.1f} %")


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
