"""Contiguous runs of the ingest's grid samples -> :class:`Chunk` objects (pure, no rclpy).

The grid instants the ingest could fill are cut into chunks at every instant it could not;
such a run of missing instants is a gap (counted, the Hankel window restarts) once data
resumes after it, or unaligned start-up data before the first chunk.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sysid_node.ingest_stream import IngestReport


@dataclass
class Chunk:
    """Uniformly sampled data for the estimator.

    ``stamps_ns[k]`` is the time of row ``k`` of ``y`` (outputs) and ``u`` (inputs, None when
    output-only). ``new_segment``: not contiguous with the previous chunk (restart the Hankel
    window). ``reset``: the channel layout or the time line changed (rebuild the estimator).
    """

    stamps_ns: np.ndarray
    y: np.ndarray
    u: np.ndarray | None
    new_segment: bool
    reset: bool = False

    def __len__(self) -> int:
        return len(self.stamps_ns)


class Segments:
    """Segment state of one time line: whether the next chunk continues the previous one,
    whether it must reset the estimator, and the run of missing grid instants."""

    def __init__(self, report: IngestReport, pending_reset: bool) -> None:
        self.report = report
        self.open = False
        self.pending_reset = pending_reset
        self.emitted_any = False
        self.gap_run = 0

    def restart(self) -> None:
        """The next chunk starts a new segment and resets the estimator (mode change)."""
        self.pending_reset = True
        self.open = False

    def missing(self, n: int) -> None:
        """``n`` grid instants without usable data (counted as a gap when data resumes)."""
        self.gap_run += max(0, int(n))

    def _close_gap(self, period: float) -> None:
        n, self.gap_run = self.gap_run, 0
        if n <= 0:
            return
        counters = self.report.counters
        if self.emitted_any:
            counters["gaps"] += 1
            counters["gap_samples"] += n
            self.report.event(f"gap of {n * period:.3f} s ({n} samples): Hankel window "
                              "restarted")
            self.open = False
        else:
            counters["unaligned_start_samples"] += n

    def split(self, g: np.ndarray, valid: np.ndarray, vals: list[np.ndarray],
              origin_ns: int, period: float) -> list[Chunk]:
        """Chunks of the runs of ``valid`` grid instants (times ``g`` [s after
        ``origin_ns``]; ``vals``: output values, then input values when input-output)."""
        chunks: list[Chunk] = []
        if not len(g):
            return chunks
        edges = np.flatnonzero(np.diff(np.concatenate(([0], valid.astype(np.int8), [0]))))
        starts, ends = edges[::2], edges[1::2]
        pos = 0
        for a, b in zip(starts, ends, strict=True):
            self.missing(a - pos)
            self._close_gap(period)
            pos = b
            stamps = origin_ns + np.round(g[a:b] * 1e9).astype(np.int64)
            chunks.append(
                Chunk(
                    stamps_ns=stamps,
                    y=vals[0][a:b],
                    u=vals[1][a:b] if len(vals) > 1 else None,
                    new_segment=not self.open,
                    reset=self.pending_reset,
                )
            )
            self.pending_reset = False
            self.open = True
            self.emitted_any = True
        self.missing(len(g) - pos)
        return chunks
