"""Messages <-> arrays, for rclpy messages and ``rosbags`` dataclasses alike.

Reading works by duck typing on the field names, so the same function converts an rclpy message
received by a node and a ``rosbags`` message read from a bag. Nothing here imports rclpy at module
level: the rclpy message classes are imported only by the ``*_msg`` builders that need them.

Stamps are integer nanoseconds since the epoch (or sim time); values are ``(samples, channels)``
float64 arrays; NaN marks unknown values.
"""

from __future__ import annotations

import array
import math
from collections.abc import Sequence
from typing import Any

import numpy as np

from sysid_node.records import EstimateRecord, ModeRecord, SpectrumRecord, stack_blocks

STATUS_CODES = {"tentative": 0, "tracked": 1, "lost": 2}
IMU_FIELDS = {
    "ax": ("linear_acceleration", "x"),
    "ay": ("linear_acceleration", "y"),
    "az": ("linear_acceleration", "z"),
    "wx": ("angular_velocity", "x"),
    "wy": ("angular_velocity", "y"),
    "wz": ("angular_velocity", "z"),
}


# ---- stamps ----
def stamp_ns(header: Any) -> int:
    """``header.stamp`` as integer nanoseconds."""
    return int(header.stamp.sec) * 1_000_000_000 + int(header.stamp.nanosec)


def split_ns(ns: int) -> tuple[int, int]:
    """Nanoseconds -> (sec, nanosec)."""
    return int(ns // 1_000_000_000), int(ns % 1_000_000_000)


# ---- signals in ----
def signal_sample_to_arrays(msg: Any) -> tuple[np.ndarray, np.ndarray]:
    """SignalSample -> stamps ``(1,)`` [ns], values ``(1, channels)``."""
    v = np.asarray(msg.values, dtype=float).reshape(1, -1)
    return np.array([stamp_ns(msg.header)], dtype=np.int64), v


def signal_block_to_arrays(msg: Any) -> tuple[np.ndarray, np.ndarray]:
    """SignalBlock (row-major samples x channels) -> stamps ``(n,)`` [ns], values ``(n, c)``.

    A block whose data length is not a multiple of ``channel_count`` comes back with the values
    as one row of all the data, which the ingest rejects as a wrong channel count."""
    data = np.asarray(msg.data, dtype=float)
    c = int(msg.channel_count)
    if c <= 0 or data.size % c:
        return np.array([stamp_ns(msg.header)], dtype=np.int64), data.reshape(1, -1)
    n = data.size // c
    period_ns = float(msg.sample_period) * 1e9
    if not math.isfinite(period_ns) or (n > 1 and period_ns <= 0):
        raise ValueError(f"SignalBlock of {n} samples with sample_period {msg.sample_period!r} "
                         "(not a positive finite number): dropped")
    stamps = stamp_ns(msg.header) + np.round(np.arange(n) * period_ns).astype(np.int64)
    return stamps, data.reshape(n, c)


def imu_to_arrays(msg: Any, axes: Sequence[str]) -> tuple[np.ndarray, np.ndarray]:
    """sensor_msgs/Imu -> stamps ``(1,)`` [ns], values ``(1, len(axes))`` (axes e.g. ['az'])."""
    vals = [float(getattr(getattr(msg, IMU_FIELDS[a][0]), IMU_FIELDS[a][1])) for a in axes]
    return np.array([stamp_ns(msg.header)], dtype=np.int64), np.array([vals])


def to_arrays(msg: Any, kind: str, axes: Sequence[str] = ("az",)) -> tuple[np.ndarray, np.ndarray]:
    """Any supported signal message (``kind`` = SignalSample, SignalBlock or Imu) -> arrays."""
    if kind == "SignalSample":
        return signal_sample_to_arrays(msg)
    if kind == "SignalBlock":
        return signal_block_to_arrays(msg)
    if kind == "Imu":
        return imu_to_arrays(msg, axes)
    raise ValueError(f"unsupported signal type '{kind}'")


def channel_names(msg: Any, kind: str, axes: Sequence[str] = ("az",)) -> list[str]:
    """Channel names a signal message carries (``channel_names`` of SignalSample/SignalBlock,
    the IMU axes read, e.g. ``['az']``); empty when the message names none."""
    if kind == "Imu":
        return list(axes)
    return [str(n) for n in getattr(msg, "channel_names", ())]


def _names(msg: Any, kind: str, axes: Sequence[str]) -> tuple[str, ...] | None:
    return tuple(channel_names(msg, kind, axes)) or None


def signal_samples_to_arrays(msgs: Sequence[Any]) -> tuple[np.ndarray, np.ndarray]:
    """Many SignalSample messages of one channel count -> stamps ``(n,)`` [ns], values
    ``(n, channels)``, without a Python loop over the values (ValueError if the counts
    differ)."""
    n = len(msgs)
    stamps = np.fromiter(
        (m.header.stamp.sec * 1_000_000_000 + m.header.stamp.nanosec for m in msgs),
        dtype=np.int64, count=n)
    width = len(msgs[0].values)
    if any(len(m.values) != width for m in msgs):
        raise ValueError("channel counts differ")
    if width == 0:
        return stamps, np.empty((n, 0))
    data = b"".join(memoryview(m.values).cast("B") if isinstance(m.values, array.array)
                    else np.asarray(m.values, dtype=np.float64).tobytes() for m in msgs)
    return stamps, np.frombuffer(data, dtype=np.float64).reshape(n, width).copy()


def burst_to_blocks(
    msgs: Sequence[Any], kind: str, axes: Sequence[str] = ("az",)
) -> tuple[list[tuple[np.ndarray, np.ndarray, tuple[str, ...] | None]], list[str]]:
    """A burst of messages of one topic -> blocks ``(stamps, values, channel names)``
    (consecutive messages of equal channel count and names stacked) and one reason per
    unreadable message."""
    if kind == "SignalSample" and msgs:
        names = _names(msgs[0], kind, axes)
        try:
            if all(_names(m, kind, axes) == names for m in msgs):
                t, v = signal_samples_to_arrays(msgs)
                return [(t, v, names)], []
        except (ValueError, TypeError, AttributeError):
            pass  # mixed channel counts or a malformed message: one at a time below
    blocks, errors = [], []
    for m in msgs:
        try:
            t, v = to_arrays(m, kind, axes)
        except (ValueError, TypeError, AttributeError) as err:
            errors.append(str(err))
            continue
        blocks.append((t, v, _names(m, kind, axes)))
    return stack_named(blocks), errors


def signal_msg_class(kind: str):
    """The rclpy message class of a signal ``kind`` (SignalSample, SignalBlock or Imu)."""
    if kind == "Imu":
        from sensor_msgs.msg import Imu

        return Imu
    if kind not in ("SignalSample", "SignalBlock"):
        raise ValueError(f"unsupported signal type '{kind}'")
    from sysid_msgs import msg

    return getattr(msg, kind)


def serialized_burst_to_blocks(
    raws: Sequence[bytes], kind: str, axes: Sequence[str] = ("az",)
) -> tuple[list[tuple[np.ndarray, np.ndarray, tuple[str, ...] | None]], list[str]]:
    """:func:`burst_to_blocks` of serialized messages (as a ``raw=True`` subscription takes
    them): a burst of one byte layout decoded as one array (:mod:`sysid_node.cdr`), any other
    deserialized message by message with rclpy (one reason per unreadable message)."""
    from sysid_node import cdr

    fast = cdr.decode_burst(raws, kind)
    if fast is not None:
        return [fast], []
    from rclpy.serialization import deserialize_message

    cls = signal_msg_class(kind)
    msgs, errors = [], []
    for raw in raws:
        try:
            msgs.append(deserialize_message(raw, cls))
        except Exception as err:  # truncated or garbled bytes
            errors.append(f"cannot deserialize {kind}: {err}")
    blocks, bad = burst_to_blocks(msgs, kind, axes)
    return blocks, errors + bad


def stack_named(blocks: Sequence[tuple]) -> list[tuple[np.ndarray, np.ndarray, Any]]:
    """Blocks ``(stamps, values, channel names)``: consecutive ones with the same names and
    channel count concatenated (arrival order kept)."""
    runs: list[tuple[Any, list]] = []
    for t, v, names in blocks:
        if not runs or runs[-1][0] != names:
            runs.append((names, []))
        runs[-1][1].append((t, v))
    return [(t, v, names) for names, run in runs for t, v in stack_blocks(run)]


# ---- signals out (rclpy) ----
def _f64(values: np.ndarray) -> array.array:
    return array.array("d", np.ascontiguousarray(values, dtype=np.float64).tobytes())


def signal_sample_msg(ns: int, values: np.ndarray, channel_names: Sequence[str] = ()):
    """rclpy ``sysid_msgs/SignalSample`` from a stamp [ns] and one row of values."""
    from sysid_msgs.msg import SignalSample

    msg = SignalSample()
    msg.header.stamp.sec, msg.header.stamp.nanosec = split_ns(ns)
    msg.values = _f64(np.asarray(values).reshape(-1))
    msg.channel_names = list(channel_names)
    return msg


def signal_block_msg(
    ns: int, period: float, values: np.ndarray, channel_names: Sequence[str] = ()
):
    """rclpy ``sysid_msgs/SignalBlock`` from the first stamp [ns], the period [s] and
    ``(n, channels)`` values."""
    from sysid_msgs.msg import SignalBlock

    values = np.atleast_2d(np.asarray(values, dtype=float))
    msg = SignalBlock()
    msg.header.stamp.sec, msg.header.stamp.nanosec = split_ns(ns)
    msg.sample_period = float(period)
    msg.channel_count = values.shape[1]
    msg.data = _f64(values.reshape(-1))
    msg.channel_names = list(channel_names)
    return msg


# ---- estimates ----
def _shape_fields(shape: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Complex shape -> magnitude normalised to max 1, phase relative to the largest entry."""
    shape = np.asarray(shape, dtype=complex).reshape(-1)
    if shape.size == 0 or not np.isfinite(shape).all():
        return np.full(shape.size, np.nan), np.full(shape.size, np.nan)
    k = int(np.argmax(np.abs(shape)))
    ref = shape[k]
    if abs(ref) == 0:
        return np.zeros(shape.size), np.zeros(shape.size)
    rel = shape / ref
    return np.abs(shape) / abs(ref), np.angle(rel)


def mode_fields(m: ModeRecord) -> dict[str, Any]:
    """Field values of ``sysid_msgs/Mode`` for a mode record."""
    mag, ph = _shape_fields(m.shape)
    return dict(
        id=int(m.id),
        status=STATUS_CODES.get(m.status, 0),
        frequency=float(m.frequency_hz),
        frequency_std=float(m.frequency_std_hz),
        damping_ratio=float(m.damping_ratio),
        damping_ratio_std=float(m.damping_std),
        amplitude=float(m.amplitude),
        age=float(m.age_s),
        shape_magnitude=mag.astype(np.float64),
        shape_phase=ph.astype(np.float64),
    )


def estimate_fields(r: EstimateRecord) -> dict[str, Any]:
    """Field values of ``sysid_msgs/ModalEstimate`` (without header and modes)."""
    return dict(
        model_order=int(r.model_order),
        block_rows=int(r.block_rows),
        forgetting_factor=float(r.forgetting_factor),
        sample_rate=float(r.sample_rate),
        prediction_error_rms=float(r.prediction_error_rms),
        prediction_error_rms_per_channel=np.asarray(
            r.prediction_error_rms_per_channel, dtype=np.float64
        ).reshape(-1),
        converged=bool(r.converged),
        samples_used=int(r.samples_used),
        health=int(r.health),
        health_reason=str(r.health_reason),
        band_min=float(r.band_min_hz),
        band_max=float(r.band_max_hz),
        scheduling_value=float(r.scheduling_value),
    )


def residual_spectrum_msg(r: SpectrumRecord, frame_id: str = ""):
    """rclpy ``sysid_msgs/ResidualSpectrum`` from a pipeline spectrum record."""
    from sysid_msgs.msg import ResidualSpectrum

    msg = ResidualSpectrum()
    msg.header.stamp.sec, msg.header.stamp.nanosec = split_ns(r.stamp_ns)
    msg.header.frame_id = frame_id
    msg.channel_name = r.channel_name
    msg.frequency = _f64(r.frequency)
    msg.magnitude = _f64(r.magnitude)
    msg.noise_floor = _f64(r.noise_floor)
    return msg


def estimate_msg(r: EstimateRecord, frame_id: str = ""):
    """rclpy ``sysid_msgs/ModalEstimate`` stamped with the last sample used."""
    from sysid_msgs.msg import ModalEstimate, Mode

    msg = ModalEstimate()
    msg.header.stamp.sec, msg.header.stamp.nanosec = split_ns(r.stamp_ns)
    msg.header.frame_id = frame_id
    for k, v in estimate_fields(r).items():
        setattr(msg, k, _f64(v) if isinstance(v, np.ndarray) else v)
    for key in ("modes", "predicted_modes"):
        modes = []
        for m in getattr(r, key):
            mm = Mode()
            for k, v in mode_fields(m).items():
                setattr(mm, k, _f64(v) if isinstance(v, np.ndarray) else v)
            modes.append(mm)
        setattr(msg, key, modes)
    return msg


def estimate_rosbags(r: EstimateRecord, typestore: Any, frame_id: str = ""):
    """``rosbags`` dataclass of ``sysid_msgs/msg/ModalEstimate`` (for writing a bag)."""
    ts = typestore.types
    Time, Header = ts["builtin_interfaces/msg/Time"], ts["std_msgs/msg/Header"]
    Mode, Est = ts["sysid_msgs/msg/Mode"], ts["sysid_msgs/msg/ModalEstimate"]
    sec, nsec = split_ns(r.stamp_ns)
    return Est(
        header=Header(stamp=Time(sec=sec, nanosec=nsec), frame_id=frame_id),
        modes=[Mode(**mode_fields(m)) for m in r.modes],
        predicted_modes=[Mode(**mode_fields(m)) for m in r.predicted_modes],
        **estimate_fields(r),
    )


def estimate_from_msg(msg: Any) -> EstimateRecord:
    """``sysid_msgs/ModalEstimate`` (rclpy or rosbags) -> :class:`EstimateRecord`."""
    return EstimateRecord(
        stamp_ns=stamp_ns(msg.header),
        modes=[mode_from_msg(m) for m in msg.modes],
        model_order=int(msg.model_order),
        block_rows=int(msg.block_rows),
        forgetting_factor=float(msg.forgetting_factor),
        sample_rate=float(msg.sample_rate),
        prediction_error_rms_per_channel=np.asarray(
            msg.prediction_error_rms_per_channel, dtype=float
        ),
        converged=bool(msg.converged),
        samples_used=int(msg.samples_used),
        health=int(msg.health),
        health_reason=str(msg.health_reason),
        band_min_hz=float(msg.band_min),
        band_max_hz=float(msg.band_max),
        scheduling_value=float(msg.scheduling_value),
        predicted_modes=[mode_from_msg(m) for m in msg.predicted_modes],
    )


def mode_from_msg(m: Any) -> ModeRecord:
    """``sysid_msgs/Mode`` (rclpy or rosbags) -> :class:`ModeRecord`."""
    names = {v: k for k, v in STATUS_CODES.items()}
    mag = np.asarray(m.shape_magnitude, dtype=float)
    ph = np.asarray(m.shape_phase, dtype=float)
    return ModeRecord(
        id=int(m.id),
        status=names.get(int(m.status), "tentative"),
        frequency_hz=float(m.frequency),
        frequency_std_hz=float(m.frequency_std),
        damping_ratio=float(m.damping_ratio),
        damping_std=float(m.damping_ratio_std),
        amplitude=float(m.amplitude),
        age_s=float(m.age),
        shape=mag * np.exp(1j * ph),
    )
