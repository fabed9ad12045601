"""Latency and throughput of sysid_node over real DDS (loopback), quiet and under CPU load.

For each scenario (issue #12's targets: 200 Hz SISO SignalSample, 1 kHz 1-in/6-out
SignalSample, 1 kHz 1-in/6-out SignalBlock of 10 samples), starts a fresh node, streams
``--seconds`` of data at real time with wall-clock stamps, and measures:

- latency from the stamp of the last sample an estimate used to the estimate's arrival here
  (the DDS reception time of ``/modal_estimate``, so this process's own load does not count),
  p50 and p99 over the estimates after the first ``--warmup`` seconds of data;
- messages lost: sent minus received by the node (its ``/diagnostics`` counters), plus the
  messages the node dropped itself to stay current (``*_shed``; none expected);
- CPU share of the node's process group (user + system time / wall time; 100 % = one core);
- the publisher's own lag (publication time minus the stamp), to tell a late sender from a
  slow node.

"stressed" runs the same with ``--hogs`` CPU-bound processes (busy Python loops, one per core
by default) started before the node: the machine of issue #12 with other work on it. The same
can be had with Debian's ``stress-ng --cpu 2`` in another shell and ``--loads quiet``.

    ros2_ws/env python benchmarks/bench_node.py [--seconds 20] [--loads quiet stressed]
        [--scenarios siso200 io6_1k block6_1k] [--set NAME:=VALUE ...]

``BENCH_RUN=/other/checkout/ros2_ws/run`` measures another checkout's node (A/B comparison).

Figures taken on a machine shared with other work are contaminated by it: say so with them.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from sysid_node.process_group import stop_group

REPO = Path(__file__).resolve().parents[1]
RUN = REPO / "ros2_ws" / "run"
CLK_TCK = os.sysconf("SC_CLK_TCK")


@dataclass(frozen=True)
class Scenario:
    name: str
    kind: str  # SignalSample or SignalBlock
    fs: float
    n_out: int
    n_in: int
    per_msg: int  # samples per message
    params: tuple[str, ...] = field(default_factory=tuple)

    def label(self) -> str:
        return f"{self.kind} {self.fs:g} Hz {self.n_in}in/{self.n_out}out x{self.per_msg}"


SCENARIOS = {
    s.name: s for s in (
        Scenario("siso200", "SignalSample", 200.0, 1, 1, 1),
        Scenario("io6_1k", "SignalSample", 1000.0, 6, 1, 1, ("freq_max:=40.0",)),
        Scenario("block6_1k", "SignalBlock", 1000.0, 6, 1, 10, ("freq_max:=40.0",)),
    )
}


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
        self.pub_y = self.node.create_publisher(cls, "vibration", 1000)
        self.pub_u = self.node.create_publisher(cls, "excitation", 1000)
        self.arrivals: list[tuple[int, int]] = []  # (stamp, DDS reception time) [ns]
        self.last_stamp = 0
        self.diag: dict[str, str] = {}
        self.node.create_subscription(ModalEstimate, "modal_estimate", self._on_est,
                                      ESTIMATE_QOS)
        self.node.create_subscription(DiagnosticArray, "diagnostics", self._on_diag, 10)
        self.start()

    def _on_est(self, msg, info) -> None:
        received = int(info.get("received_timestamp") or 0) or time.time_ns()
        st = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
        self.last_stamp = st
        self.arrivals.append((st, received))

    def _on_diag(self, msg) -> None:
        self.diag = {v.key: v.value for v in msg.status[0].values}

    def wait_subscribed(self, n_topics: int, timeout: float = 60.0) -> bool:
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            pubs = (self.pub_y, self.pub_u)[:n_topics]
            if all(p.get_subscription_count() for p in pubs):
                return True
            time.sleep(0.05)
        return False


def start_hogs(n: int) -> list[subprocess.Popen]:
    """``n`` CPU-bound processes (busy loops), each in its own session."""
    return [subprocess.Popen([sys.executable, "-c", "while True: pass"],
                             start_new_session=True) for _ in range(n)]


def stop_hogs(hogs: list[subprocess.Popen]) -> None:
    for h in hogs:
        h.kill()
        h.wait()


def _count(diag: dict[str, str], *keys: str) -> int:
    return sum(int(float(diag.get(k, "0"))) for k in keys)


def _profile(pid: int, seconds: float, out: Path) -> subprocess.Popen | None:
    """py-spy (``pip install py-spy``) sampling the node and its worker into ``out`` (collapsed
    stacks, one line per stack with its sample count; idle stacks included)."""
    import shutil

    exe = shutil.which("py-spy") or os.environ.get("PY_SPY")
    if not exe:
        print("--profile: py-spy not found (pip install py-spy, or PY_SPY=/path/to/py-spy)")
        return None
    return subprocess.Popen([exe, "record", "-p", str(pid), "-d", str(int(seconds)), "-r", "200",
                             "--subprocesses", "--threads", "--nonblocking",
                             "-f", "raw", "-o", str(out)],
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)


def run_one(sc: Scenario, seconds: float, warmup: float, extra: list[str],
            profile: Path | None = None) -> dict:
    from sysid_node import msg_convert as mc

    env = dict(os.environ, ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
    args = [os.environ.get("BENCH_RUN", str(RUN)), "sysid_node", "sysid_node", "--ros-args",
            "-p", f"output_type:={sc.kind}", "-p", f"input_type:={sc.kind}",
            "-p", f"sample_rate:={sc.fs}",
            "-p", f"qos_depth:={max(1000, int(2 * sc.fs))}"]
    for item in (*sc.params, *extra):
        args += ["-p", item]
    node = subprocess.Popen(args, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                            env=env, start_new_session=True)
    client = Client(sc.kind)
    try:
        if not client.wait_subscribed(2 if sc.n_in else 1):
            return {"error": "node did not subscribe"}
        time.sleep(1.0)
        rng = np.random.default_rng(0)
        n = int(seconds * sc.fs)
        tt = np.arange(n) / sc.fs
        u = rng.standard_normal((n, max(sc.n_in, 1)))
        y = (np.sin(2 * np.pi * np.outer(tt, [2.0, 4.0, 6.0])) @ rng.standard_normal((3, sc.n_out))
             + 0.1 * rng.standard_normal((n, sc.n_out)))
        sent = 0
        pub_lag: list[float] = []
        spy = _profile(node.pid, seconds, profile) if profile else None
        cpu0 = _group_cpu_s(node.pid)
        w0 = time.monotonic()
        start_ns = time.time_ns()
        k = 0
        b = sc.per_msg
        while k < n:
            # send everything due by now (bursts keep pace at rates above the sleep resolution)
            due = min(n, int((time.monotonic() - w0) * sc.fs) + 1)
            while k + b <= due or (k < n and due == n):
                st = start_ns + int(k * 1e9 / sc.fs)
                last = k + b - 1
                if sc.kind == "SignalSample":
                    client.pub_y.publish(mc.signal_sample_msg(st, y[k]))
                    if sc.n_in:
                        client.pub_u.publish(mc.signal_sample_msg(st, u[k]))
                else:
                    client.pub_y.publish(mc.signal_block_msg(st, 1 / sc.fs, y[k : k + b]))
                    if sc.n_in:
                        client.pub_u.publish(mc.signal_block_msg(st, 1 / sc.fs, u[k : k + b]))
                pub_lag.append((time.time_ns() - start_ns) * 1e-9 - last / sc.fs)
                sent += 1 + (sc.n_in > 0)
                k += b
            time.sleep(0.002)
        end_stamp = start_ns + int((n - 1) * 1e9 / sc.fs)
        deadline = time.monotonic() + 10.0
        while time.monotonic() < deadline and client.last_stamp < end_stamp - 0.2e9:
            time.sleep(0.02)
        wall = time.monotonic() - w0
        cpu = (_group_cpu_s(node.pid) - cpu0) / wall
        time.sleep(1.5)  # one more diagnostics message after the end
        if spy is not None:
            spy.wait(timeout=30)
        d = client.diag
        if os.environ.get("BENCH_VERBOSE"):
            print(d)
        received = _count(d, "output_messages", "input_messages")
        shed = _count(d, "output_shed", "input_shed", "overload_dropped_messages")
        arr = np.array(client.arrivals, dtype=np.int64).reshape(-1, 2)
        keep = arr[:, 0] >= start_ns + int(warmup * 1e9)
        lat = (arr[keep, 1] - arr[keep, 0]) * 1e-9
        pct = (lambda q: float(np.percentile(lat, q))) if lat.size else (lambda q: float("nan"))
        return {
            "sent": sent, "received": received, "lost": sent - received + shed,
            "estimates": int(lat.size), "cpu": cpu, "p50": pct(50), "p99": pct(99),
            "max": float(lat.max()) if lat.size else float("nan"),
            "pub_lag_p99": float(np.percentile(pub_lag, 99)) if pub_lag else float("nan"),
            "kept_pace": client.last_stamp >= end_stamp - 0.2e9,
            "stages": "  ".join(
                f"{st} {float(d[f'latency_{st}_p50_ms']):.0f}/"
                f"{float(d[f'latency_{st}_p99_ms']):.0f}"
                for st in ("arrival", "waiting", "to_worker", "worker_estimating",
                           "from_worker", "estimate")
                if f"latency_{st}_p50_ms" in d),
        }
    finally:
        client.close()
        stop_group(node)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=20.0, help="data streamed per run [s]")
    ap.add_argument("--warmup", type=float, default=3.0,
                    help="estimates of the first S seconds of data are not counted [s]")
    ap.add_argument("--scenarios", nargs="+", default=list(SCENARIOS), choices=list(SCENARIOS))
    ap.add_argument("--loads", nargs="+", default=["quiet", "stressed"],
                    choices=["quiet", "stressed"])
    ap.add_argument("--hogs", type=int, default=os.cpu_count() or 2,
                    help="CPU-bound processes of the stressed runs (default: one per core)")
    ap.add_argument("--set", nargs="*", default=[], metavar="NAME:=VALUE",
                    help="more node parameters for every run, e.g. reorder_window:=0.01")
    ap.add_argument("--profile", type=Path, metavar="DIR",
                    help="record py-spy stacks of the node during each run into DIR")
    args = ap.parse_args()
    if args.profile:
        args.profile.mkdir(parents=True, exist_ok=True)
    os.environ.setdefault("ROS_DOMAIN_ID", str(10 + os.getpid() % 80))
    print(f"sysid_node latency (last sample's stamp -> estimate received), {args.seconds:g} s "
          f"per run, first {args.warmup:g} s not counted, {os.cpu_count()} CPUs, load average "
          f"{os.getloadavg()[0]:.1f} at start, ROS_DOMAIN_ID={os.environ['ROS_DOMAIN_ID']}, "
          f"extra parameters: {' '.join(args.set) or 'none'}")
    head = (f"{'scenario':<48}{'load':>9}{'sent':>7}{'lost':>6}{'est':>5}{'CPU %':>7}"
            f"{'p50 ms':>8}{'p99 ms':>8}{'max ms':>8}{'pub lag p99 ms':>16}")
    print(head)
    print("-" * len(head))
    for load in args.loads:
        hogs = start_hogs(args.hogs) if load == "stressed" else []
        try:
            for name in args.scenarios:
                sc = SCENARIOS[name]
                prof = args.profile / f"{name}_{load}.txt" if args.profile else None
                r = run_one(sc, args.seconds, args.warmup, args.set, prof)
                label = sc.label() + (f" {' '.join(sc.params)}" if sc.params else "")
                if "error" in r:
                    print(f"{label:<48}{load:>9}  {r['error']}", flush=True)
                    continue
                print(f"{label:<48}{load:>9}{r['sent']:>7}{r['lost']:>6}{r['estimates']:>5}"
                      f"{100 * r['cpu']:>7.0f}{1e3 * r['p50']:>8.1f}{1e3 * r['p99']:>8.1f}"
                      f"{1e3 * r['max']:>8.1f}{1e3 * r['pub_lag_p99']:>16.1f}"
                      + ("" if r["kept_pace"] else "  (did not keep pace)"), flush=True)
                if r["stages"]:
                    print(f"{'':<8}node's stages, p50/p99 ms: {r['stages']}", flush=True)
        finally:
            stop_hogs(hogs)
    print(f"load average at the end {os.getloadavg()[0]:.1f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
