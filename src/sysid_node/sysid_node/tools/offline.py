"""``offline``: the node's processing over a bag, without DDS, as fast as possible.

    ros2 run sysid_node offline --bag IN --output OUT [--params-file FILE] [--report OUT.html]

Reads the output (and input, and scheduling) topic messages of a bag in log-time order,
converts each message with the node's own conversion and feeds
:class:`sysid_node.pipeline.Pipeline`, exactly as the node does; publication instants come from
the sample stamps, so the run is deterministic and matches a live replay (with
``scheduling_topic``, each estimate's scheduling value and LPV-predicted modes too: they use
only the samples stamped at or before the estimate). Writes ``/modal_estimate``
(``sysid_msgs/msg/ModalEstimate``) into the rosbag2 bag ``OUT``, one CSV row per mode per
estimate to ``OUT.csv`` and a JSON summary to ``OUT.json``; ``--report`` writes an HTML page
(modes against time, with the truth when the bag has a ``<bag>.truth.json`` beside it, the
final modes and the summary as tables). The parameter file is the node's
(``sysid_node: ros__parameters: ...``).
A bad bag or parameter file ends the run with a one-line reason and exit status 2.
"""

from __future__ import annotations

import argparse
import csv
import json
import math
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

from sysid_node import msg_convert as mc
from sysid_node import params as P
from sysid_node.pipeline import Pipeline
from sysid_node.records import EstimateRecord
from sysid_node.topics import resolve

NODE_NAME = "sysid_node"
ESTIMATE_TOPIC = "modal_estimate"  # relative, as the node publishes it
ESTIMATE_TYPE = "sysid_msgs/msg/ModalEstimate"
#: Message type of the scheduling topic (as the node subscribes to it).
SCHEDULING_TYPE = "SignalSample"
TYPE_NAMES = {
    "sysid_msgs/msg/SignalSample": "SignalSample",
    "sysid_msgs/msg/SignalBlock": "SignalBlock",
    "sensor_msgs/msg/Imu": "Imu",
}


class OfflineError(RuntimeError):
    """Ends the run with a one-line reason."""


def load_params_file(path: Path, node_name: str = NODE_NAME) -> dict[str, Any]:
    """Parameters for ``node_name`` from a ROS 2 YAML parameter file, checked as the node checks
    them at start-up (``params_file``: unknown names and near-miss node names refused with the
    closest valid name); invalid values raise OfflineError."""
    from sysid_node import params_file as PF

    try:
        values = PF.node_values(PF.read(path), node_name, P.SPECS, path=path)
    except PF.ParamsFileError as err:
        raise OfflineError(str(err)) from None
    for k in PF.ROS_OWN:
        values.pop(k, None)
    for k, v in values.items():
        if P.SPECS[k].type is float and isinstance(v, int) and not isinstance(v, bool):
            values[k] = float(v)
    reason = P.validate_set({**P.defaults(), **values})
    if reason:
        raise OfflineError(f"parameter file {path}: {reason}")
    return values


def _bag_topics(bag: Path) -> dict[str, tuple[str, int]]:
    from sysid_node import bag_io

    return bag_io.list_topics(bag)


class Progress:
    """A plain-text progress bar on stderr (one line rewritten with carriage returns)."""

    def __init__(self, total: int, enabled: bool = True, width: int = 30) -> None:
        self.total, self.enabled, self.width = max(total, 1), enabled, width
        self._last = -1.0
        self._t0 = time.monotonic()

    def update(self, done: int, note: str = "") -> None:
        if not self.enabled or self._last >= 1.0:
            return
        frac = min(done / self.total, 1.0)
        if frac - self._last < 0.01 and frac < 1.0:
            return
        self._last = frac
        n = int(frac * self.width)
        bar = "#" * n + "." * (self.width - n)
        el = time.monotonic() - self._t0
        sys.stderr.write(f"\roffline [{bar}] {100 * frac:5.1f}% {el:6.1f} s {note:<24}")
        if frac >= 1.0:
            sys.stderr.write("\n")
        sys.stderr.flush()


def run(
    bag: Path,
    values: dict[str, Any] | None = None,
    progress: bool = False,
    log=None,
    namespace: str = "/",
) -> tuple[list[EstimateRecord], Pipeline, dict[str, Any]]:
    """Run the pipeline over ``bag``; return the records, the pipeline and run information.

    Relative topic names (the defaults, ``vibration``) are looked up in the bag as a node in
    ``namespace`` resolves them (``/vibration`` at the root)."""
    from sysid_node import bag_io

    values = dict(values or {})
    pipeline = Pipeline(values, log=log)
    v = pipeline.values
    topics = _bag_topics(bag)
    out_topic = resolve(v["output_topic"], namespace)
    in_topic = resolve(v["input_topic"], namespace) if v["input_topic"] else ""
    if out_topic not in topics:
        raise OfflineError(
            f"no topic {out_topic} in bag {bag}; available: {', '.join(sorted(topics)) or '-'}"
        )
    selected = {"output": out_topic}
    if in_topic and not v["output_only"] and in_topic in topics:
        selected["input"] = in_topic
    sched_topic = resolve(v["scheduling_topic"], namespace) if v["scheduling_topic"] else ""
    if sched_topic in topics:
        selected["scheduling"] = sched_topic
    elif sched_topic and log:
        log(f"no scheduling topic {sched_topic} in the bag: no scheduling value, no prediction")
    kinds: dict[str, str] = {}
    for stream, topic in selected.items():
        msgtype = topics[topic][0]
        if msgtype not in TYPE_NAMES:
            raise OfflineError(
                f"topic {topic} in bag {bag} has type {msgtype}; supported: "
                + ", ".join(TYPE_NAMES)
            )
        kinds[topic] = TYPE_NAMES[msgtype]
        if stream == "scheduling" and kinds[topic] != SCHEDULING_TYPE:
            raise OfflineError(f"scheduling topic {topic} in bag {bag} has type {msgtype}; "
                               f"the node subscribes to it as {SCHEDULING_TYPE}")
        if stream != "scheduling" and kinds[topic] != v[f"{stream}_type"] and log:
            log(f"{topic} is {kinds[topic]} in the bag ({stream}_type is {v[stream + '_type']})")
    stream_of = {t: s for s, t in selected.items()}
    axes = P.parse_axes(v["imu_axes"])
    total = sum(topics[t][1] for t in selected.values())
    bar = Progress(total, enabled=progress)
    ts = bag_io.typestore()
    records: list[EstimateRecord] = []
    n = 0
    t_start = time.perf_counter()
    batch: list[tuple[str, np.ndarray, np.ndarray]] = []
    for conn, _log_ns, raw in bag_io.iter_messages(bag, list(selected.values())):
        try:
            msg = ts.deserialize_cdr(raw, conn.msgtype)
        except Exception as err:
            raise OfflineError(
                f"cannot decode a {conn.msgtype} message on {conn.topic} in {bag}: "
                f"{' '.join(str(err).split())[:200]}"
            ) from None
        stream = stream_of[conn.topic]
        try:
            stamps, vals = mc.to_arrays(msg, kinds[conn.topic], axes)
        except (ValueError, TypeError, AttributeError) as err:  # one bad message: counted
            pipeline.ingest.reject(stream, 1, "unreadable", f"{stream}: unreadable message: {err}")
            continue
        names = mc.channel_names(msg, kinds[conn.topic], axes)
        if names != pipeline.channel_names.get(stream):
            pipeline.set_channel_names(stream, names)
        batch.append((stream, stamps, vals, tuple(names) or None))
        n += 1
        if len(batch) >= 64:
            records += _process(pipeline, batch)
            batch = []
            bar.update(n, f"{len(records)} estimates")
    records += _process(pipeline, batch)
    records += pipeline.step(flush=True)
    bar.update(total, f"{len(records)} estimates")
    wall = time.perf_counter() - t_start
    info = {
        "bag": str(bag),
        "topics": selected,
        "messages": n,
        "wall_time_s": wall,
        "mode": pipeline.ingest.mode,
    }
    return records, pipeline, info


def _process(pipeline: Pipeline, batch: list) -> list[EstimateRecord]:
    """Feed messages as the node's worker does: per stream, stacked blocks; then one step."""
    pushes = {"output": pipeline.push_output, "input": pipeline.push_input,
              "scheduling": pipeline.push_scheduling}
    for stream, push in pushes.items():
        for t, v, names in mc.stack_named([b[1:] for b in batch if b[0] == stream]):
            push(t, v, names)
    records = pipeline.step()
    pipeline.pop_spectra()  # /residual_spectrum is a live view; the offline outputs omit it
    return records


CSV_FIELDS = [
    "stamp",
    "samples_used",
    "converged",
    "forgetting_factor",
    "model_order",
    "prediction_error_rms",
    "mode_id",
    "status",
    "frequency_hz",
    "frequency_std_hz",
    "damping_ratio",
    "damping_std",
    "amplitude",
    "age_s",
]


def write_csv(path: Path, records: list[EstimateRecord]) -> None:
    """One row per mode per estimate (an estimate without modes gives one row, mode fields
    empty)."""
    with path.open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(CSV_FIELDS)
        for r in records:
            head = [
                f"{r.stamp_ns * 1e-9:.9f}",
                r.samples_used,
                int(r.converged),
                f"{r.forgetting_factor:.6g}",
                r.model_order,
                f"{r.prediction_error_rms:.6g}",
            ]
            if not r.modes:
                w.writerow(head + [""] * 8)
            for m in r.modes:
                w.writerow(
                    head
                    + [m.id, m.status]
                    + [
                        f"{x:.6g}"
                        for x in (
                            m.frequency_hz,
                            m.frequency_std_hz,
                            m.damping_ratio,
                            m.damping_std,
                            m.amplitude,
                            m.age_s,
                        )
                    ]
                )


def write_bag(path: Path, records: list[EstimateRecord], namespace: str = "/") -> None:
    from sysid_node import bag_io

    ts = bag_io.typestore()
    topic = resolve(ESTIMATE_TOPIC, namespace)
    with bag_io.BagWriter(path) as bag:
        bag.add_topic(
            topic,
            ESTIMATE_TYPE,
            [bag_io.make_qos(reliable=True, transient_local=True, depth=1)],
        )
        for r in records:
            bag.write(topic, r.stamp_ns, mc.estimate_rosbags(r, ts))


def summary(records: list[EstimateRecord], pipeline: Pipeline, info: dict) -> dict[str, Any]:
    last = records[-1] if records else None
    data_s = (records[-1].stamp_ns - records[0].stamp_ns) * 1e-9 if len(records) > 1 else 0.0
    return {
        **info,
        "parameters": pipeline.values,
        "sample_rate_hz": pipeline.sample_rate,
        "estimates": len(records),
        "data_time_s": data_s,
        "realtime_factor": data_s / info["wall_time_s"] if info["wall_time_s"] > 0 else math.nan,
        "update_cost_us_per_sample": (
            1e6 * pipeline.update_seconds / pipeline.update_samples
            if pipeline.update_samples
            else math.nan
        ),
        "counters": pipeline.counters,
        **pipeline.scheduling_status(),
        "final": last.to_dict() if last else None,
    }


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(
        prog="offline", description="Run sysid_node's processing over a bag, without DDS."
    )
    ap.add_argument("--bag", required=True, type=Path, help="input rosbag2 (mcap or sqlite3)")
    ap.add_argument(
        "--output",
        required=True,
        type=Path,
        help="output bag with /modal_estimate; OUT.csv and OUT.json are written too",
    )
    ap.add_argument("--params-file", type=Path, help="the node's YAML parameter file")
    ap.add_argument(
        "--namespace",
        default="/",
        metavar="NS",
        help="resolve relative topic names as a node in NS does (default /: vibration -> "
        "/vibration; left_wing: /left_wing/vibration)",
    )
    ap.add_argument("--quiet", action="store_true", help="no progress bar, no log lines")
    ap.add_argument("--report", type=Path, help="HTML report (modes against time, tables)")
    args = ap.parse_args(argv)
    from sysid_node.bag_io import BagError

    def log(text: str) -> None:
        if not args.quiet:
            print(f"[offline] {text}", file=sys.stderr)

    try:
        values = load_params_file(args.params_file) if args.params_file else {}
        if args.output.exists():
            raise OfflineError(f"output already exists: {args.output}")
        if not args.output.parent.is_dir():
            raise OfflineError(f"output directory does not exist: {args.output.parent}")
        if args.report and not args.report.parent.is_dir():
            raise OfflineError(f"report directory does not exist: {args.report.parent}")
        records, pipeline, info = run(
            args.bag, values, progress=not args.quiet, log=log, namespace=args.namespace
        )
        if not records:
            raise OfflineError(
                f"no estimate could be made from {args.bag} "
                f"(counters: {pipeline.counters or 'no samples'})"
            )
        write_bag(args.output, records, args.namespace)
        csv_path = args.output.with_name(args.output.name + ".csv")
        json_path = args.output.with_name(args.output.name + ".json")
        write_csv(csv_path, records)
        summ = summary(records, pipeline, info)
        json_path.write_text(json.dumps(summ, indent=2, default=_json_default))
        if args.report:
            write_report(args.report, args.bag, records, summ)
    except (OfflineError, BagError, ValueError) as err:
        print(f"offline: error: {err}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("offline: interrupted", file=sys.stderr)
        return 130
    last = records[-1]
    freqs = ", ".join(f"{m.frequency_hz:.3f} Hz ({m.status})" for m in last.modes) or "none"
    print(
        f"offline: {len(records)} estimates from {info['messages']} messages in "
        f"{info['wall_time_s']:.2f} s -> {args.output} (+ .csv, .json); last: {freqs}"
    )
    return 0


def write_report(path: Path, bag: Path, records: list[EstimateRecord], summ: dict) -> Path:
    """HTML page: modes against time (truth overlaid when ``<bag>.truth.json`` exists), the
    final modes and the run's summary as tables."""
    from sysid_node.report import Page, figure, mode_points, mode_table, plot_mode_tracks
    from sysid_node.scenarios.truth import TrueMode

    truth_file = bag.parent / f"{bag.name}.truth.json"
    truth = json.loads(truth_file.read_text()) if truth_file.exists() else {}
    t0 = truth.get("start_time_s", records[0].stamp_ns * 1e-9)
    modes = [TrueMode(m["name"], m.get("kind", "structural"), m["t_s"], m["frequency_hz"],
                      m["damping_ratio"]) for m in truth.get("modes", [])]
    points = mode_points(records, t0)
    page = Page(f"offline: {bag.name}")
    fig, ax = figure(2, 1, 10, 3.2, sharex=True)
    plot_mode_tracks(ax[0, 0], ax[1, 0], points, truth=modes)
    ax[0, 0].set_title("Identified modes (2-sigma band; faint: tentative or lost"
                       + ("; dashed: truth)" if modes else ")"))
    page.heading("Modes against time").figure(fig)
    page.heading("Final estimate").table(*mode_table(points))
    summ = {k: v for k, v in summ.items() if k != "final"}
    page.heading("Run").summary(summ)
    return page.write(path)


def _json_default(x: Any) -> Any:
    if isinstance(x, np.ndarray):
        return x.tolist()
    if isinstance(x, np.generic):
        return x.item()
    return str(x)


if __name__ == "__main__":
    sys.exit(main())
