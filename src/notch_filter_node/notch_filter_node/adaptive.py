"""The adaptive notch filter (pure): a :class:`RetuningPolicy` driving a :class:`NotchBank`.

This is what the node runs and what the tests and the benchmark exercise: feed estimates with
:meth:`AdaptiveNotchFilter.set_estimate`, blocks of samples with :meth:`process`.
"""

from __future__ import annotations

import numpy as np

from notch_filter_node.policy import EstimateInput, PolicyConfig, PolicyStatus, RetuningPolicy
from notch_filter_node.sections import NotchBank


class AdaptiveNotchFilter:
    """Notch bank on ``channels`` channels sampled at ``fs`` [Hz], retuned by the policy.

    ``enabled`` (bool per channel) selects the channels that are filtered; the others pass
    through unchanged (their filter memory is kept up to date all the same)."""

    def __init__(
        self, config: PolicyConfig, fs: float, channels: int, substep: int = 8
    ) -> None:
        self.fs = float(fs)
        self.policy = RetuningPolicy(config, fs)
        self.bank = NotchBank(fs, channels, config.max_notches + 1, substep)
        self.bank.params = self.policy.params()
        self.enabled = np.ones(channels, dtype=bool)

    @property
    def channels(self) -> int:
        return self.bank.channels

    def set_estimate(self, est: EstimateInput) -> None:
        self.policy.set_estimate(est)

    def reconfigure(self, config: PolicyConfig) -> None:
        self.policy.reconfigure(config)

    def process(self, x: np.ndarray, t_last: float) -> np.ndarray:
        """Filter ``x`` ``(samples, channels)`` whose last sample was taken at ``t_last`` [s]."""
        x = np.asarray(x, dtype=float)
        params = self.policy.advance(t_last, x.shape[0] / self.fs)
        y = self.bank.process(x, params)
        if not self.enabled.all():
            y[:, ~self.enabled] = x[:, ~self.enabled]
        return y

    def status(self) -> PolicyStatus:
        return self.policy.status()
