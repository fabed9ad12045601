"""The identified model: discrete innovation form, its modes, prediction, simulation, storage."""

from __future__ import annotations

import json
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
from scipy import linalg

from .inputs import InputError, as_2d
from .lti import ContinuousSystem, simulate_discrete
from .modal import ModalParameters

_ARRAYS = (
    "A",
    "B",
    "C",
    "D",
    "K",
    "Q",
    "R",
    "S",
    "innovation_covariance",
    "singular_values",
    "real_poles",
    "input_covariance",
)


@dataclass
class IdentifiedModel:
    """Discrete model x+ = A x + B u + K e, y = C x + D u + e (innovation form, sample rate fs).

    Q, S, R are the (A4) residual covariances of process and measurement noise (physical units),
    ``innovation_covariance`` the covariance of e. ``modes`` are the retained structural modes,
    ``real_poles`` the real continuous poles [1/s]. ``time_s`` is the data time of the
    realization (recursive estimator; NaN for batch).
    """

    A: np.ndarray
    B: np.ndarray
    C: np.ndarray
    D: np.ndarray
    K: np.ndarray
    Q: np.ndarray
    R: np.ndarray
    S: np.ndarray
    innovation_covariance: np.ndarray
    fs: float
    order: int
    singular_values: np.ndarray
    n_inputs: int
    n_outputs: int
    modes: list[ModalParameters] = field(default_factory=list)
    real_poles: np.ndarray = field(default_factory=lambda: np.zeros(0))
    input_covariance: np.ndarray = field(default_factory=lambda: np.zeros((0, 0)))
    time_s: float = float("nan")

    def _u(self, u: np.ndarray | None, n: int) -> np.ndarray:
        if self.n_inputs == 0:
            return np.zeros((n, 0))
        if u is None:
            raise InputError(f"model has {self.n_inputs} input(s): u is required")
        u = as_2d(u, "u", self.n_inputs)
        if u.shape[0] != n:
            raise InputError(f"u has {u.shape[0]} samples, expected {n}")
        return u

    def predict(
        self, y: np.ndarray, u: np.ndarray | None = None, x0: np.ndarray | None = None
    ) -> np.ndarray:
        """One-step-ahead prediction yhat_k = C x_k + D u_k with the Kalman predictor
        x+ = (A - K C) x + (B - K D) u + K y; returns (N, n_outputs)."""
        y = as_2d(y, "y", self.n_outputs)
        u = self._u(u, y.shape[0])
        ak = self.A - self.K @ self.C
        bk = np.hstack([self.B - self.K @ self.D, self.K])
        dk = np.hstack([self.D, np.zeros((self.n_outputs, self.n_outputs))])
        yhat, _ = simulate_discrete(ak, bk, self.C, dk, np.hstack([u, y]), x0)
        return yhat

    def stable_predictor(self) -> IdentifiedModel:
        """This model, or a copy whose Kalman gain K comes from the Riccati equation when the
        stored one (the cheap K = S R^-1 of the recursive realizations) leaves A - K C
        unstable: use it before :meth:`predict` on long records."""
        if self.order == 0 or np.max(np.abs(np.linalg.eigvals(self.A - self.K @ self.C))) < 1.0:
            return self
        from .realization import kalman_gain

        k, re = kalman_gain(self.A, self.C, self.Q, self.S, self.R, riccati=True)
        return replace(self, K=k, innovation_covariance=re)

    def simulate(self, u: np.ndarray, x0: np.ndarray | None = None) -> np.ndarray:
        """Free-run (deterministic part) response to u (N, n_inputs); (N, n_outputs)."""
        u = as_2d(u, "u", self.n_inputs)
        y, _ = simulate_discrete(self.A, self.B, self.C, self.D, u, x0)
        return y

    def to_continuous(self) -> ContinuousSystem:
        """ZOH-equivalent continuous system: [Ac Bc; 0 0] = fs logm([A B; 0 I])."""
        n, m = self.order, self.n_inputs
        big = np.zeros((n + m, n + m))
        big[:n, :n] = self.A
        big[:n, n:] = self.B
        big[n:, n:] = np.eye(m)
        lg = np.real(linalg.logm(big)) * self.fs
        return ContinuousSystem(lg[:n, :n], lg[:n, n:], self.C.copy(), self.D.copy())

    def save(self, path: str | Path) -> None:
        """Store as .npz (matrices plus the modes as JSON)."""
        arrays = {k: np.asarray(getattr(self, k)) for k in _ARRAYS}
        meta = {
            "fs": self.fs,
            "order": self.order,
            "n_inputs": self.n_inputs,
            "n_outputs": self.n_outputs,
            "time_s": self.time_s,
            "modes": [md.to_dict() for md in self.modes],
        }
        with open(path, "wb") as fh:
            np.savez(fh, meta=np.array(json.dumps(meta)), **arrays)

    @classmethod
    def load(cls, path: str | Path) -> IdentifiedModel:
        """Reload a model written by :meth:`save`."""
        try:
            with np.load(path, allow_pickle=False) as z:
                meta = json.loads(str(z["meta"]))
                arrays = {k: np.array(z[k]) for k in _ARRAYS}
        except (OSError, KeyError, ValueError) as exc:
            raise InputError(f"cannot load model from {path}: {exc}") from None
        modes = [ModalParameters.from_dict(d) for d in meta.pop("modes")]
        return cls(modes=modes, **meta, **arrays)
