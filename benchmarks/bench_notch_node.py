"""Throughput and filtered-output latency of notch_filter_node over real DDS (loopback).

For SignalSample (one message per sample) and SignalBlock (one message per 10 ms of samples)
with 6 channels and five tracked modes (five notches), steps the sample rate up and, for each
rate, starts a fresh node, streams ``--seconds`` of data at real time and measures:

- filtered messages received here against messages sent (none may be lost);
- latency from publishing a message to receiving its filtered copy (matched by header stamp):
  what the notch bank adds to the flight-control path, DDS included;
- CPU share of the node's process group (100 % = one core).

Estimates (``sysid_msgs/ModalEstimate``, five tracked modes) are published every 0.2 s with the
stamp of the latest sample, as sysid_node does. Run:

    ros2_ws/env python benchmarks/bench_notch_node.py [--seconds 5] [--rates 200 1000 4000]
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import threading
import time

import numpy as np
from bench_node import RUN, DdsClient, _group_cpu_s, _stop

CHANNELS = 6
MODES_HZ = (3.0, 6.0, 9.0, 12.0, 15.0)


class Client(DdsClient):
    def __init__(self, kind: str) -> None:
        from sysid_node.node import ESTIMATE_QOS

        from sysid_msgs.msg import ModalEstimate, SignalBlock, SignalSample

        super().__init__("bench_notch_client")
        cls = SignalSample if kind == "SignalSample" else SignalBlock
        self.pub = self.node.create_publisher(cls, "/vibration", 1000)
        self.pub_est = self.node.create_publisher(ModalEstimate, "/modal_estimate", ESTIMATE_QOS)
        self.sent_at: dict[int, int] = {}
        self.latency: list[float] = []
        self.received = 0
        self.lock = threading.Lock()
        self.node.create_subscription(cls, "/vibration_filtered", self._on_out, 1000)
        self.start()

    def _on_out(self, msg) -> None:
        now = time.perf_counter_ns()
        st = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
        with self.lock:
            sent = self.sent_at.pop(st, None)
            self.received += 1
        if sent is not None:
            self.latency.append((now - sent) * 1e-9)

    def publish(self, msg, stamp_ns: int) -> None:
        with self.lock:
            self.sent_at[stamp_ns] = time.perf_counter_ns()
        self.pub.publish(msg)

    def wait_subscribed(self, timeout: float = 20.0) -> bool:
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            if self.pub.get_subscription_count() and self.pub_est.get_subscription_count():
                return True
            time.sleep(0.05)
        return False


def estimate(stamp_ns: int):
    from sysid_node.records import EstimateRecord, ModeRecord

    from sysid_node import msg_convert as mc

    modes = [ModeRecord(k + 1, "tracked", f, 0.01, 0.02, 0.003, 1.0, 10.0,
                        np.ones(CHANNELS, complex)) for k, f in enumerate(MODES_HZ)]
    return mc.estimate_msg(EstimateRecord(
        stamp_ns=stamp_ns, modes=modes, model_order=10, block_rows=20, forgetting_factor=0.99,
        sample_rate=0.0, prediction_error_rms_per_channel=np.zeros(CHANNELS), converged=True,
        samples_used=1000, counters={}))


def run_level(kind: str, fs: float, seconds: float) -> dict:
    from sysid_node import msg_convert as mc

    env = dict(os.environ, ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
    args = [str(RUN), "notch_filter_node", "notch_filter_node", "--ros-args",
            "-p", f"signal_type:={kind}", "-p", f"sample_rate:={fs}",
            "-p", f"qos_depth:={max(200, int(fs))}", "-p", "fallback_depth:=0.0"]
    node = subprocess.Popen(args, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                            env=env, start_new_session=True)
    client = Client(kind)
    try:
        if not client.wait_subscribed():
            return {"error": "node did not subscribe"}
        rng = np.random.default_rng(0)
        n = int(seconds * fs)
        warm = int(2.0 * fs)  # notches faded in before the timed part
        y = rng.standard_normal((warm + n, CHANNELS))
        per_msg = 1 if kind == "SignalSample" else max(1, int(round(fs * 0.01)))
        start_ns = time.time_ns()
        client.pub_est.publish(estimate(start_ns))
        time.sleep(0.3)
        sent = 0
        cpu0 = wall0 = None
        w0 = time.monotonic()
        k, next_est = 0, 0.2
        total = warm + n
        while k < total:
            due = min(total, int((time.monotonic() - w0) * fs) + per_msg)
            while k < due:
                b = min(per_msg, total - k)
                st = start_ns + int(k * 1e9 / fs)
                if k >= warm and cpu0 is None:
                    cpu0, wall0 = _group_cpu_s(node.pid), time.monotonic()
                    with client.lock:
                        client.latency.clear()
                        client.received = 0
                        client.sent_at.clear()
                if kind == "SignalSample":
                    msg = mc.signal_sample_msg(st, y[k])
                else:
                    msg = mc.signal_block_msg(st, 1 / fs, y[k : k + b])
                client.publish(msg, st)
                if k >= warm:
                    sent += 1
                k += b
                if k / fs >= next_est:
                    client.pub_est.publish(estimate(st))
                    next_est += 0.2
            time.sleep(0.001)
        send_wall = time.monotonic() - wall0
        deadline = time.monotonic() + 3.0
        while time.monotonic() < deadline and client.received < sent:
            time.sleep(0.02)
        cpu = (_group_cpu_s(node.pid) - cpu0) / (time.monotonic() - wall0)
        lat = np.array(client.latency)
        return {
            "sent": sent, "received": client.received, "send_rate": n / send_wall, "cpu": cpu,
            "lat_med": float(np.median(lat)) if lat.size else float("nan"),
            "lat_p95": float(np.percentile(lat, 95)) if lat.size else float("nan"),
            "lat_max": float(lat.max()) if lat.size else float("nan"),
        }
    finally:
        client.close()
        _stop(node)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=5.0, help="data streamed per level [s]")
    ap.add_argument("--rates", type=float, nargs="+", default=[200, 1000, 2000, 4000],
                    help="sample rates to try [Hz]")
    ap.add_argument("--kinds", nargs="+", default=["SignalSample", "SignalBlock"])
    args = ap.parse_args()
    os.environ.setdefault("ROS_DOMAIN_ID", str(10 + os.getpid() % 80))
    print(f"notch_filter_node throughput and latency, {CHANNELS} channels x {len(MODES_HZ)} "
          f"notches, {args.seconds:g} s per level, {os.cpu_count()} CPUs, "
          f"ROS_DOMAIN_ID={os.environ['ROS_DOMAIN_ID']}")
    head = (f"{'type':<13}{'rate Hz':>8}{'sent':>7}{'recv':>7}{'send Hz':>9}{'CPU %':>7}"
            f"{'lat med ms':>11}{'lat p95 ms':>11}{'lat max ms':>11}  sustained")
    print(head)
    print("-" * len(head))
    best: dict[str, float] = {}
    for kind in args.kinds:
        for fs in args.rates:
            r = run_level(kind, fs, args.seconds)
            if "error" in r:
                print(f"{kind:<13}{fs:>8g}  {r['error']}")
                continue
            ok = r["received"] == r["sent"] and r["send_rate"] >= 0.97 * fs
            if ok:
                best[kind] = max(best.get(kind, 0.0), fs)
            print(f"{kind:<13}{fs:>8g}{r['sent']:>7}{r['received']:>7}{r['send_rate']:>9.0f}"
                  f"{100 * r['cpu']:>7.0f}{1e3 * r['lat_med']:>11.2f}{1e3 * r['lat_p95']:>11.2f}"
                  f"{1e3 * r['lat_max']:>11.2f}  {'yes' if ok else 'no'}", flush=True)
    for kind in args.kinds:
        print(f"highest sustained {kind} rate: {best.get(kind, 0):g} Hz (of those tried)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
