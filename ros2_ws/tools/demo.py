"""The main job: replay a scenario bag through sysid_node and notch_filter_node over real DDS.

Starts both nodes and a recorder in their own process groups, replays the bag, stops everything
by process group, then prints modes and notch centres over time and writes an HTML report:
modes tracked against time (the paper's Fig. 2), notch centres over the estimated modes, and the
spectrum of the signal before and after the notch bank.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

from find_executable import find
from sysid_node.process_group import stop_group

REPO = Path(__file__).resolve().parents[2]
DEFAULT_BAG = REPO / "bags" / "paper_example"
DEFAULT_PARAMS = REPO / "src" / "notch_filter_node" / "config" / "adaptive_notch.yaml"
RECORDED = ["/vibration", "/vibration_filtered", "/modal_estimate", "/notch_bank"]


class DemoError(RuntimeError):
    """Ends the demo with a one-line reason."""


def _start(argv: list[str], log: Path) -> subprocess.Popen:
    fh = log.open("w")
    return subprocess.Popen(argv, stdout=fh, stderr=subprocess.STDOUT, start_new_session=True)


def _wait_until_quiet(topic: str, quiet_s: float = 1.5, limit_s: float = 30.0) -> None:
    """Return once ``topic`` has carried no message for ``quiet_s`` (at most ``limit_s``): on a
    busy machine the nodes finish the replayed data seconds after the player, and a fixed pause
    cut the end of the recording."""
    import rclpy
    from rclpy.qos import qos_profile_sensor_data
    from sysid_node.tools import msg_class

    rclpy.init()
    node = rclpy.create_node("demo_drain")
    try:
        t_end = time.monotonic() + limit_s
        last = [time.monotonic()]
        sub = None
        while time.monotonic() < t_end and time.monotonic() - last[0] < quiet_s:
            if sub is None:
                names = dict(node.get_topic_names_and_types()).get(topic)
                if names:
                    sub = node.create_subscription(
                        msg_class(names[0]), topic,
                        lambda _raw: last.__setitem__(0, time.monotonic()),
                        qos_profile_sensor_data, raw=True)
            rclpy.spin_once(node, timeout_sec=0.05)
    finally:
        node.destroy_node()
        rclpy.shutdown()


def run_pipeline(bag: Path, out: Path, params: Path, rate: float) -> Path:
    """Replay ``bag`` through both nodes, record the outputs; return the recorded bag path."""
    logs = out / "logs"
    logs.mkdir(parents=True, exist_ok=True)
    recorded = out / "recorded"
    if recorded.exists():
        import shutil

        shutil.rmtree(recorded)
    ros_args = ["--ros-args", "--params-file", str(params)] if params.exists() else []
    procs: list[subprocess.Popen] = []
    try:
        procs.append(
            _start([str(find("sysid_node", "sysid_node")), *ros_args], logs / "sysid_node.log")
        )
        procs.append(
            _start(
                [str(find("notch_filter_node", "notch_filter_node")), *ros_args],
                logs / "notch_filter_node.log",
            )
        )
        procs.append(
            _start(
                [str(find("sysid_node", "record")), "--output", str(recorded), *RECORDED],
                logs / "record.log",
            )
        )
        time.sleep(2.0)  # discovery on loopback
        for p, name in zip(procs, ("sysid_node", "notch_filter_node", "record"), strict=True):
            if p.poll() is not None:
                raise DemoError(f"{name} exited at start (see {logs / (name + '.log')})")
        print(
            f"[demo] replaying {bag.relative_to(REPO) if bag.is_relative_to(REPO) else bag} "
            f"at {rate:g}x through sysid_node and notch_filter_node ...",
            flush=True,
        )
        replay = subprocess.run(
            [
                str(find("sysid_node", "replay")),
                "--bag",
                str(bag),
                "--rate",
                str(rate),
                "--topics",
                "/vibration",
                "/excitation",
            ],
            capture_output=True,
            text=True,
            timeout=600,
        )
        (logs / "replay.log").write_text(replay.stdout + replay.stderr)
        if replay.returncode != 0:
            raise DemoError(f"replay failed: {(replay.stderr.strip().splitlines() or ['?'])[-1]}")
        _wait_until_quiet("/vibration_filtered")  # the last filtered samples and estimates
    finally:
        for p in reversed(procs):
            stop_group(p)
    if not recorded.exists():
        raise DemoError(f"nothing was recorded (see {logs / 'record.log'})")
    return recorded


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="ros2_ws/demo", description=__doc__.splitlines()[0])
    ap.add_argument("--bag", type=Path, default=DEFAULT_BAG, help="scenario bag to replay")
    ap.add_argument("--out", type=Path, default=REPO / "out" / "demo", help="output directory")
    ap.add_argument("--params-file", type=Path, default=DEFAULT_PARAMS, help="YAML for both nodes")
    ap.add_argument("--rate", type=float, default=1.0,
                    help="replay speed factor (default 1: the recorded pace, as in flight)")
    ap.add_argument("--report-only", action="store_true", help="re-analyse the last recording")
    ap.add_argument("--hogs", type=int, default=0,
                    help="busy-loop processes to run meanwhile (a loaded flight computer)")
    args = ap.parse_args(argv)
    os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    os.environ.setdefault("ROS_DOMAIN_ID", str(10 + os.getpid() % 90))
    try:
        from demo_report import analyse, write_report

        if not args.bag.exists():
            raise DemoError(f"bag not found: {args.bag}")
        args.out.mkdir(parents=True, exist_ok=True)
        t0 = time.monotonic()
        recorded = args.out / "recorded"
        if not args.report_only:
            hogs = [subprocess.Popen([sys.executable, "-c", "while True: pass"])
                    for _ in range(max(args.hogs, 0))]
            try:
                recorded = run_pipeline(args.bag, args.out, args.params_file, args.rate)
            finally:
                for p in hogs:  # ours, by pid
                    p.kill()
                    p.wait(timeout=10)
        result = analyse(args.bag, recorded, args.params_file)
        print(result.table())
        print(result.peak_table())
        report = write_report(result, args.out / "report.html")
        (args.out / "summary.json").write_text(json.dumps(result.summary(), indent=2))
        print(f"[demo] report: {report}  ({time.monotonic() - t0:.0f} s)")
    except DemoError as err:
        print(f"demo: error: {err}", file=sys.stderr)
        return 1
    except Exception as err:  # a user-facing tool ends with one line, never a traceback
        print(f"demo: error: {type(err).__name__}: {err}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
