"""Throughput of sysid_node over real DDS (loopback): prints a table.

For SignalSample (one message per sample) and SignalBlock (one message per 10 ms of samples)
with 1 input and 6 output channels, steps the sample rate up and, for each rate, starts a fresh
node, streams ``--seconds`` of data at real time with wall-clock stamps and measures:

- messages the node received against messages sent (from its /diagnostics counters);
- whether it kept pace: the last estimate covers the data within ``--lag`` s of the end;
- CPU share of the node's process group (user + system time / wall time; 100 % = one core);
- latency from the stamp of the last sample used to the arrival of /modal_estimate here.

The highest rate with no message lost and the pace kept is marked "yes". Run:

    ros2_ws/env python benchmarks/bench_node.py [--seconds 5] [--rates 100 200 500 1000]
"""

from __future__ import annotations

import argparse
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
RUN = REPO / "ros2_ws" / "run"
CLK_TCK = os.sysconf("SC_CLK_TCK")


def _group_cpu_s(pgid: int) -> float:
    """User + system CPU seconds of every process in process group ``pgid``."""
    total = 0
    for d in Path("/proc").iterdir():
        if not d.name.isdigit():
            continue
        try:
            fields = (d / "stat").read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        if int(fields[2]) == pgid:  # fields after ')' start at state (3rd field of stat)
            total += int(fields[11]) + int(fields[12])
    return total / CLK_TCK


def _stop(proc: subprocess.Popen) -> None:
    if proc.poll() is None:
        try:
            os.killpg(proc.pid, signal.SIGINT)
            proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait(timeout=5)
        except ProcessLookupError:
            pass


class DdsClient:
    """A node of its own context, spun by a daemon thread (the benchmarks' side of DDS)."""

    def __init__(self, name: str) -> None:
        import rclpy

        self.rclpy = rclpy
        self.ctx = rclpy.Context()
        rclpy.init(context=self.ctx)
        self.node = rclpy.create_node(name, context=self.ctx)

    def start(self) -> None:
        from rclpy.executors import SingleThreadedExecutor

        self.ex = SingleThreadedExecutor(context=self.ctx)
        self.ex.add_node(self.node)
        self.thread = threading.Thread(target=self._spin, daemon=True)
        self.thread.start()

    def _spin(self) -> None:
        try:
            self.ex.spin()
        except Exception:
            pass

    def close(self) -> None:
        self.ex.shutdown()
        self.node.destroy_node()
        self.rclpy.try_shutdown(context=self.ctx)


class Client(DdsClient):
    def __init__(self, kind: str) -> None:
        from diagnostic_msgs.msg import DiagnosticArray
        from sysid_node.node import ESTIMATE_QOS

        from sysid_msgs.msg import ModalEstimate, SignalBlock, SignalSample

        super().__init__("bench_node_client")
        cls = SignalSample if kind == "SignalSample" else SignalBlock
        self.pub_y = self.node.create_publisher(cls, "/vibration", 1000)
        self.pub_u = self.node.create_publisher(cls, "/excitation", 1000)
        self.latency: list[float] = []
        self.last_stamp = 0
        self.diag: dict[str, str] = {}
        self.node.create_subscription(ModalEstimate, "/modal_estimate", self._on_est,
                                      ESTIMATE_QOS)
        self.node.create_subscription(DiagnosticArray, "/diagnostics", self._on_diag, 10)
        self.start()

    def _on_est(self, msg) -> None:
        now = time.time_ns()
        st = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
        self.last_stamp = st
        self.latency.append((now - st) * 1e-9)

    def _on_diag(self, msg) -> None:
        self.diag = {v.key: v.value for v in msg.status[0].values}

    def wait_subscribed(self, timeout: float = 20.0) -> bool:
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            if self.pub_y.get_subscription_count() and self.pub_u.get_subscription_count():
                return True
            time.sleep(0.05)
        return False


def run_level(kind: str, fs: float, seconds: float, lag: float, extra: list[str]) -> dict:
    from sysid_node import msg_convert as mc

    env = dict(os.environ, ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
    args = [str(RUN), "sysid_node", "sysid_node", "--ros-args", "-p", f"output_type:={kind}",
            "-p", f"input_type:={kind}", "-p", f"sample_rate:={fs}",
            "-p", f"qos_depth:={max(200, int(fs))}"]
    for item in extra:
        args += ["-p", item]
    node = subprocess.Popen(args, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                            env=env, start_new_session=True)
    client = Client(kind)
    try:
        if not client.wait_subscribed():
            return {"error": "node did not subscribe"}
        time.sleep(0.5)
        rng = np.random.default_rng(0)
        n = int(seconds * fs)
        tt = np.arange(n) / fs
        u = rng.standard_normal((n, 1))
        y = (np.sin(2 * np.pi * np.outer(tt, [2.0, 4.0, 6.0])) @ rng.standard_normal((3, 6))
             + 0.1 * rng.standard_normal((n, 6)))
        per_msg = 1 if kind == "SignalSample" else max(1, int(round(fs * 0.01)))
        sent = 0
        cpu0 = _group_cpu_s(node.pid)
        w0 = time.monotonic()
        start_ns = time.time_ns()
        k = 0
        while k < n:
            # send everything due by now (bursts keep pace at rates above the sleep resolution)
            due = min(n, int((time.monotonic() - w0) * fs) + per_msg)
            while k < due:
                b = min(per_msg, n - k)
                st = start_ns + int(k * 1e9 / fs)
                if kind == "SignalSample":
                    client.pub_y.publish(mc.signal_sample_msg(st, y[k]))
                    client.pub_u.publish(mc.signal_sample_msg(st, u[k]))
                else:
                    client.pub_y.publish(mc.signal_block_msg(st, 1 / fs, y[k : k + b]))
                    client.pub_u.publish(mc.signal_block_msg(st, 1 / fs, u[k : k + b]))
                sent += 1
                k += b
            time.sleep(0.002)
        send_wall = time.monotonic() - w0
        end_stamp = start_ns + int((n - 1) * 1e9 / fs)
        deadline = time.monotonic() + lag
        while time.monotonic() < deadline and client.last_stamp < end_stamp - 0.2e9:
            time.sleep(0.02)
        kept_pace = client.last_stamp >= end_stamp - 0.2e9
        time.sleep(1.2)  # one more diagnostics message
        wall = time.monotonic() - w0
        cpu = (_group_cpu_s(node.pid) - cpu0) / wall
        got = int(client.diag.get("output_messages", "0"))
        lat = np.array(client.latency[len(client.latency) // 4 :]) if client.latency else None
        return {
            "sent": sent,
            "received": got,
            "send_rate": n / send_wall,
            "kept_pace": kept_pace,
            "cpu": cpu,
            "lat_med": float(np.median(lat)) if lat is not None and lat.size else float("nan"),
            "lat_p95": float(np.percentile(lat, 95)) if lat is not None and lat.size else
            float("nan"),
            "cost_us": client.diag.get("update_cost_us_per_sample", "nan"),
        }
    finally:
        client.close()
        _stop(node)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=5.0, help="data streamed per level [s]")
    ap.add_argument("--rates", type=float, nargs="+", default=[100, 200, 400, 800, 1600],
                    help="sample rates to try [Hz]")
    ap.add_argument("--kinds", nargs="+", default=["SignalSample", "SignalBlock"])
    ap.add_argument("--lag", type=float, default=3.0, help="allowed catch-up after the end [s]")
    ap.add_argument("--set", nargs="*", default=[], metavar="NAME:=VALUE",
                    help="more node parameters, e.g. freq_max:=40.0 (default: none)")
    args = ap.parse_args()
    os.environ.setdefault("ROS_DOMAIN_ID", str(10 + os.getpid() % 80))
    print(f"sysid_node throughput, 1 input + 6 outputs, {args.seconds:g} s per level, "
          f"{os.cpu_count()} CPUs, ROS_DOMAIN_ID={os.environ['ROS_DOMAIN_ID']}, parameters: "
          f"{' '.join(args.set) or 'defaults'}")
    head = (f"{'type':<13}{'rate Hz':>8}{'sent':>7}{'recv':>7}{'send Hz':>9}{'pace':>6}"
            f"{'CPU %':>7}{'us/smp':>8}{'lat med s':>10}{'lat p95 s':>10}  sustained")
    print(head)
    print("-" * len(head))
    best: dict[str, float] = {}
    for kind in args.kinds:
        for fs in args.rates:
            r = run_level(kind, fs, args.seconds, args.lag, args.set)
            if "error" in r:
                print(f"{kind:<13}{fs:>8g}  {r['error']}")
                continue
            ok = r["received"] == r["sent"] and r["kept_pace"]
            if ok:
                best[kind] = max(best.get(kind, 0.0), fs)
            print(f"{kind:<13}{fs:>8g}{r['sent']:>7}{r['received']:>7}{r['send_rate']:>9.0f}"
                  f"{'yes' if r['kept_pace'] else 'no':>6}{100 * r['cpu']:>7.0f}"
                  f"{float(r['cost_us']):>8.1f}{r['lat_med']:>10.3f}{r['lat_p95']:>10.3f}"
                  f"  {'yes' if ok else 'no'}", flush=True)
    for kind in args.kinds:
        print(f"highest sustained {kind} rate: {best.get(kind, 0):g} Hz (of those tried)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
