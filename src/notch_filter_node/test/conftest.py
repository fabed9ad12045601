"""Shared helpers of the notch_filter_node tests: run the pure adaptive filter over a signal."""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np
import pytest
from notch_filter_node.adaptive import AdaptiveNotchFilter
from notch_filter_node.policy import EstimateInput


class Run:
    """Drive filters block by block with estimates delivered at given data times."""

    @staticmethod
    def run(
        filters: Sequence[AdaptiveNotchFilter],
        signals: Sequence[np.ndarray],
        fs: float,
        block: int,
        estimates: Sequence[tuple[float, EstimateInput]] = (),
        on_block: Callable[[float], None] | None = None,
    ) -> list[np.ndarray]:
        """Filter ``signals[i]`` (samples, channels) with ``filters[i]``; each estimate is given
        to every filter before the first block ending at or after its delivery time."""
        n = signals[0].shape[0]
        out = [np.empty_like(s, dtype=float) for s in signals]
        todo = sorted(estimates, key=lambda e: e[0])
        k = 0
        for a in range(0, n, block):
            b = min(a + block, n)
            t_last = (b - 1) / fs
            while k < len(todo) and todo[k][0] <= t_last:
                for f in filters:
                    f.set_estimate(todo[k][1])
                k += 1
            for f, s, o in zip(filters, signals, out, strict=True):
                o[a:b] = f.process(s[a:b], t_last)
            if on_block is not None:
                on_block(t_last)
        return out


@pytest.fixture
def runner() -> type[Run]:
    return Run
