"""record: write DDS topics into a rosbag2 until stopped (stand-in for ros2 bag record).

    ros2 run sysid_node record /modal_estimate /vibration -o out/bag [--duration 30]
    ros2 run sysid_node record modal_estimate vibration -o out/left --ros-args -r __ns:=/left_wing

Subscribes with ``raw=True`` and writes the serialized bytes it receives, so the bag is
byte-exact. Types come from the ROS graph (``--type TOPIC=pkg/msg/Name`` overrides, and lets a
topic be recorded before any publisher exists). The subscription QoS adapts to the publishers:
transient-local publishers (e.g. ``/modal_estimate``) get a reliable transient-local
subscription, best-effort ones a best-effort subscription, others (and a ``--type`` topic with
no publisher yet) reliable volatile. The offered QoS is stored in the bag. DDS pads serialized
messages to a multiple of 4 bytes, so a recorded message may end in up to 3 more zero bytes
than the one in a bag written by rosbags. Stops on SIGINT/SIGTERM or after ``--duration`` and
closes the bag cleanly. Relative topic names are resolved in the recorder's namespace
(``--ros-args -r __ns:=/left_wing``: ``vibration`` is ``/left_wing/vibration``); the bag holds
the fully qualified names.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from sysid_node.bag_io import STORAGES, BagError, BagWriter, make_qos
from sysid_node.tools import ToolError, msg_class, run_tool, start_node, stop_node

PROG = "record"


def _parse(argv: list[str] | None) -> argparse.Namespace:
    ap = argparse.ArgumentParser(prog=PROG, description=__doc__.splitlines()[0])
    ap.add_argument("topics", nargs="+", metavar="TOPIC", help="topics to record")
    ap.add_argument("-o", "--output", type=Path, required=True, help="new rosbag2 directory")
    ap.add_argument("--storage", choices=STORAGES, default="mcap", help="default mcap")
    ap.add_argument("--duration", type=float, default=None, metavar="S", help="stop after S s")
    ap.add_argument(
        "--type",
        action="append",
        default=[],
        metavar="TOPIC=TYPE",
        help="message type of a topic (pkg/msg/Name), instead of discovering it",
    )
    ap.add_argument("--depth", type=int, default=1000, help="subscription queue depth")
    ap.add_argument("--quiet", action="store_true", help="no progress lines")
    args = ap.parse_args(argv)
    if args.duration is not None and not args.duration > 0:
        ap.error("--duration must be positive")
    types: dict[str, str] = {}
    for item in args.type:
        topic, sep, name = item.partition("=")
        if not sep or not topic or not name:
            ap.error(f"--type expects TOPIC=pkg/msg/Name, got {item!r}")
        types[topic] = name if name.count("/") == 2 else name.replace("/", "/msg/", 1)
    args.types = types
    return args


def run(args: argparse.Namespace) -> int:
    for t in args.types:
        msg_class(args.types[t])  # fail early on an unknown type
    if args.output.exists():
        raise BagError(f"output already exists: {args.output}")
    for parent in args.output.parents:
        if parent.exists() and not parent.is_dir():
            raise ToolError(f"cannot create {args.output}: {parent} is a file, not a directory")
    try:
        args.output.parent.mkdir(parents=True, exist_ok=True)
    except OSError as err:
        raise ToolError(f"cannot create the directory {args.output.parent}: "
                        f"{err.strerror}") from None

    import rclpy
    from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

    node, stop = start_node("record", args.ros_args)
    # fully qualified names (namespace and remapping applied): what the graph and the bag use
    args.topics = list(dict.fromkeys(node.resolve_topic_name(t) for t in args.topics))
    args.types = {node.resolve_topic_name(t): v for t, v in args.types.items()}
    bag = BagWriter(args.output, storage=args.storage).open()
    subs = {}

    def subscribe(topic: str, msgtype: str, best_effort: bool, latched: bool) -> None:
        cls = msg_class(msgtype)
        bag.add_topic(
            topic,
            msgtype,
            qos=[make_qos(reliable=not best_effort, transient_local=latched, depth=args.depth)],
        )
        qos = QoSProfile(
            history=HistoryPolicy.KEEP_LAST,
            depth=args.depth,
            reliability=ReliabilityPolicy.BEST_EFFORT
            if best_effort
            else ReliabilityPolicy.RELIABLE,
            durability=DurabilityPolicy.TRANSIENT_LOCAL if latched else DurabilityPolicy.VOLATILE,
        )

        def on_msg(raw: bytes, topic: str = topic) -> None:
            bag.write_raw(topic, time.time_ns(), raw)

        subs[topic] = node.create_subscription(cls, topic, on_msg, qos, raw=True)
        if not args.quiet:
            mode = "best effort" if best_effort else "reliable"
            mode += ", transient local" if latched else ""
            print(f"[{PROG}] recording {topic} ({msgtype}, {mode})", flush=True)

    def discover() -> None:
        graph = dict(node.get_topic_names_and_types())
        for topic in args.topics:
            if topic in subs:
                continue
            infos = node.get_publishers_info_by_topic(topic)
            msgtype = args.types.get(topic)
            if msgtype is None:
                names = graph.get(topic)
                if not names or not infos:
                    continue  # not published yet
                if len(names) > 1:
                    raise ToolError(f"topic {topic} has several types ({', '.join(names)})")
                msgtype = names[0]
            best_effort = any(
                i.qos_profile.reliability == ReliabilityPolicy.BEST_EFFORT for i in infos
            )
            latched = bool(infos) and all(
                i.qos_profile.durability == DurabilityPolicy.TRANSIENT_LOCAL for i in infos
            )
            subscribe(topic, msgtype, best_effort, latched)

    try:
        t_end = None if args.duration is None else time.monotonic() + args.duration
        next_discovery = 0.0
        while not stop["flag"] and (t_end is None or time.monotonic() < t_end):
            if len(subs) < len(args.topics) and time.monotonic() >= next_discovery:
                discover()
                next_discovery = time.monotonic() + 0.2
            rclpy.spin_once(node, timeout_sec=0.05)
        # drain what already arrived
        for _ in range(50):
            rclpy.spin_once(node, timeout_sec=0.0)
    finally:
        bag.close()
        stop_node(node)
    never = [t for t in args.topics if t not in subs]
    if not args.quiet:
        counts = ", ".join(f"{t} {bag.counts.get(t, 0)}" for t in args.topics)
        print(f"[{PROG}] wrote {args.output}: {counts}", flush=True)
        if never:
            print(f"[{PROG}] never saw a publisher on {', '.join(never)}", flush=True)
    return 0


def main(argv: list[str] | None = None) -> int:
    return run_tool(PROG, _parse, run, argv)


if __name__ == "__main__":
    sys.exit(main())
