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
        self.bank = NotchBank(fs, channels, self.policy.n_sections, substep)
        self.bank.params = self.policy.params()
        self.enabled = np.ones(channels, dtype=bool)

    @property
    def channels(self) -> int:
        return self.bank.channels

    def set_estimate(self, est: EstimateInput) -> str:
        """Give the policy an estimate; '' when taken, else why it was rejected."""
        return self.policy.set_estimate(est)

    def reconfigure(self, config: PolicyConfig) -> None:
        self.policy.reconfigure(config)

    def process(self, x: np.ndarray, t_last: float, channels: np.ndarray | None = None
                ) -> np.ndarray:
        """Filter ``x`` ``(samples, channels)`` whose last sample was taken at ``t_last`` [s];
        ``channels``: the bank channel of each column (a subset, any order), default all."""
        x = np.asarray(x, dtype=float)
        params = self.policy.advance(t_last, x.shape[0] / self.fs)
        y = self.bank.process(x, params, channels)
        enabled = self.enabled if channels is None else self.enabled[channels]
        if not enabled.all():
            y[:, ~enabled] = x[:, ~enabled]
        return y

    def set_rate(self, fs: float) -> None:
        """The signal's sample rate changed (or was wrong): the sections are re-designed at
        ``fs`` from the same notches in Hz (no fade), the filter memory restarts from the next
        sample's steady state."""
        self.fs = float(fs)
        self.policy.set_rate(fs)
        bank = NotchBank(fs, self.bank.channels, self.bank.n_sections, self.bank.substep)
        bank.params = self.policy.params()
        self.bank = bank

    def relayout(self, kept: np.ndarray) -> None:
        """New channel layout (see :meth:`NotchBank.remap`); the notches stay as they are."""
        kept = np.asarray(kept, dtype=int)
        old = self.enabled
        self.bank.remap(kept)
        self.enabled = np.where(kept >= 0, old[np.maximum(kept, 0)], True)

    def status(self) -> PolicyStatus:
        return self.policy.status()

    def peak_reductions(self) -> tuple[np.ndarray, np.ndarray]:
        """Per active notch: (guaranteed, nominal) peak reduction [dB] of its mode by the bank."""
        return self.policy.peak_reductions()

    def phase_lag(self) -> float:
        """Phase lag [deg] of the whole bank as applied now at the crossover frequency."""
        return self.policy.phase_lag()
