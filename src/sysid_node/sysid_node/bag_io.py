"""rosbag2 access through the pure-Python ``rosbags`` library (no rclpy, no rosbag2).

The ``sysid_msgs`` definitions are registered from their ``.msg`` files: the installed copies
(``share/sysid_msgs/msg`` found through the ament index) or, in a source checkout, the package
sources. Messages read here are ``rosbags`` dataclasses, not rclpy messages.
"""

from __future__ import annotations

import os
from collections.abc import Iterable, Iterator, Mapping, Sequence
from contextlib import contextmanager, suppress
from dataclasses import dataclass
from functools import cache
from pathlib import Path

import numpy as np
from rosbags.highlevel import AnyReader, AnyReaderError
from rosbags.interfaces import (
    Connection,
    Qos,
    QosDurability,
    QosHistory,
    QosLiveliness,
    QosReliability,
    QosTime,
)
from rosbags.rosbag2 import CompressionFormat, CompressionMode, ReaderError, StoragePlugin, Writer
from rosbags.typesys import Stores, get_types_from_msg, get_typestore
from rosbags.typesys.store import Typestore

MSG_PACKAGE = "sysid_msgs"
_SOURCE_MSG_DIR = Path(__file__).resolve().parents[2] / MSG_PACKAGE / "msg"


class BagError(RuntimeError):
    """A bag cannot be used; ``str(err)`` is a one-line reason for the user."""


def msg_dir() -> Path:
    """Directory holding ``sysid_msgs/msg/*.msg`` (installed share first, then the sources)."""
    try:
        from ament_index_python.packages import get_package_share_directory

        installed = Path(get_package_share_directory(MSG_PACKAGE)) / "msg"
        if any(installed.glob("*.msg")):
            return installed
    except (ImportError, LookupError, ValueError):
        pass
    if any(_SOURCE_MSG_DIR.glob("*.msg")):
        return _SOURCE_MSG_DIR
    raise BagError(f"cannot find the {MSG_PACKAGE} .msg files (workspace not built?)")


@cache
def typestore(store: Stores = Stores.ROS2_KILTED) -> Typestore:
    """A typestore with the ROS 2 standard types plus every ``sysid_msgs`` message."""
    ts = get_typestore(store)
    types: dict = {}
    for path in sorted(msg_dir().glob("*.msg")):
        types.update(get_types_from_msg(path.read_text(), f"{MSG_PACKAGE}/msg/{path.stem}"))
    ts.register(types)
    return ts


def msg_names() -> list[str]:
    """Full type names of the ``sysid_msgs`` messages, e.g. ``sysid_msgs/msg/Mode``."""
    return [f"{MSG_PACKAGE}/msg/{p.stem}" for p in sorted(msg_dir().glob("*.msg"))]


def bag_exists(path: str | os.PathLike) -> Path:
    """Return ``path`` as a Path if it looks like a rosbag2 directory or file, else raise."""
    p = Path(path)
    if not p.exists():
        raise BagError(f"bag not found: {p}")
    return p


# --------------------------------------------------------------------------------------------
# Reading
# --------------------------------------------------------------------------------------------

SIGNAL_SAMPLE = "sysid_msgs/msg/SignalSample"
SIGNAL_BLOCK = "sysid_msgs/msg/SignalBlock"
IMU = "sensor_msgs/msg/Imu"
SIGNAL_TYPES = (SIGNAL_SAMPLE, SIGNAL_BLOCK, IMU)
IMU_CHANNELS = (
    "linear_acceleration_x",
    "linear_acceleration_y",
    "linear_acceleration_z",
    "angular_velocity_x",
    "angular_velocity_y",
    "angular_velocity_z",
)
STORAGES = ("mcap", "sqlite3")


@dataclass
class Signal:
    """Samples of one topic as arrays.

    ``t`` holds the sample times [s] from the header stamps (for ``SignalBlock`` expanded to
    ``header.stamp + k * sample_period``), ``values`` the samples (one row per sample, one column
    per channel), ``receive_t`` the bag log time [s] of the message each sample came in.
    ``bad_messages`` counts messages whose channel count differs from the usual one (the most
    common for ``SignalSample``, where such a message becomes a NaN row; the first message's for
    ``SignalBlock``, where a malformed block is skipped).
    """

    topic: str
    msgtype: str
    t: np.ndarray
    values: np.ndarray
    channel_names: list[str]
    receive_t: np.ndarray
    bad_messages: int = 0

    def __len__(self) -> int:
        return int(self.t.shape[0])

    @property
    def channel_count(self) -> int:
        return int(self.values.shape[1])

    @property
    def sample_rate(self) -> float:
        """Median sample rate from the stamps [Hz]; NaN with fewer than two samples."""
        if len(self) < 2:
            return float("nan")
        dt = np.median(np.diff(self.t))
        return float(1.0 / dt) if dt > 0 else float("nan")


def _resolve(path: str | os.PathLike) -> Path:
    """The rosbag2 directory for ``path`` (a directory, or a file inside one)."""
    p = bag_exists(path)
    if p.is_file():
        if p.suffix == ".bag":
            raise BagError(f"ROS 1 bag (convert it to rosbag2 with rosbags-convert first): {p}")
        if (p.parent / "metadata.yaml").is_file():
            p = p.parent
        else:
            raise BagError(f"not a rosbag2 bag (no metadata.yaml next to it): {p}")
    if not (p / "metadata.yaml").is_file():
        raise BagError(f"not a rosbag2 bag (no metadata.yaml): {p}")
    return p


def _one_line(err: BaseException) -> str:
    text = " ".join(str(err).split()) or type(err).__name__
    return text if len(text) <= 300 else text[:297] + "..."


@contextmanager
def open_bag(path: str | os.PathLike) -> Iterator[AnyReader]:
    """Open a bag (rosbag2 mcap or sqlite3) with ``AnyReader``; every failure is a BagError."""
    p = _resolve(path)
    try:
        reader = AnyReader([p], default_typestore=typestore())
        reader.open()
    except BagError:
        raise
    except Exception as err:  # rosbags raises many kinds (ReaderError, struct, sqlite, yaml ...)
        raise BagError(f"cannot read bag {p}: {_one_line(err)}") from None
    try:
        yield reader
    except BagError:
        raise
    except (ReaderError, AnyReaderError, OSError, ValueError, KeyError, IndexError) as err:
        raise BagError(f"cannot read bag {p}: {_one_line(err)}") from None
    except Exception as err:  # corrupt chunks surface while iterating
        if type(err).__module__.startswith(("rosbags", "struct", "sqlite3", "zstd", "lz4")):
            raise BagError(f"cannot read bag {p}: {_one_line(err)}") from None
        raise
    finally:
        with suppress(Exception):
            reader.close()


def list_topics(path: str | os.PathLike) -> dict[str, tuple[str, int]]:
    """``{topic: (msgtype, message count)}`` of a bag."""
    with open_bag(path) as reader:
        return {name: (info.msgtype or "", info.msgcount) for name, info in reader.topics.items()}


def _select(reader: AnyReader, topics: Sequence[str] | None, path: Path) -> list:
    available = sorted({c.topic for c in reader.connections})
    if topics is None:
        return list(reader.connections)
    missing = [t for t in topics if t not in available]
    if missing:
        raise BagError(
            f"no topic {', '.join(missing)} in bag {path}; available: {', '.join(available) or '-'}"
        )
    return [c for c in reader.connections if c.topic in set(topics)]


def iter_messages(
    path: str | os.PathLike, topics: Sequence[str] | None = None
) -> Iterator[tuple[Connection, int, bytes]]:
    """Stream ``(connection, log timestamp [ns], raw CDR bytes)`` in log-time order."""
    p = Path(path)
    with open_bag(p) as reader:
        conns = _select(reader, topics, p)
        if not conns:  # AnyReader reads every connection when given none
            return
        for conn, timestamp, raw in reader.messages(connections=conns):
            yield conn, int(timestamp), bytes(raw)


def _stamp_s(stamp) -> float:
    return stamp.sec + 1e-9 * stamp.nanosec


def _assemble(topic: str, msgtype: str, msgs: list, log_ns: list[int]) -> Signal:
    """Per-message rosbags objects of one supported type -> Signal (one pass, then numpy)."""
    rt = np.asarray(log_ns, dtype=np.int64) * 1e-9
    if msgtype == IMU:
        t = np.fromiter((_stamp_s(m.header.stamp) for m in msgs), float, len(msgs))
        v = np.array(
            [
                (
                    m.linear_acceleration.x,
                    m.linear_acceleration.y,
                    m.linear_acceleration.z,
                    m.angular_velocity.x,
                    m.angular_velocity.y,
                    m.angular_velocity.z,
                )
                for m in msgs
            ],
            dtype=np.float64,
        ).reshape(len(msgs), 6)
        return Signal(topic, msgtype, t, v, list(IMU_CHANNELS), rt)
    names: list[str] = []
    if msgtype == SIGNAL_SAMPLE:
        counts = np.fromiter((len(m.values) for m in msgs), np.int64, len(msgs))
        c = int(np.bincount(counts).argmax()) if msgs else 0  # the usual channel count
        ok = counts == c
        names = list(msgs[int(np.argmax(ok))].channel_names) if msgs else []
        t = np.fromiter((_stamp_s(m.header.stamp) for m in msgs), float, len(msgs))
        v = np.full((len(msgs), c), np.nan)
        if ok.any():
            v[ok] = np.stack([m.values for m, g in zip(msgs, ok, strict=True) if g])
        return Signal(topic, msgtype, t, v, names, rt, int((~ok).sum()))
    # SignalBlock
    c = int(msgs[0].channel_count) if msgs else 0
    names = list(msgs[0].channel_names) if msgs else []
    ts, vs, rts, bad = [], [], [], 0
    for m, r in zip(msgs, rt, strict=True):
        n = len(m.data) // c if c else 0
        if int(m.channel_count) != c or c == 0 or len(m.data) != n * c:
            bad += 1
            continue
        ts.append(_stamp_s(m.header.stamp) + m.sample_period * np.arange(n))
        vs.append(np.asarray(m.data, dtype=np.float64).reshape(n, c))
        rts.append(np.full(n, r))
    if not ts:
        return Signal(topic, msgtype, np.zeros(0), np.zeros((0, c)), names, np.zeros(0), bad)
    return Signal(
        topic, msgtype, np.concatenate(ts), np.vstack(vs), names, np.concatenate(rts), bad
    )


def read_signals(path: str | os.PathLike, topics: Sequence[str] | None = None) -> dict[str, Signal]:
    """Read topics of type SignalSample, SignalBlock or sensor_msgs/Imu into arrays.

    ``topics=None`` reads every topic of a supported type (others are skipped); a named topic
    that is missing or of another type raises a BagError.
    """
    p = Path(path)
    with open_bag(p) as reader:
        conns = _select(reader, topics, p)
        if topics is not None:
            for c in conns:
                if c.msgtype not in SIGNAL_TYPES:
                    raise BagError(
                        f"topic {c.topic} has type {c.msgtype}; readable as a signal: "
                        + ", ".join(SIGNAL_TYPES)
                    )
        conns = [c for c in conns if c.msgtype in SIGNAL_TYPES]
        msgs: dict[str, list] = {c.topic: [] for c in conns}
        stamps: dict[str, list[int]] = {c.topic: [] for c in conns}
        types = {c.topic: c.msgtype for c in conns}
        for conn, timestamp, raw in reader.messages(connections=conns) if conns else ():
            try:
                msg = reader.deserialize(raw, conn.msgtype)
            except Exception as err:
                raise BagError(
                    f"cannot decode a {conn.msgtype} message on {conn.topic} in {p}: "
                    f"{_one_line(err)}"
                ) from None
            msgs[conn.topic].append(msg)
            stamps[conn.topic].append(timestamp)
    order = topics if topics is not None else sorted(msgs)
    return {t: _assemble(t, types[t], msgs[t], stamps[t]) for t in order}


# --------------------------------------------------------------------------------------------
# Writing
# --------------------------------------------------------------------------------------------


def make_qos(reliable: bool = True, transient_local: bool = False, depth: int = 10) -> Qos:
    """A rosbags QoS record (what rosbag2 stores as a topic's offered QoS profile)."""
    zero = QosTime(sec=0, nsec=0)
    return Qos(
        history=QosHistory.KEEP_LAST,
        depth=depth,
        reliability=QosReliability.RELIABLE if reliable else QosReliability.BEST_EFFORT,
        durability=QosDurability.TRANSIENT_LOCAL if transient_local else QosDurability.VOLATILE,
        deadline=zero,
        lifespan=zero,
        liveliness=QosLiveliness.AUTOMATIC,
        liveliness_lease_duration=zero,
        avoid_ros_namespace_conventions=False,
    )


#: rosbag2 metadata version written: 8 is the newest that every supported distribution reads.
#: Humble and Iron take ``offered_qos_profiles`` as a YAML *string* whatever the version; Jazzy
#: and later take a string up to version 8 and a list from version 9. A version 8 bag (string
#: profiles with integer policies, ``''`` when none) is therefore read by Humble, Iron, Jazzy,
#: Kilted and Rolling alike (test/test_bag_metadata.py checks every bag against those rules).
BAG_VERSION = 8
#: rosbag2 readers a bag written here is checked against (the packages themselves support Humble,
#: Jazzy and Kilted; Iron is end-of-life but its reader takes the same bags).
BAG_READERS = ("humble", "iron", "jazzy", "kilted", "rolling")


class BagWriter:
    """A rosbag2 writer (rosbags ``Writer``, format version :data:`BAG_VERSION`) with
    sysid_msgs registered.

    Use as a context manager; ``add_topic`` then ``write`` (rosbags message) or ``write_raw``
    (serialized CDR bytes, written as they are). On an exception inside the ``with`` block the
    partial bag is closed so that what was written stays readable.
    """

    def __init__(
        self,
        path: str | os.PathLike,
        storage: str = "mcap",
        version: int = BAG_VERSION,
        compress: bool = False,
    ) -> None:
        if storage not in STORAGES:
            raise BagError(f"unknown storage {storage!r}; use one of {', '.join(STORAGES)}")
        self.path = Path(path)
        if self.path.exists():
            raise BagError(f"output already exists: {self.path}")
        if not self.path.parent.is_dir():
            raise BagError(f"output directory does not exist: {self.path.parent}")
        plugin = StoragePlugin.MCAP if storage == "mcap" else StoragePlugin.SQLITE3
        self._writer = Writer(self.path, version=version, storage_plugin=plugin)
        if compress:
            self._writer.set_compression(CompressionMode.FILE, CompressionFormat.ZSTD)
        self._conns: dict[str, Connection] = {}
        self.counts: dict[str, int] = {}
        self._open = False

    def open(self) -> BagWriter:
        try:
            self._writer.open()
        except Exception as err:
            raise BagError(f"cannot create bag {self.path}: {_one_line(err)}") from None
        self._open = True
        return self

    def __enter__(self) -> BagWriter:
        return self.open()

    def __exit__(self, *exc) -> None:
        self.close()

    def add_topic(self, topic: str, msgtype: str, qos: Sequence[Qos] = ()) -> None:
        """Declare ``topic`` of type ``msgtype`` (e.g. ``sysid_msgs/msg/SignalSample``)."""
        ts = typestore()
        if msgtype not in ts.fielddefs:
            raise BagError(f"unknown message type {msgtype} for topic {topic}")
        self._conns[topic] = self._writer.add_connection(
            topic, msgtype, typestore=ts, offered_qos_profiles=list(qos)
        )
        self.counts[topic] = 0

    def write_raw(self, topic: str, timestamp_ns: int, data: bytes | memoryview) -> None:
        """Write already serialized CDR bytes of a declared topic at log time ``timestamp_ns``."""
        self._writer.write(self._conns[topic], int(timestamp_ns), data)
        self.counts[topic] += 1

    def write(self, topic: str, timestamp_ns: int, msg: object) -> None:
        """Serialize a rosbags message of a declared topic and write it."""
        conn = self._conns[topic]
        self.write_raw(topic, timestamp_ns, typestore().serialize_cdr(msg, conn.msgtype))

    def close(self) -> None:
        if self._open:
            self._open = False
            self._writer.close()


def write_bag(
    path: str | os.PathLike,
    topics_messages: Mapping[str, tuple[str, Iterable[tuple[int, object]]]],
    storage: str = "mcap",
    compress: bool = False,
    qos: Mapping[str, Sequence[Qos]] | None = None,
) -> Path:
    """Write ``{topic: (msgtype, [(log timestamp ns, rosbags message), ...])}`` to a new bag.

    Messages of all topics are written in log-time order (ties keep the topic order).
    ``qos`` optionally gives a topic's offered QoS profiles (see ``make_qos``).
    """
    with BagWriter(path, storage=storage, compress=compress) as bag:
        queue: list[tuple[int, int, int, object]] = []
        for k, (topic, (msgtype, items)) in enumerate(topics_messages.items()):
            bag.add_topic(topic, msgtype, qos=(qos or {}).get(topic, ()))
            queue.extend((int(ts), k, i, m) for i, (ts, m) in enumerate(items))
        names = list(topics_messages)
        queue.sort(key=lambda q: (q[0], q[1], q[2]))
        for ts, k, _, msg in queue:
            bag.write(names[k], ts, msg)
    return Path(path)


def stamp_msg(t: float) -> object:
    """A ``builtin_interfaces/Time`` (rosbags) for ``t`` seconds."""
    ns = int(round(t * 1e9))
    time_cls = typestore().types["builtin_interfaces/msg/Time"]
    return time_cls(sec=ns // 1_000_000_000, nanosec=ns % 1_000_000_000)


def signal_samples(
    t: np.ndarray, values: np.ndarray, channel_names: Sequence[str] = (), frame_id: str = ""
) -> list[tuple[int, object]]:
    """``(log timestamp ns, SignalSample)`` per row of ``values`` (N, c) at times ``t`` [s]."""
    ts = typestore()
    header_cls = ts.types["std_msgs/msg/Header"]
    sample_cls = ts.types[SIGNAL_SAMPLE]
    vals = np.ascontiguousarray(np.asarray(values, dtype=np.float64).reshape(len(t), -1))
    names = [str(n) for n in channel_names]
    ns = np.round(np.asarray(t, dtype=np.float64) * 1e9).astype(np.int64)
    out = []
    time_cls = ts.types["builtin_interfaces/msg/Time"]
    for k in range(len(ns)):
        n = int(ns[k])
        stamp = time_cls(sec=n // 1_000_000_000, nanosec=n % 1_000_000_000)
        msg = sample_cls(
            header=header_cls(stamp=stamp, frame_id=frame_id),
            values=vals[k].copy(),
            channel_names=names,
        )
        out.append((n, msg))
    return out


def write_signals(
    path: str | os.PathLike,
    signals: Mapping[str, tuple[np.ndarray, np.ndarray, Sequence[str]]],
    storage: str = "mcap",
    compress: bool = False,
) -> Path:
    """Write ``{topic: (t [s] (N,), values (N, c), channel_names)}`` as SignalSample topics."""
    return write_bag(
        path,
        {
            topic: (SIGNAL_SAMPLE, signal_samples(t, v, names))
            for topic, (t, v, names) in signals.items()
        },
        storage=storage,
        compress=compress,
    )
