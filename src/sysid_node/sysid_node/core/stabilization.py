"""Stabilization diagram data: modes over a range of model orders from one DSRA projection."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy import linalg

from .batch import model_from_projection
from .hankel import Layout, window_rows
from .inputs import check_rate, validate_batch
from .modal import ModalParameters, mac
from .order import max_order
from .realization import project


@dataclass
class StabilizationPoint:
    """One mode at one model order; ``stable_*`` compare it with the nearest mode of the
    previous order (frequency within ``freq_tol``, damping within ``damping_tol`` relative,
    MAC above ``mac_tol``)."""

    order: int
    mode: ModalParameters
    stable_frequency: bool
    stable_damping: bool
    stable_shape: bool

    @property
    def stable(self) -> bool:
        return self.stable_frequency and self.stable_damping and self.stable_shape


@dataclass
class StabilizationDiagram:
    orders: list[int]
    points: list[StabilizationPoint] = field(default_factory=list)
    singular_values: np.ndarray = field(default_factory=lambda: np.zeros(0))

    def as_arrays(self) -> dict[str, np.ndarray]:
        """Columns order, frequency_hz, damping_ratio, stable (for plots and reports)."""
        return {
            "order": np.array([p.order for p in self.points], dtype=int),
            "frequency_hz": np.array([p.mode.frequency_hz for p in self.points]),
            "damping_ratio": np.array([p.mode.damping_ratio for p in self.points]),
            "stable": np.array([p.stable for p in self.points], dtype=bool),
        }


def stabilization_diagram(
    y: np.ndarray,
    u: np.ndarray | None = None,
    fs: float = 1.0,
    orders: list[int] | range | None = None,
    block_rows: int = 20,
    band: tuple[float, float] | None = None,
    damping_bounds: tuple[float, float] | None = (0.0, 0.5),
    freq_tol: float = 0.01,
    damping_tol: float = 0.05,
    mac_tol: float = 0.98,
) -> StabilizationDiagram:
    """Realize every order in ``orders`` (default 2, 4, .. up to the largest realizable) from
    one projection ((A1)-(A2) and the SVD are done once) and flag stable modes."""
    fs = check_rate(fs)
    y, u = validate_batch(y, u, block_rows)
    su, sy = np.std(u, axis=0), np.std(y, axis=0)
    z = window_rows(u / su, y / sy, block_rows)
    lay = Layout(block_rows, u.shape[1], y.shape[1])
    r_fac = linalg.qr(z, mode="r", check_finite=False)[0]
    proj = project(np.ascontiguousarray(r_fac[: lay.dim].T), lay, z.shape[0], z.shape[0])
    top = max_order(proj)
    orders = list(range(2, top + 1, 2)) if orders is None else [n for n in orders if n <= top]
    diagram = StabilizationDiagram(orders=orders, singular_values=proj.singular_values)
    prev: list[ModalParameters] = []
    for n in orders:
        mdl = model_from_projection(proj, n, fs, su, sy, band, damping_bounds, None)
        for md in mdl.modes:
            sf = sd = ss = False
            if prev:
                j = int(np.argmin([abs(p.frequency_hz - md.frequency_hz) for p in prev]))
                p = prev[j]
                sf = abs(p.frequency_hz - md.frequency_hz) <= freq_tol * md.frequency_hz
                sd = abs(p.damping_ratio - md.damping_ratio) <= damping_tol * max(
                    abs(md.damping_ratio), 1e-3
                )
                ss = mac(p.shape, md.shape) >= mac_tol
            diagram.points.append(StabilizationPoint(n, md, sf, sd, ss))
        prev = mdl.modes
    return diagram
