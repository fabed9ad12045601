"""Plain data passed between the modules (pure, no rclpy, no numerics): the estimate records
the pipeline makes and ``msg_convert`` turns into messages, and blocks of stamped samples.

Dependencies run one way: ``pipeline`` -> ``records`` <- ``msg_convert``; ``pipeline`` never
imports ``msg_convert``.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np

STATUS_NAMES = ("tentative", "tracked", "lost")


@dataclass
class ModeRecord:
    """One mode of an estimate (NaN = unknown); ``shape`` is complex over output channels."""

    id: int
    status: str
    frequency_hz: float
    frequency_std_hz: float
    damping_ratio: float
    damping_std: float
    amplitude: float
    age_s: float
    shape: np.ndarray


@dataclass
class SpectrumRecord:
    """Amplitude spectral density of the one-step prediction residual of one output channel
    (sysid_msgs/ResidualSpectrum), and the level a white residual would have."""

    stamp_ns: int
    channel_name: str
    frequency: np.ndarray  # [Hz]
    magnitude: np.ndarray  # [output unit / sqrt(Hz)]
    noise_floor: np.ndarray  # [output unit / sqrt(Hz)]


@dataclass
class EstimateRecord:
    """The modal content identified at one instant (``stamp_ns``: time of the last sample used)."""

    stamp_ns: int
    modes: list[ModeRecord]
    model_order: int
    block_rows: int
    forgetting_factor: float
    sample_rate: float
    prediction_error_rms_per_channel: np.ndarray
    converged: bool
    samples_used: int
    counters: dict[str, int] = field(default_factory=dict)
    health: int = 0  # sysid_msgs/ModalEstimate HEALTH_*: 0 ok, 1 degraded, 2 fault
    health_reason: str = ""
    band_min_hz: float = math.nan
    band_max_hz: float = math.nan
    scheduling_value: float = math.nan
    predicted_modes: list[ModeRecord] = field(default_factory=list)

    @property
    def prediction_error_rms(self) -> float:
        """RMS over the output channels, NaN while unknown."""
        e = np.asarray(self.prediction_error_rms_per_channel, dtype=float)
        return float(np.sqrt(np.mean(e**2))) if e.size else math.nan

    def to_dict(self) -> dict[str, Any]:
        """Plain JSON-serialisable form (shapes as magnitude and phase lists)."""
        d = asdict(self)
        d["stamp"] = self.stamp_ns * 1e-9
        d["prediction_error_rms"] = self.prediction_error_rms
        d["prediction_error_rms_per_channel"] = [
            float(x) for x in self.prediction_error_rms_per_channel
        ]
        for key in ("modes", "predicted_modes"):
            d[key] = []
            for m in getattr(self, key):
                md = {k: v for k, v in asdict(m).items() if k != "shape"}
                md["shape_magnitude"] = [float(x) for x in np.abs(m.shape)]
                md["shape_phase"] = [float(x) for x in np.angle(m.shape)]
                d[key].append(md)
        return d


# ---- blocks of stamped samples ----
def stack_blocks(
    blocks: Iterable[tuple[np.ndarray, np.ndarray]],
) -> list[tuple[np.ndarray, np.ndarray]]:
    """Concatenate consecutive blocks with the same channel count (arrival order is kept), so
    that many one-sample messages become one block for the vectorised ingest."""
    out: list[tuple[np.ndarray, np.ndarray]] = []
    run_t: list[np.ndarray] = []
    run_v: list[np.ndarray] = []
    width = None
    for t, v in blocks:
        if width is not None and v.shape[1] != width:
            out.append((np.concatenate(run_t), np.concatenate(run_v)))
            run_t, run_v = [], []
        width = v.shape[1]
        run_t.append(t)
        run_v.append(v)
    if run_t:
        out.append((np.concatenate(run_t), np.concatenate(run_v)))
    return out
