"""bag_io: real rosbag2 files (mcap and sqlite3) written and read with rosbags."""

from __future__ import annotations

import json
import shutil
import sys
from pathlib import Path

import numpy as np
import pytest
from sysid_node.bag_io import BagError

from sysid_node import bag_io

T0 = 1_700_000_000.0


def _signals(n: int = 300, seed: int = 1):
    rng = np.random.default_rng(seed)
    t = T0 + np.arange(n) / 100.0
    return t, rng.standard_normal((n, 3)), rng.standard_normal((n, 1))


def _one_line(err: pytest.ExceptionInfo) -> str:
    text = str(err.value)
    assert text and "\n" not in text and "Traceback" not in text
    return text


@pytest.mark.parametrize("storage", ["mcap", "sqlite3"])
@pytest.mark.parametrize("compress", [False, True])
def test_signal_sample_round_trip(tmp_path: Path, storage: str, compress: bool) -> None:
    t, y, u = _signals()
    names = ["acc_1[m/s^2]", "acc_2[m/s^2]", "acc_3[m/s^2]"]
    bag = bag_io.write_signals(
        tmp_path / "b",
        {"/vibration": (t, y, names), "/excitation": (t, u, ["u[N]"])},
        storage=storage,
        compress=compress,
    )
    topics = bag_io.list_topics(bag)
    assert topics == {
        "/vibration": (bag_io.SIGNAL_SAMPLE, 300),
        "/excitation": (bag_io.SIGNAL_SAMPLE, 300),
    }
    sig = bag_io.read_signals(bag)
    assert list(sig) == ["/excitation", "/vibration"]
    v = sig["/vibration"]
    assert v.msgtype == bag_io.SIGNAL_SAMPLE and v.channel_names == names
    assert v.values.dtype == np.float64 and v.values.shape == (300, 3)
    np.testing.assert_array_equal(v.values, y)
    np.testing.assert_allclose(v.t, t, rtol=0, atol=1e-6)
    np.testing.assert_allclose(v.receive_t, t, rtol=0, atol=1e-6)
    assert v.sample_rate == pytest.approx(100.0, rel=1e-6)
    assert v.bad_messages == 0
    np.testing.assert_array_equal(sig["/excitation"].values, u)
    only = bag_io.read_signals(bag, ["/excitation"])
    assert list(only) == ["/excitation"]


@pytest.mark.parametrize("storage", ["mcap", "sqlite3"])
def test_block_and_imu_and_raw_stream(tmp_path: Path, storage: str) -> None:
    ts = bag_io.typestore()
    header = ts.types["std_msgs/msg/Header"]
    block = ts.types[bag_io.SIGNAL_BLOCK]
    vec = ts.types["geometry_msgs/msg/Vector3"]
    quat = ts.types["geometry_msgs/msg/Quaternion"]
    imu = ts.types[bag_io.IMU]
    rng = np.random.default_rng(2)
    data = rng.standard_normal((4, 10, 2))  # 4 blocks of 10 samples, 2 channels
    blocks = [
        (
            int((T0 + 0.1 * k) * 1e9),
            block(
                header=header(stamp=bag_io.stamp_msg(T0 + 0.1 * k), frame_id="wing"),
                sample_period=0.01,
                channel_count=2,
                data=data[k].reshape(-1).copy(),
                channel_names=["a", "b"],
            ),
        )
        for k in range(4)
    ]
    acc = rng.standard_normal((5, 6))
    imus = [
        (
            int((T0 + 0.02 * k) * 1e9),
            imu(
                header=header(stamp=bag_io.stamp_msg(T0 + 0.02 * k), frame_id="imu"),
                orientation=quat(x=0.0, y=0.0, z=0.0, w=1.0),
                orientation_covariance=np.zeros(9),
                angular_velocity=vec(x=acc[k, 3], y=acc[k, 4], z=acc[k, 5]),
                angular_velocity_covariance=np.zeros(9),
                linear_acceleration=vec(x=acc[k, 0], y=acc[k, 1], z=acc[k, 2]),
                linear_acceleration_covariance=np.zeros(9),
            ),
        )
        for k in range(5)
    ]
    bag = bag_io.write_bag(
        tmp_path / "b",
        {"/block": (bag_io.SIGNAL_BLOCK, blocks), "/imu": (bag_io.IMU, imus)},
        storage=storage,
    )
    sig = bag_io.read_signals(bag)
    b = sig["/block"]
    np.testing.assert_array_equal(b.values, data.reshape(40, 2))
    np.testing.assert_allclose(b.t - T0, np.arange(40) * 0.01, atol=1e-6)
    assert b.channel_names == ["a", "b"]
    i = sig["/imu"]
    assert i.channel_names == list(bag_io.IMU_CHANNELS)
    np.testing.assert_array_equal(i.values, acc)
    raw = list(bag_io.iter_messages(bag, ["/imu", "/block"]))
    assert len(raw) == 9
    stamps = [ts_ for _, ts_, _ in raw]
    assert stamps == sorted(stamps)
    conn, _, data0 = raw[0]
    assert conn.topic == "/block" and isinstance(data0, bytes)
    back = ts.deserialize_cdr(data0, conn.msgtype)
    np.testing.assert_array_equal(back.data, data[0].reshape(-1))


def test_wrong_channel_count_becomes_nan_row(tmp_path: Path) -> None:
    t, y, _ = _signals(5)
    items = bag_io.signal_samples(t, y, ["a", "b", "c"])
    items[2] = bag_io.signal_samples(t[2:3], y[2:3, :2], ["a", "b"])[0]
    items[0] = bag_io.signal_samples(t[:1], y[:1, :1], ["a"])[0]  # even the first one
    bag = bag_io.write_bag(tmp_path / "b", {"/v": (bag_io.SIGNAL_SAMPLE, items)})
    v = bag_io.read_signals(bag)["/v"]
    assert v.bad_messages == 2 and v.channel_names == ["a", "b", "c"]
    assert np.isnan(v.values[[0, 2]]).all()
    np.testing.assert_array_equal(v.values[[1, 3, 4]], y[[1, 3, 4]])


@pytest.fixture
def small_bag(tmp_path: Path) -> Path:
    t, y, u = _signals(200)
    return bag_io.write_signals(
        tmp_path / "ok", {"/vibration": (t, y, []), "/excitation": (t, u, [])}
    )


def test_missing_path(tmp_path: Path) -> None:
    with pytest.raises(BagError) as err:
        bag_io.read_signals(tmp_path / "nope")
    assert "not found" in _one_line(err)


def test_not_a_bag(tmp_path: Path) -> None:
    (tmp_path / "empty").mkdir()
    with pytest.raises(BagError) as err:
        bag_io.read_signals(tmp_path / "empty")
    assert "metadata.yaml" in _one_line(err)
    (tmp_path / "x.txt").write_text("hello")
    with pytest.raises(BagError):
        bag_io.list_topics(tmp_path / "x.txt")


def test_corrupt_metadata(small_bag: Path) -> None:
    (small_bag / "metadata.yaml").write_text("rosbag2_bagfile_information: [unclosed\n")
    with pytest.raises(BagError) as err:
        bag_io.read_signals(small_bag)
    _one_line(err)


@pytest.mark.parametrize("storage", ["mcap", "sqlite3"])
def test_truncated(tmp_path: Path, storage: str) -> None:
    t, y, u = _signals(2000)
    bag = bag_io.write_signals(tmp_path / "b", {"/vibration": (t, y, [])}, storage=storage)
    (data,) = [p for p in bag.iterdir() if p.suffix in (".mcap", ".db3")]
    raw = data.read_bytes()
    data.write_bytes(raw[: len(raw) // 2])
    with pytest.raises(BagError) as err:
        bag_io.read_signals(bag)
    assert str(bag) in _one_line(err)


def test_file_inside_bag_is_accepted(small_bag: Path) -> None:
    (data,) = small_bag.glob("*.mcap")
    assert set(bag_io.read_signals(data)) == {"/vibration", "/excitation"}


def test_no_such_topic_lists_available(small_bag: Path) -> None:
    with pytest.raises(BagError) as err:
        bag_io.read_signals(small_bag, ["/vibration", "/airspeed"])
    text = _one_line(err)
    assert "/airspeed" in text and "available: /excitation, /vibration" in text
    with pytest.raises(BagError):
        list(bag_io.iter_messages(small_bag, ["/nothing"]))


def test_unknown_message_type(tmp_path: Path) -> None:
    with pytest.raises(BagError) as err, bag_io.BagWriter(tmp_path / "w") as w:
        w.add_topic("/x", "foo_msgs/msg/Bar")
    assert "unknown message type foo_msgs/msg/Bar" in _one_line(err)
    # A bag holding a type this package does not know (definition embedded in the bag).
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    foreign = get_typestore(Stores.EMPTY)
    foreign.register(get_types_from_msg("float64 x\n", "foo_msgs/msg/Bar"))
    path = tmp_path / "foreign"
    with Writer(path, version=9, storage_plugin=StoragePlugin.MCAP) as w:
        c = w.add_connection("/bar", "foo_msgs/msg/Bar", typestore=foreign)
        w.write(c, 1, b"\x00\x01\x00\x00" + b"\x00" * 8)
    assert bag_io.list_topics(path)["/bar"][0] == "foo_msgs/msg/Bar"
    assert bag_io.read_signals(path) == {}  # skipped when not asked for
    with pytest.raises(BagError) as err:
        bag_io.read_signals(path, ["/bar"])
    assert "foo_msgs/msg/Bar" in _one_line(err)


def test_writer_errors(small_bag: Path, tmp_path: Path) -> None:
    with pytest.raises(BagError) as err:
        bag_io.BagWriter(small_bag)
    assert "already exists" in _one_line(err)
    with pytest.raises(BagError) as err:
        bag_io.BagWriter(tmp_path / "new", storage="rosbag1")
    _one_line(err)
    with pytest.raises(BagError):
        bag_io.BagWriter(tmp_path / "no" / "such" / "dir")
    shutil.rmtree(small_bag)


def test_qos_record_is_stored(tmp_path: Path) -> None:
    qos = bag_io.make_qos(reliable=True, transient_local=True, depth=1)
    with bag_io.BagWriter(tmp_path / "q") as w:
        w.add_topic("/modal_estimate", "sysid_msgs/msg/ModalEstimate", qos=[qos])
    text = (tmp_path / "q" / "metadata.yaml").read_text()
    assert "transient_local" in text.lower() or "durability: 1" in text


# --------------------------------------------------------------------------------------------
# The committed scenario bags (bags/) and their generator
# --------------------------------------------------------------------------------------------

BAGS = Path(__file__).resolve().parents[3] / "bags"
SCENARIOS = ["paper_example", "wing_bending_drift", "cobra_stick", "output_only"]


def _generator():
    import importlib.util

    spec = importlib.util.spec_from_file_location("generate_bags", BAGS / "generate_bags.py")
    mod = importlib.util.module_from_spec(spec)
    sys.modules.setdefault("generate_bags", mod)  # dataclasses look their module up
    spec.loader.exec_module(sys.modules["generate_bags"])
    mod = sys.modules["generate_bags"]
    return mod


@pytest.mark.parametrize("name", SCENARIOS)
def test_scenario_bag_matches_its_truth(name: str) -> None:
    import json

    truth = json.loads((BAGS / f"{name}.truth.json").read_text())
    sig = bag_io.read_signals(BAGS / name)
    assert set(sig) == set(truth["topics"])
    assert ("/excitation" not in sig) == truth["output_only"] == (name == "output_only")
    for topic, info in truth["topics"].items():
        s = sig[topic]
        assert s.msgtype == bag_io.SIGNAL_SAMPLE
        assert s.channel_names == info["channels"] and len(s) == info["samples"]
        assert np.isfinite(s.values).all()
        dt = np.diff(s.t)
        assert np.allclose(dt, 1.0 / info["rate_hz"], rtol=0, atol=2e-6), topic
        assert s.t[0] == pytest.approx(truth["start_time_s"])
    vib = sig["/vibration"]
    assert vib.sample_rate == pytest.approx(truth["sample_rate_hz"], rel=1e-6)
    assert len(vib) / truth["sample_rate_hz"] == pytest.approx(truth["duration_s"])
    for mode in truth["modes"]:
        assert len(mode["t_s"]) == len(mode["frequency_hz"]) == len(mode["damping_ratio"]) >= 2
        assert 0 < min(mode["frequency_hz"]) and max(mode["frequency_hz"]) < 0.5 * vib.sample_rate


def test_truth_follows_the_paper() -> None:
    import json

    paper = json.loads((BAGS / "paper_example.truth.json").read_text())
    first = {round(m["frequency_hz"][0]): m["t_s"][0] for m in paper["modes"]}
    assert first == {2: 0.0, 4: 0.0, 6: 20.0}
    wing = json.loads((BAGS / "wing_bending_drift.truth.json").read_text())
    (swb,) = [m for m in wing["modes"] if m["name"] == "symmetric_wing_beam"]
    assert swb["frequency_hz"][0] == pytest.approx(2.6) and swb["frequency_hz"][-1] == 3.0
    air = bag_io.read_signals(BAGS / "wing_bending_drift", ["/airspeed"])["/airspeed"]
    assert air.values[:50].mean() == pytest.approx(150 * 0.514444, abs=0.2)
    assert air.values[-50:].mean() == pytest.approx(250 * 0.514444, abs=0.2)


def test_committed_bag_is_what_the_generator_makes(tmp_path: Path) -> None:
    gen = _generator()
    assert gen.main(["paper_example", "--out", str(tmp_path)]) == 0
    new = bag_io.read_signals(tmp_path / "paper_example")
    old = bag_io.read_signals(BAGS / "paper_example")
    # same numbers up to rounding: another CPU (other BLAS kernels) differs in the last bits
    for topic in old:
        scale = np.max(np.abs(old[topic].values))
        np.testing.assert_allclose(new[topic].values, old[topic].values, rtol=1e-9,
                                   atol=1e-12 * scale)
        np.testing.assert_allclose(new[topic].t, old[topic].t, rtol=0, atol=1e-9)
    assert set(new) == set(old)
    new_truth = json.loads((tmp_path / "paper_example.truth.json").read_text())
    old_truth = json.loads((BAGS / "paper_example.truth.json").read_text())
    assert _approx_tree(new_truth, old_truth)


def _approx_tree(a, b) -> bool:
    """Nested JSON values equal, floats within a relative 1e-9."""
    if isinstance(b, dict):
        return isinstance(a, dict) and a.keys() == b.keys() and all(
            _approx_tree(a[k], b[k]) for k in b)
    if isinstance(b, list):
        return isinstance(a, list) and len(a) == len(b) and all(
            _approx_tree(x, y) for x, y in zip(a, b, strict=True))
    if isinstance(b, float):
        return a == pytest.approx(b, rel=1e-9, abs=1e-12)
    return a == b


def test_ros1_bag_is_refused(tmp_path: Path) -> None:
    (tmp_path / "old.bag").write_bytes(b"#ROSBAG V2.0\n")
    with pytest.raises(BagError) as err:
        bag_io.read_signals(tmp_path / "old.bag")
    assert "rosbags-convert" in _one_line(err)
