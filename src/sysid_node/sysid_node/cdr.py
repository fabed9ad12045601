"""Bursts of serialized (CDR) SignalSample / SignalBlock messages -> arrays (pure, no rclpy).

sysid_node takes its data messages serialized (``raw=True`` subscriptions): building one rclpy
message object per sample costs more than everything else the node does with it. A burst of
messages of one topic usually has one byte layout (same frame_id, channel count and channel
names, only stamps and values differ), so it is decoded as one ``(messages, bytes)`` array:
stamps and values are columns of it. :func:`decode_burst` returns None for anything else
(mixed layouts, big-endian data, malformed bytes); the caller then deserializes message by
message and gets the per-message reasons.

Layout (XCDR1, little endian; offsets after the 4-byte encapsulation header, each primitive
aligned to its size): ``int32 sec, uint32 nanosec, string frame_id`` (uint32 length with the
NUL, then the bytes), then SignalSample ``float64[] values`` (uint32 count, doubles aligned to
8), ``string[] channel_names``; SignalBlock ``float64 sample_period, uint32 channel_count,
float64[] data, string[] channel_names``.
"""

from __future__ import annotations

import struct
from collections.abc import Sequence

import numpy as np

#: Encapsulation header of little-endian plain CDR.
CDR_LE = b"\x00\x01\x00\x00"
_BASE = 4  # alignment is relative to the end of the encapsulation header


def _align(offset: int, size: int) -> int:
    """``offset`` (absolute) rounded up to a multiple of ``size`` relative to the data start."""
    d = offset - _BASE
    return _BASE + (d + size - 1) // size * size


class _Layout:
    """Byte offsets of one message; raises ValueError (struct.error) on truncated bytes."""

    def __init__(self, buf: bytes, kind: str) -> None:
        if buf[:4] != CDR_LE:
            raise ValueError("not little-endian CDR")
        (flen,) = struct.unpack_from("<I", buf, _BASE + 8)
        pos = _BASE + 12 + flen
        self.period_at = -1
        self.channels_at = -1
        if kind == "SignalBlock":
            self.period_at = _align(pos, 8)
            self.channels_at = self.period_at + 8
            pos = self.channels_at + 4
        self.count_at = _align(pos, 4)
        (self.count,) = struct.unpack_from("<I", buf, self.count_at)
        self.values_at = _align(self.count_at + 4, 8) if self.count else self.count_at + 4
        self.names_at = self.values_at + 8 * self.count
        self.names, self.names_bytes = _strings(buf, self.names_at)
        self.size = len(buf)


def _strings(buf: bytes, pos: int) -> tuple[tuple[str, ...], np.ndarray]:
    """A ``string[]`` at ``pos``: the strings and the offsets of its meaningful bytes (counts,
    lengths, characters; not the alignment padding, which a serializer may leave unset)."""
    pos = _align(pos, 4)
    (n,) = struct.unpack_from("<I", buf, pos)
    spans = [np.arange(pos, pos + 4)]
    pos += 4
    out = []
    for _ in range(n):
        pos = _align(pos, 4)
        (length,) = struct.unpack_from("<I", buf, pos)
        if length == 0 or pos + 4 + length > len(buf):
            raise ValueError("bad string")
        out.append(buf[pos + 4 : pos + 3 + length].decode("utf-8"))
        spans.append(np.arange(pos, pos + 4 + length))
        pos += 4 + length
    return tuple(out), np.concatenate(spans)


def decode_burst(
    raws: Sequence[bytes], kind: str
) -> tuple[np.ndarray, np.ndarray, tuple[str, ...] | None] | None:
    """Stamps ``(samples,)`` [ns], values ``(samples, channels)`` and channel names (None when
    the messages name none) of a burst of serialized ``kind`` messages of ONE layout, in
    arrival order; None when the burst is not of one layout (or not decodable this way)."""
    if not raws or kind not in ("SignalSample", "SignalBlock"):
        return None
    try:
        lay = _Layout(raws[0], kind)
    except (ValueError, struct.error, UnicodeDecodeError):
        return None
    n, size = len(raws), lay.size
    if any(len(r) != size for r in raws):
        return None
    rows = np.frombuffer(b"".join(raws), dtype=np.uint8).reshape(n, size)
    # same header word, frame_id length, counts and names: the same layout in every message
    fixed = np.r_[0:4, _BASE + 8 : _BASE + 12, lay.count_at : lay.count_at + 4,
                  lay.names_bytes]
    if lay.channels_at >= 0:
        fixed = np.r_[fixed, lay.channels_at : lay.channels_at + 4]
    if not (rows[:, fixed] == rows[0, fixed]).all():
        return None
    head = rows[:, _BASE : _BASE + 8].copy().view("<u4")
    stamps = head[:, 0].view("<i4").astype(np.int64) * 1_000_000_000 + head[:, 1]
    values = rows[:, lay.values_at : lay.names_at].copy().view("<f8").reshape(n, lay.count)
    names = lay.names or None
    if kind == "SignalSample":
        return stamps, values.astype(np.float64), names
    (c,) = struct.unpack_from("<I", raws[0], lay.channels_at)
    if c == 0 or lay.count % c:
        return None  # the per-message path says why
    k = lay.count // c
    period = rows[:, lay.period_at : lay.period_at + 8].copy().view("<f8").reshape(n)
    if not np.isfinite(period).all() or (k > 1 and not (period > 0).all()):
        return None  # the per-message path says why
    offsets = np.round(np.arange(k)[None, :] * (period[:, None] * 1e9))
    stamps = (stamps[:, None] + offsets.astype(np.int64)).reshape(-1)
    return stamps, values.reshape(n * k, c).astype(np.float64), names
