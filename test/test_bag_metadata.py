"""Bags are readable by every supported ROS 2 distribution's rosbag2 (Humble, Iron, Jazzy,
Kilted, Rolling): the committed bags and whatever ``bag_io.BagWriter`` writes (record, offline).

``reader_errors`` models what each distribution's reader requires of the metadata, as read in
ros2/rosbag2 (``rosbag2_storage`` metadata decoding per branch, the QoS decoding of
``rosbag2_transport`` in Humble and of ``rosbag2_storage`` from Jazzy on):

- every version: version, storage_identifier, duration, starting_time, message_count,
  topics_with_message_count (name, type, serialization_format, message_count) and
  relative_file_paths; from version 3 compression_format/mode; from 5 files;
- ``offered_qos_profiles`` (version >= 4): Humble and Iron take it as a YAML *string* whatever
  the version; Jazzy and later take a string up to version 8 and a *list* from version 9. A
  non-empty string is a YAML list of profiles; Humble reads their policies as integers;
- Iron and later: ``custom_data`` (version >= 6, a map or null) and ``type_description_hash``
  (version >= 7); Jazzy and later: ``ros_distro`` (version >= 8).

The same rules apply where a reader takes the metadata from inside the storage: the mcap
``rosbag2`` metadata record (Jazzy on), the mcap channels' ``offered_qos_profiles`` (every
distribution) and the sqlite3 ``metadata`` table.
"""

from __future__ import annotations

import io
import sqlite3
from pathlib import Path

import numpy as np
import pytest
import yaml

from sysid_node import bag_io

REPO = Path(__file__).resolve().parents[1]
DISTROS = bag_io.BAG_READERS
QOS_KEYS = ("history", "depth", "reliability", "durability", "deadline", "lifespan",
            "liveliness", "liveliness_lease_duration", "avoid_ros_namespace_conventions")
COMMITTED = sorted(p.parent for p in (REPO / "bags").rglob("metadata.yaml"))


def _qos_errors(profiles, distro: str, where: str) -> list[str]:
    """A parsed list of QoS profiles as the distribution's player decodes it."""
    if not isinstance(profiles, list):
        return [f"{where}: QoS profiles are not a list"]
    errors = []
    for q in profiles:
        missing = [k for k in QOS_KEYS if not isinstance(q, dict) or k not in q]
        if missing:
            errors.append(f"{where}: QoS profile without {', '.join(missing)}")
            continue
        for k in ("deadline", "lifespan", "liveliness_lease_duration"):
            if not (isinstance(q[k], dict) and {"sec", "nsec"} <= set(q[k])):
                errors.append(f"{where}: QoS {k} is not {{sec, nsec}}")
        if distro == "humble" and not all(
            isinstance(q[k], int) for k in ("history", "reliability", "durability", "liveliness")
        ):
            errors.append(f"{where}: Humble reads QoS policies as integers")
    return errors


def qos_string_errors(text, distro: str, where: str) -> list[str]:
    """``offered_qos_profiles`` held as a string (metadata up to v8, mcap channel metadata)."""
    if not isinstance(text, str):
        return [f"{where}: offered_qos_profiles is a {type(text).__name__}, {distro} "
                "expects a string"]
    return _qos_errors(yaml.safe_load(text), distro, where) if text.strip() else []


def reader_errors(info: dict, distro: str, where: str = "metadata") -> list[str]:
    """Why ``distro``'s rosbag2 cannot decode ``info`` (rosbag2_bagfile_information)."""
    errors: list[str] = []
    v = info.get("version")
    if not isinstance(v, int):
        return [f"{where}: version is not an integer"]

    def need(d: dict, key: str, kind, at: str) -> None:
        if key not in d or (kind is not None and not isinstance(d[key], kind)):
            errors.append(f"{where}: {at}{key} missing or not {getattr(kind, '__name__', kind)}")

    need(info, "storage_identifier", str, "")
    need(info, "message_count", int, "")
    need(info, "relative_file_paths", list, "")
    for key, sub in (("duration", "nanoseconds"), ("starting_time", "nanoseconds_since_epoch")):
        need(info, key, dict, "")
        if isinstance(info.get(key), dict):
            need(info[key], sub, int, f"{key}.")
    if v >= 3:
        need(info, "compression_format", str, "")
        need(info, "compression_mode", str, "")
    if v >= 5:
        need(info, "files", list, "")
    if v >= 6 and distro != "humble" and not isinstance(info.get("custom_data", 0), dict | None):
        errors.append(f"{where}: custom_data must be a map or null")
    if v >= 8 and distro in ("jazzy", "kilted", "rolling"):
        need(info, "ros_distro", str, "")
    for k, entry in enumerate(info.get("topics_with_message_count") or []):
        tm = entry.get("topic_metadata", {})
        at = f"topic {tm.get('name', k)}: "
        need(entry, "message_count", int, at)
        for key in ("name", "type", "serialization_format"):
            need(tm, key, str, at)
        if v >= 7 and distro != "humble":
            need(tm, "type_description_hash", str, at)
        if v < 4:
            continue
        qos = tm.get("offered_qos_profiles")
        if v >= 9 and distro in ("jazzy", "kilted", "rolling"):
            errors += _qos_errors(qos, distro, f"{where}: {at}")
        else:
            errors += qos_string_errors(qos, distro, f"{where}: {at}")
    return errors


def storage_errors(bag: Path, distro: str) -> list[str]:
    """The metadata a storage plugin reads from inside the bag's file."""
    from mcap.reader import make_reader

    info = yaml.safe_load((bag / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    errors = []
    for rel in info["relative_file_paths"]:
        data = (bag / rel).read_bytes()
        if rel.endswith(".zstd"):
            import zstandard

            data = zstandard.ZstdDecompressor().decompressobj().decompress(data)
        if info["storage_identifier"] == "mcap":
            reader = make_reader(io.BytesIO(data))
            for ch in reader.get_summary().channels.values():
                errors += qos_string_errors(ch.metadata.get("offered_qos_profiles", ""), distro,
                                            f"{rel} channel {ch.topic}")
            if distro in ("jazzy", "kilted", "rolling"):
                for rec in reader.iter_metadata():
                    if rec.name == "rosbag2":
                        inner = yaml.safe_load(rec.metadata["serialized_metadata"])
                        errors += reader_errors(inner, distro, f"{rel} rosbag2 record")
        else:
            tmp = bag / (rel + ".check")
            tmp.write_bytes(data)
            try:
                with sqlite3.connect(tmp) as db:
                    for (qos,) in db.execute("SELECT offered_qos_profiles FROM topics"):
                        errors += qos_string_errors(qos, distro, f"{rel} topics table")
                    if distro in ("jazzy", "kilted", "rolling"):
                        for (text,) in db.execute("SELECT metadata FROM metadata"):
                            errors += reader_errors(yaml.safe_load(text), distro,
                                                    f"{rel} metadata table")
            finally:
                tmp.unlink()
    return errors


def _all_errors(bag: Path) -> list[str]:
    info = yaml.safe_load((bag / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    return [e for d in DISTROS for e in
            [f"{d}: {x}" for x in reader_errors(info, d) + storage_errors(bag, d)]]


@pytest.mark.parametrize("bag", COMMITTED, ids=[str(p.relative_to(REPO)) for p in COMMITTED])
def test_committed_bags_are_readable_by_every_supported_distro(bag):
    assert _all_errors(bag) == []
    assert bag_io.list_topics(bag)  # and rosbags reads them


@pytest.mark.parametrize(("storage", "compress"),
                         [("mcap", False), ("mcap", True), ("sqlite3", False)])
def test_written_bags_are_readable_by_every_supported_distro(tmp_path, storage, compress):
    t = np.arange(5) * 0.01
    path = tmp_path / "bag"
    with bag_io.BagWriter(path, storage=storage, compress=compress) as bag:
        bag.add_topic("/vibration", bag_io.SIGNAL_SAMPLE)  # no QoS known
        bag.add_topic("/modal_estimate", "sysid_msgs/msg/ModalEstimate",
                      [bag_io.make_qos(reliable=True, transient_local=True, depth=1)])
        for ns, msg in bag_io.signal_samples(t, t, ["y"]):
            bag.write("/vibration", ns, msg)
    assert _all_errors(path) == []
    with bag_io.open_bag(path) as reader:
        conns = {c.topic: c for c in reader.connections}
    (qos,) = conns["/modal_estimate"].ext.offered_qos_profiles  # kept for the replay tool
    assert qos.depth == 1 and qos.durability.name == "TRANSIENT_LOCAL"


def test_a_version_9_bag_is_refused_by_humble_and_iron(tmp_path):
    """The checker sees the problem of the issue: rosbag2 v9 QoS lists break older readers."""
    path = tmp_path / "v9"
    with bag_io.BagWriter(path, version=9) as bag:
        bag.add_topic("/modal_estimate", "sysid_msgs/msg/ModalEstimate", [bag_io.make_qos()])
    info = yaml.safe_load((path / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    for distro in ("humble", "iron"):
        assert any("expects a string" in e for e in reader_errors(info, distro)), distro
    assert any("integers" in e for e in storage_errors(path, "humble"))
    assert reader_errors(info, "jazzy") == [] and reader_errors(info, "kilted") == []
