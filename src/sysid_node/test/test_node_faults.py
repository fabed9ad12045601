"""Fault injection into the running node over real DDS (issue #13, node-side classes): a stuck
sensor and a dead worker are visible in /diagnostics and on the estimates; bad parameter files
end the start-up with one line naming the closest valid name."""

from __future__ import annotations

import importlib.util
import os
import subprocess
import time
from pathlib import Path

import numpy as np
import pytest
from sysid_node.process_group import stop_group
from sysid_node.scenarios.paper import paper_example_data

pytest.importorskip("rclpy")
_spec = importlib.util.spec_from_file_location("sysid_test_node",
                                               Path(__file__).with_name("test_node.py"))
_tn = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(_tn)  # the DDS harness of test_node.py (not its tests)
FS, RUN, T0, Harness, _env = _tn.FS, _tn.RUN, _tn.T0, _tn.Harness, _tn._env
start_node = _tn.start_node

pytestmark = [pytest.mark.dds, pytest.mark.slow]


harness = _tn.harness  # the same fixture


def _diag(h: Harness, pred, timeout: float) -> dict[str, str] | None:
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        for d in list(h.diagnostics)[-3:]:
            st = d.status[0]
            kv = {v.key: v.value for v in st.values}
            kv["_level"], kv["_message"] = str(st.level[0]), st.message
            if pred(kv):
                return kv
        time.sleep(0.05)
    return None


def test_stuck_sensor_and_dead_worker_visible(harness, tmp_path):
    t, u, y = paper_example_data(duration_s=16.0, fs=FS, seed=5)
    stamps = T0 + np.round(t * 1e9).astype(np.int64)
    proc = start_node("-p", "output_type:=SignalBlock", "-p", "input_type:=SignalBlock",
                      "-p", f"sample_rate:={FS}", log=tmp_path / "node.log")
    try:
        harness.wait_for_node()
        harness.send(stamps[:600], y[:600], u[:600])
        good = harness.wait_estimate(stamps[560])
        assert good.health == 0
        y_stuck = y.copy()
        y_stuck[600:] = y[600]
        t_sent = time.monotonic()
        harness.send(stamps[600:800], y_stuck[600:800], u[600:800])
        kv = _diag(harness, lambda kv: kv.get("health") == "fault" and "stuck"
                   in kv.get("health_reason", ""), 20.0)
        assert kv is not None, [m.status[0].message for m in harness.diagnostics[-3:]]
        assert kv["_level"] == "2" and "stuck" in kv["_message"]
        print(f"stuck output visible in /diagnostics {time.monotonic() - t_sent:.2f} s after "
              "the stuck data started")
        last = harness.wait_estimate(stamps[760])
        assert last.health == 2 and "stuck" in last.health_reason and not last.converged

        # the worker process killed: restarted, said, and estimates resume
        workers = subprocess.run(["pgrep", "-P", str(proc.pid)], capture_output=True,
                                 text=True).stdout.split()
        killed = 0
        for w in workers:
            with open(f"/proc/{w}/cmdline", "rb") as fh:
                cmd = fh.read()
            if b"multiprocessing-fork" in cmd and b"resource_tracker" not in cmd:
                os.kill(int(w), 9)
                killed += 1
        assert killed == 1, workers
        harness.send(stamps[800:1600], y[800:1600], u[800:1600])
        kv = _diag(harness, lambda kv: int(kv.get("worker_restarts", "0")) >= 1, 60.0)
        assert kv is not None
        after = harness.wait_estimate(stamps[1500], timeout=90)
        assert after.samples_used > 0
    finally:
        code = stop_group(proc)
    text = (tmp_path / "node.log").read_text()
    assert code == 0 and "Traceback" not in text, text[-2000:]
    assert "restarting it" in text


@pytest.mark.parametrize(("content", "needle"), [
    ("sysid_node:\n  ros__parameters:\n    forgeting_factor: 0.98\n",
     "did you mean 'forgetting_factor'"),
    ("sysid_nod:\n  ros__parameters:\n    forgetting_factor: 0.98\n",
     "did you mean 'sysid_node'"),
    ("sysid_node:\n  ros__parameters:\n    forgetting_factor: [0.98\n", "not valid YAML"),
    ("sysid_node:\n  ros__parameters:\n    block_rows: 3.5\n", "block_rows"),
])
def test_bad_params_file_one_line(content, needle, tmp_path):
    f = tmp_path / "p.yaml"
    f.write_text(content)
    res = subprocess.run([str(RUN), "sysid_node", "sysid_node", "--ros-args", "--params-file",
                          str(f)], capture_output=True, text=True, env=_env(), timeout=120)
    assert res.returncode == 1, res.stderr[-2000:]
    err = [ln for ln in res.stderr.splitlines() if ln.startswith("sysid_node: error:")]
    assert len(err) == 1 and needle in err[0] and "Traceback" not in res.stderr, res.stderr
