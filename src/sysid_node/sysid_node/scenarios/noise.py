"""Measurement noise added to simulated outputs."""

from __future__ import annotations

import numpy as np


def add_output_noise(
    y: np.ndarray, fraction: float, rng: np.random.Generator, reference: np.ndarray | None = None
) -> np.ndarray:
    """y plus white Gaussian noise whose std is ``fraction`` x each channel's std (0.05 = 5 %)
    of ``reference`` (default: y itself)."""
    y = np.asarray(y, dtype=float)
    std = np.std(y if reference is None else reference, axis=0, keepdims=True)
    return y + fraction * std * rng.standard_normal(y.shape)
