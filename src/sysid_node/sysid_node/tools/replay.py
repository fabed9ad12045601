"""replay: publish a rosbag2's messages over DDS at the recorded pace (stand-in for ros2 bag play).

    ros2 run sysid_node replay BAG [--rate 2] [--topics /vibration /excitation] [--clock] [--loop]
        [--remap /vibration:=/left_wing/vibration ...] [--ros-args ...]

The raw CDR bytes of each message are published as they are (byte-exact, no re-encoding) with
the rclpy class of the recorded type. Pacing follows the bag's log timestamps scaled by
``--rate``. Before the first message the tool waits (bounded by ``--wait-subscribers``) until
every replayed topic has a subscriber, and at the end until reliable subscribers acknowledged
everything, so that a replay into a running node loses nothing at either end.

A bag holds fully qualified topic names, so a namespace does not move them (as with
``ros2 bag play``): ``--remap FROM:=TO`` publishes a recorded topic under another name, e.g. into
one wing's namespace.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from sysid_node.bag_io import BagError, iter_messages, list_topics, open_bag
from sysid_node.tools import msg_class, run_tool, start_node, stop_node
from sysid_node.topics import topic_name_error

PROG = "replay"
#: Upper bound of the default publisher depth [messages]: a whole bag's worth, for a bag that fits
MAX_DEPTH = 200_000


def _parse(argv: list[str] | None) -> argparse.Namespace:
    ap = argparse.ArgumentParser(prog=PROG, description=__doc__.splitlines()[0])
    ap.add_argument("bag_pos", nargs="?", type=Path, metavar="BAG", help="rosbag2 directory")
    ap.add_argument("--bag", type=Path, help="rosbag2 directory (same as the positional BAG)")
    ap.add_argument("--rate", type=float, default=1.0, help="speed factor (default 1 = recorded)")
    ap.add_argument("--topics", nargs="+", metavar="TOPIC", help="topics to replay (default all)")
    ap.add_argument("--clock", action="store_true", help="publish /clock (for use_sim_time)")
    ap.add_argument("--loop", action="store_true", help="start again at the end until stopped")
    ap.add_argument(
        "--qos",
        choices=("reliable", "sensor"),
        default="reliable",
        help="reliable (default, deep queue, lossless) or sensor (best effort, sensor-data QoS)",
    )
    ap.add_argument(
        "--depth",
        type=int,
        default=0,
        help="publisher queue depth (reliable); 0 (default): the topic's message count in the bag, "
        f"at most {MAX_DEPTH} (a reliable writer drops what a stalled reader has not yet "
        "acknowledged beyond its depth)",
    )
    ap.add_argument(
        "--wait-subscribers",
        type=float,
        default=10.0,
        metavar="S",
        help="wait up to S seconds for a subscriber on every topic before starting (default 10)",
    )
    ap.add_argument(
        "--remap",
        nargs="+",
        default=[],
        metavar="FROM:=TO",
        help="publish bag topic FROM as TO (as ros2 bag play --remap)",
    )
    ap.add_argument("--quiet", action="store_true", help="no progress lines")
    args = ap.parse_args(argv)
    args.remaps = {}
    for item in args.remap:
        src, sep, dst = item.partition(":=")
        reason = topic_name_error(dst) if sep and src else "expected FROM:=TO"
        if reason:
            ap.error(f"--remap {item}: {reason}")
        args.remaps[src] = dst
    if args.bag is None:
        args.bag = args.bag_pos
    if args.bag is None:
        ap.error("a bag is required (BAG or --bag BAG)")
    if not args.rate > 0 or args.rate == float("inf"):
        ap.error("--rate must be a positive finite number")
    if args.depth < 0:
        ap.error("--depth must be 0 (the bag's message count) or positive")
    return args


def _transient_local(bag: Path) -> set[str]:
    """Topics recorded with a transient-local offered QoS (re-offered the same way)."""
    from rosbags.interfaces import QosDurability

    with open_bag(bag) as reader:
        out = set()
        for c in reader.connections:
            profiles = getattr(c.ext, "offered_qos_profiles", None) or []
            if profiles and all(q.durability == QosDurability.TRANSIENT_LOCAL for q in profiles):
                out.add(c.topic)
        return out


def _bag_depth(count: int) -> int:
    """Default reliable depth: every message of the topic, so that a subscriber process stalled
    (descheduled, swapped) for seconds loses nothing: a KEEP_LAST writer overwrites samples not
    yet acknowledged, and acknowledgements stop while the reader's process does not run."""
    return max(1, min(int(count), MAX_DEPTH))


def run(args: argparse.Namespace) -> int:
    available = list_topics(args.bag)
    topics = list(args.topics) if args.topics else sorted(available)
    missing = [t for t in topics if t not in available]
    if missing:
        raise BagError(
            f"no topic {', '.join(missing)} in bag {args.bag}; "
            f"available: {', '.join(sorted(available)) or '-'}"
        )
    classes = {t: msg_class(available[t][0]) for t in topics}
    latched = _transient_local(args.bag)

    from rclpy.duration import Duration
    from rclpy.qos import (
        DurabilityPolicy,
        HistoryPolicy,
        QoSProfile,
        ReliabilityPolicy,
        qos_profile_sensor_data,
    )

    node, stop = start_node("replay", args.ros_args)
    try:
        pubs = {}
        for t in topics:
            if args.qos == "sensor" and t not in latched:
                qos = qos_profile_sensor_data
            else:
                qos = QoSProfile(
                    history=HistoryPolicy.KEEP_LAST,
                    depth=1 if t in latched else args.depth or _bag_depth(available[t][1]),
                    reliability=ReliabilityPolicy.RELIABLE,
                    durability=DurabilityPolicy.TRANSIENT_LOCAL
                    if t in latched
                    else DurabilityPolicy.VOLATILE,
                )
            pubs[t] = node.create_publisher(classes[t], args.remaps.get(t, t), qos)
        clock_pub = None
        if args.clock:
            from rosgraph_msgs.msg import Clock

            clock_pub = node.create_publisher(Clock, "/clock", 10)
            clock_msg = Clock()

        deadline = time.monotonic() + max(0.0, args.wait_subscribers)
        while not stop["flag"] and time.monotonic() < deadline:
            if all(p.get_subscription_count() > 0 for p in pubs.values()):
                break
            time.sleep(0.05)
        lonely = [p.topic_name for p in pubs.values() if p.get_subscription_count() == 0]
        if lonely and not args.quiet:
            print(f"[{PROG}] no subscriber on {', '.join(lonely)}; replaying anyway", flush=True)
        if not lonely:
            time.sleep(0.3)  # let the subscribers' side of the match settle too

        sent = dict.fromkeys(topics, 0)
        t_start = time.monotonic()
        while not stop["flag"]:
            wall0 = None
            bag0 = 0
            for conn, stamp, raw in iter_messages(args.bag, topics):
                if stop["flag"]:
                    break
                if wall0 is None:
                    wall0, bag0 = time.monotonic(), stamp
                delay = wall0 + (stamp - bag0) * 1e-9 / args.rate - time.monotonic()
                if delay > 0:
                    time.sleep(delay)
                if clock_pub is not None:
                    clock_msg.clock.sec, clock_msg.clock.nanosec = divmod(stamp, 1_000_000_000)
                    clock_pub.publish(clock_msg)
                pubs[conn.topic].publish(raw)
                sent[conn.topic] += 1
            if not args.loop:
                break
        if args.qos == "reliable" or latched:
            for t, p in pubs.items():
                if args.qos == "reliable" or t in latched:
                    p.wait_for_all_acked(Duration(seconds=5))
        took = time.monotonic() - t_start
        if not args.quiet:
            counts = ", ".join(f"{pubs[t].topic_name} {n}" for t, n in sent.items())
            print(f"[{PROG}] published {sum(sent.values())} messages in {took:.2f} s ({counts})")
    finally:
        stop_node(node)
    return 0


def main(argv: list[str] | None = None) -> int:
    return run_tool(PROG, _parse, run, argv)


if __name__ == "__main__":
    sys.exit(main())
