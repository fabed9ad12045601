"""Two namespaced instances (left and right wing) over real DDS do not hear each other.

Both nodes use relative topic names, so ``-r __ns:=/left_wing`` moves every topic but the global
``/diagnostics``. A bag replayed into the left wing only (``replay --remap``) must give estimates,
a notch bank and a filtered signal on ``/left_wing/...`` and nothing on ``/right_wing/...``; the
start-up lines name the resolved topics and the diagnostics carry each node's full name.
"""

from __future__ import annotations

import os
import subprocess
import sys
import time
from pathlib import Path

import pytest
from sysid_node.process_group import stop_group

REPO = Path(__file__).resolve().parents[1]
BAG = REPO / "bags" / "paper_example"
PARAMS = REPO / "src" / "notch_filter_node" / "config" / "adaptive_notch.yaml"
WINGS = ("left_wing", "right_wing")
NODES = (("sysid_node", "sysid_node"), ("notch_filter_node", "notch_filter_node"))


def _executable(pkg: str, exe: str) -> str:
    sys.path.insert(0, str(REPO / "ros2_ws" / "tools"))
    try:
        from find_executable import find
    finally:
        sys.path.pop(0)
    return str(find(pkg, exe))


def _bag_end_s() -> float:
    """Header stamp of the bag's last vibration sample [s]."""
    from sysid_node.bag_io import read_signals

    return float(read_signals(BAG, ["/vibration"])["/vibration"].t[-1])


@pytest.fixture(scope="module")
def two_wings(tmp_path_factory):
    """Both wings running, the paper bag replayed into the left one; what each side heard."""
    import rclpy
    from diagnostic_msgs.msg import DiagnosticArray
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy

    from sysid_msgs.msg import ModalEstimate, NotchBank, ResidualSpectrum, SignalSample

    logs = tmp_path_factory.mktemp("wings")
    env = {**os.environ, "ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST"}
    env.setdefault("ROS_DOMAIN_ID", str(10 + os.getpid() % 80))
    procs: dict[str, subprocess.Popen] = {}
    ctx = rclpy.Context()
    rclpy.init(context=ctx, domain_id=int(env["ROS_DOMAIN_ID"]))
    node = rclpy.create_node("wing_listener", context=ctx)
    ex = SingleThreadedExecutor(context=ctx)
    ex.add_node(node)
    heard: dict[str, list] = {}
    latched = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                         durability=DurabilityPolicy.TRANSIENT_LOCAL)
    for wing in WINGS:
        for name, cls, qos in (("modal_estimate", ModalEstimate, latched),
                               ("notch_bank", NotchBank, 10),
                               ("vibration_filtered", SignalSample, 1000),
                               ("residual_spectrum", ResidualSpectrum, 10)):
            topic = f"/{wing}/{name}"
            heard[topic] = []
            node.create_subscription(cls, topic, heard[topic].append, qos)
    heard["/diagnostics"] = []
    node.create_subscription(DiagnosticArray, "/diagnostics", heard["/diagnostics"].append, 50)
    try:
        for wing in WINGS:
            for pkg, exe in NODES:
                log = (logs / f"{wing}_{exe}.log").open("w")
                procs[f"{wing}/{exe}"] = subprocess.Popen(
                    [_executable(pkg, exe), "--ros-args", "-r", f"__ns:=/{wing}",
                     "--params-file", str(PARAMS)],
                    stdout=log, stderr=subprocess.STDOUT, env=env, start_new_session=True,
                )
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline:  # every node subscribed to its own wing's signal
            ex.spin_once(timeout_sec=0.2)
            if all(node.count_subscribers(f"/{w}/vibration") == 2 for w in WINGS):
                break
            dead = [k for k, p in procs.items() if p.poll() is not None]
            assert not dead, f"{dead} exited at start: {(logs / 'left_wing_sysid_node.log')}"
        else:
            pytest.fail("the four nodes did not come up within 120 s")
        replay = subprocess.run(
            [_executable("sysid_node", "replay"), "--bag", str(BAG), "--rate", "4", "--quiet",
             "--remap", "/vibration:=/left_wing/vibration", "/excitation:=/left_wing/excitation"],
            capture_output=True, text=True, env=env, timeout=180,
        )
        assert replay.returncode == 0, replay.stderr
        # until the left wing's estimate reaches the bag's last second (a busy machine finishes
        # the replayed data seconds after the player; at most 30 s), then 1 s for the rest
        last_s = _bag_end_s() - 1.0
        end = time.monotonic() + 30.0
        est = heard["/left_wing/modal_estimate"]
        while time.monotonic() < end and not (
                est and est[-1].header.stamp.sec + 1e-9 * est[-1].header.stamp.nanosec >= last_s):
            ex.spin_once(timeout_sec=0.1)
        end = time.monotonic() + 1.0
        while time.monotonic() < end:
            ex.spin_once(timeout_sec=0.1)
    finally:
        codes = {k: stop_group(p, timeout=20) for k, p in procs.items()}
        ex.shutdown()
        node.destroy_node()
        rclpy.shutdown(context=ctx)
    texts = {k: (logs / f"{k.replace('/', '_')}.log").read_text() for k in procs}
    return heard, codes, texts


@pytest.mark.dds
@pytest.mark.slow
def test_left_wing_data_reaches_only_the_left_wing(two_wings):
    heard, _, _ = two_wings
    left = heard["/left_wing/modal_estimate"]
    assert left and any(m.status == 1 and abs(m.frequency - 2.0) < 0.1 for m in left[-1].modes)
    assert heard["/left_wing/vibration_filtered"] and heard["/left_wing/notch_bank"]
    # the residual spectrum is labelled with the bag's channel name ('y'), not y0
    assert {s.channel_name for s in heard["/left_wing/residual_spectrum"]} == {"y"}
    for name in ("modal_estimate", "notch_bank", "vibration_filtered", "residual_spectrum"):
        assert heard[f"/right_wing/{name}"] == [], f"/right_wing/{name} heard the left wing"


@pytest.mark.dds
@pytest.mark.slow
def test_logs_and_diagnostics_name_the_resolved_topics(two_wings):
    heard, codes, texts = two_wings
    assert "identifying modes from /left_wing/vibration (SignalSample), inputs from " \
           "/left_wing/excitation" in texts["left_wing/sysid_node"]
    assert "publishing /right_wing/modal_estimate" in texts["right_wing/sysid_node"]
    assert "filtering /right_wing/vibration (SignalSample) -> /right_wing/vibration_filtered, " \
           "estimates from /right_wing/modal_estimate" in texts["right_wing/notch_filter_node"]
    names = {s.name for a in heard["/diagnostics"] for s in a.status}
    for wing in WINGS:
        assert f"{wing}/sysid_node: identification" in names
        assert f"{wing}/notch_filter_node: notch bank" in names
    assert all("\x1b[" not in t and "Traceback" not in t for t in texts.values())
    assert codes == dict.fromkeys(codes, 0), codes
