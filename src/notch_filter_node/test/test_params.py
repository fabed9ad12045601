"""Parameter table, shipped YAML, and the message adapters of the node (no DDS)."""

from pathlib import Path

import numpy as np
import pytest
import yaml
from notch_filter_node.policy import PolicyConfig

from notch_filter_node import params as P

PKG = Path(__file__).resolve().parents[1]


def test_every_parameter_has_description_and_range():
    for s in P.PARAMS:
        assert s.description, s.name
        if s.type in (int, float):
            assert s.lo is not None and s.hi is not None and s.lo <= s.default <= s.hi, s.name
        assert P.validate(s.name, s.default) == "", s.name
    assert P.validate_set(P.defaults()) == ""


def test_defaults_match_policy_config():
    assert P.policy_config(P.defaults()) == PolicyConfig()


@pytest.mark.parametrize(
    ("name", "value", "words"),
    [
        ("depth", 100.0, "above the maximum"),
        ("slew_rate", -1.0, "below the minimum"),
        ("signal_type", "Foo", "not one of"),
        ("imu_axes", "az,qq", "imu_axes"),
        ("disabled_channels", "1,x", "disabled_channels"),
        ("output_topic", "a//b", "empty name token"),
        ("bank_topic", "bank-1", "letters, digits"),
        ("depth", "deep", "type float"),
        ("hold_time", float("nan"), "finite"),
        ("nope", 1, "unknown"),
    ],
)
def test_invalid_values_have_a_reason(name, value, words):
    assert words in P.validate(name, value)


def test_cross_checks():
    v = P.defaults()
    assert "must exceed" in P.validate_set({**v, "peak_reduction": 35.0})
    assert "fallback_timeout" in P.validate_set({**v, "stale_timeout": 20.0})
    assert "not one of" in P.validate_set({**v, "budget_priority": "both"})
    assert "Nyquist" in P.validate_set({**v, "freq_max": 300.0}, fs=500.0)
    assert P.validate_set({**v, "freq_max": 200.0}, fs=500.0) == ""
    assert P.disabled_channels(" 0, 3") == [0, 3]


def test_shipped_yaml_is_the_defaults():
    doc = yaml.safe_load((PKG / "config" / "notch_filter_node.yaml").read_text())
    values = doc["/**/notch_filter_node"]["ros__parameters"]
    assert set(values) == set(P.SPECS)
    for k, v in values.items():
        assert v == P.SPECS[k].default, k
    assert P.validate_set(values) == ""


@pytest.mark.parametrize(
    ("text", "words"),
    [
        ("notch_filter_node:\n  ros__parameters:\n    depht: 30.0\n",
         "unknown parameter 'depht' (did you mean 'depth'?) for notch_filter_node"),
        ("notch_filer_node:\n  ros__parameters:\n    depth: 30.0\n",
         "section 'notch_filer_node' matches no node (did you mean 'notch_filter_node'?)"),
        ("notch_filter_node:\n  ros__parameters:\n    depth: [30.0\n", "not valid YAML at line"),
        ("- 1\n- 2\n", "expected 'NODE_NAME: ros__parameters: ...'"),
        ("notch_filter_node: 3\n", "has no 'ros__parameters:' mapping"),
    ],
)
def test_params_file_problems_have_one_line_reasons(tmp_path, text, words):
    path = tmp_path / "p.yaml"
    path.write_text(text)
    reason = P.check_params_file(str(path), "notch_filter_node")
    assert words in reason and "\n" not in reason
    assert "cannot read" in P.check_params_file(str(tmp_path / "none.yaml"), "notch_filter_node")


def test_params_file_with_other_nodes_and_wildcards_is_fine(tmp_path):
    path = tmp_path / "p.yaml"
    path.write_text("sysid_node:\n  ros__parameters:\n    forgetting_factor: 0.99\n"
                    "/**:\n  ros__parameters:\n    use_sim_time: false\n"
                    "camera_driver:\n  ros__parameters:\n    fps: 30\n"
                    "notch_filter_node:\n  ros__parameters:\n    depth: 30\n")
    assert P.check_params_file(str(path), "notch_filter_node") == ""
    for cfg in (PKG / "config").glob("*.yaml"):
        assert P.check_params_file(str(cfg), "notch_filter_node") == "", cfg


def test_type_errors_name_both_types_and_unknown_names_the_closest():
    from sysid_node import node_params as NP

    assert P.validate("depth", 30) == ""
    assert P.validate("depth", "deep") == (
        "depth: expected double (type float), got string (type str)")
    assert NP.unknown_names(P.SPECS, ["depth", "use_sim_time", "depht"]) == (
        "unknown parameter 'depht' (did you mean 'depth'?)")
    assert NP.closest("forgeting_factor", ["forgetting_factor", "depth"]) == (
        " (did you mean 'forgetting_factor'?)")


def test_message_adapters():
    from notch_filter_node.node import estimate_input, filled_message
    from sensor_msgs.msg import Imu

    from sysid_msgs.msg import ModalEstimate, Mode, SignalBlock

    blk = SignalBlock(sample_period=0.005, channel_count=2, data=[1.0, 2.0, 3.0, 4.0],
                      channel_names=["a", "b"])
    blk.header.stamp.sec, blk.header.frame_id = 5, "wing"
    out = filled_message(blk, "SignalBlock", np.array([[9.0, 8.0], [7.0, 6.0]]), [])
    assert list(out.data) == [9.0, 8.0, 7.0, 6.0] and out.header.frame_id == "wing"
    assert out.header.stamp.sec == 5 and list(blk.data) == [1.0, 2.0, 3.0, 4.0]
    imu = Imu()
    imu.linear_acceleration.z, imu.angular_velocity.x = 9.81, 0.5
    out = filled_message(imu, "Imu", np.array([[1.5]]), ["az"])
    assert out.linear_acceleration.z == 1.5 and out.angular_velocity.x == 0.5
    assert imu.linear_acceleration.z == 9.81
    est = ModalEstimate(converged=True, modes=[
        Mode(id=2, status=Mode.STATUS_TRACKED, frequency=6.0, frequency_std=0.01,
             damping_ratio=0.02, damping_ratio_std=float("nan"))])
    est.header.stamp.sec, est.header.stamp.nanosec = 3, 500_000_000
    e = estimate_input(est)
    assert e.stamp == 3.5 and e.converged
    (m,) = e.modes
    assert (m.id, m.status, m.frequency_hz) == (2, "tracked", 6.0) and np.isnan(m.damping_std)
