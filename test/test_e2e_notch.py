"""End to end over real DDS, through the README's main job: ``replay`` of the paper-example bag
-> ``sysid_node`` -> ``notch_filter_node`` -> ``record`` (ros2_ws/tools/demo.py with the shipped
both-node YAML), replayed at the recorded pace (the demo's default, as in flight). A notch is
placed within 2 % of the 6 Hz mode within 3 s of its appearance at t = 20 s, the 2 and 4 Hz
modes keep theirs, and the report, table and summary are written.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
TOOLS = REPO / "ros2_ws" / "tools"
BAG = REPO / "bags" / "paper_example"
SWITCH_S = 20.0


@pytest.fixture(scope="module")
def demo_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("demo")
    env = dict(os.environ)
    env["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    env.setdefault("ROS_DOMAIN_ID", str(10 + os.getpid() % 80))
    proc = subprocess.run(
        [sys.executable, str(TOOLS / "demo.py"), "--bag", str(BAG), "--out", str(out)],
        capture_output=True, text=True, env=env, timeout=300,
    )
    assert proc.returncode == 0, (proc.stdout[-2000:], proc.stderr[-2000:])
    sys.path.insert(0, str(TOOLS))
    try:
        from demo_report import analyse
    finally:
        sys.path.remove(str(TOOLS))
    return out, proc.stdout, analyse(BAG, out / "recorded")


def notch_groups(notches):
    sys.path.insert(0, str(TOOLS))
    try:
        from demo_report import notch_groups as groups
    finally:
        sys.path.remove(str(TOOLS))
    return groups(notches)


def test_launch_file_runs_the_demos_parameters():
    """`ros2 launch notch_filter_node notch_filter.launch.py` behaves as ros2_ws/demo: its
    default params_file is the YAML the demo passes to both nodes, which holds both sections
    (checked without a ROS install: `launch` is not on PyPI)."""
    import ast

    import yaml

    sys.path.insert(0, str(TOOLS))
    try:
        import demo
    finally:
        sys.path.remove(str(TOOLS))
    launch = REPO / "src" / "notch_filter_node" / "launch" / "notch_filter.launch.py"
    names = {n.value for n in ast.walk(ast.parse(launch.read_text()))
             if isinstance(n, ast.Constant) and isinstance(n.value, str)}
    assert demo.DEFAULT_PARAMS.name in names and "notch_filter_node.yaml" not in names
    doc = yaml.safe_load(demo.DEFAULT_PARAMS.read_text())
    assert {"sysid_node", "notch_filter_node"} <= {str(k).split("/")[-1] for k in doc}
    data_files = (REPO / "src" / "notch_filter_node" / "setup.py").read_text()
    assert "config" in data_files and "launch" in data_files  # both installed to share/


def _notch_near(bank: dict, f: float, tol: float = 0.02) -> bool:
    # state 0 = tracking: an adaptive notch (one section or a pair) sitting on an estimated mode
    return any(st == 0 and abs(c - f) <= tol * f for _, st, c, _ in notch_groups(bank["notches"]))


@pytest.mark.dds
@pytest.mark.slow
def test_notch_on_six_hz_within_3_s_of_its_appearance(demo_run):
    _, _, res = demo_run
    assert res.banks, "no /notch_bank recorded"
    t_six = next((b["t"] for b in res.banks if b["t"] > SWITCH_S and _notch_near(b, 6.0)), None)
    assert t_six is not None and t_six - SWITCH_S <= 3.0, f"6 Hz notch only at t = {t_six}"
    last = res.banks[-1]
    assert all(_notch_near(last, f) for f in (2.0, 4.0, 6.0)), last


@pytest.mark.dds
@pytest.mark.slow
def test_main_job_prints_table_and_writes_report(demo_run):
    out, stdout, res = demo_run
    assert "notch centres [Hz]" in stdout and "[demo] report:" in stdout
    assert (out / "report.html").stat().st_size > 10_000
    summary = json.loads((out / "summary.json").read_text())
    # 400 publication periods, replayed at the recorded pace; a node that falls more than 0.25 s
    # behind (on this VM its processes stall for up to a second several times a minute, even
    # at 1x: 12 warnings in 40 s) skips the late estimates by design (catch_up, counted as
    # estimates_skipped): most are published (264-316 measured)
    assert summary["estimates_received"] > 200 and summary["notch_bank_messages"] > 0
    # the filtered signal was recorded; the bank lowers the three structural resonance peaks
    # (true mode x published sections), and never claims more than it does
    assert res.y_out is not None and len(res.y_out) > 0.9 * len(res.y_in)
    assert "peak reduction median/min" in stdout
    pr = {round(p["frequency_hz"]): p for p in summary["peak_reduction"]}
    assert set(pr) == {2, 4, 6}, pr
    assert all(p["median_db"] > 10.0 for p in pr.values()), pr
    assert all(p["claimed_median_db"] <= p["median_db"] + 0.5 for p in pr.values()), pr
