"""Ground truth of a scenario: the true modes over time.

A :class:`TrueMode` holds knots ``t_s`` [s from the start of the record] with the frequency
[Hz] and damping ratio at each knot, linear in between; the mode exists from ``t_s[0]`` to
``t_s[-1]`` (NaN outside). :meth:`TrueMode.as_dict` is the format of ``bags/<name>.truth.json``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class TrueMode:
    name: str
    kind: str  # "structural" or "rigid_body"
    t_s: tuple[float, ...]
    frequency_hz: tuple[float, ...]
    damping_ratio: tuple[float, ...]

    def __post_init__(self) -> None:
        for name in ("t_s", "frequency_hz", "damping_ratio"):
            object.__setattr__(self, name, tuple(float(x) for x in getattr(self, name)))
        if not len(self.t_s) == len(self.frequency_hz) == len(self.damping_ratio) >= 2:
            raise ValueError("a true mode needs >= 2 knots, as many frequencies and dampings")

    @classmethod
    def constant(cls, name: str, kind: str, frequency_hz: float, damping_ratio: float,
                 start_s: float, end_s: float) -> TrueMode:
        return cls(name, kind, (start_s, end_s), (frequency_hz,) * 2, (damping_ratio,) * 2)

    def at(self, t) -> tuple[np.ndarray, np.ndarray]:
        """(frequency_hz, damping_ratio) at times ``t`` [s]; NaN where the mode does not exist.

        Knots at the same time (an abrupt change) give the value after the change."""
        t = np.asarray(t, dtype=float)
        inside = (t >= self.t_s[0]) & (t <= self.t_s[-1])
        # np.interp takes the last of equal knots from the right: the value after a jump
        f = np.where(inside, np.interp(t, self.t_s, self.frequency_hz), np.nan)
        z = np.where(inside, np.interp(t, self.t_s, self.damping_ratio), np.nan)
        return f, z

    def as_dict(self, digits: int = 6) -> dict:
        return {
            "name": self.name,
            "kind": self.kind,
            "t_s": [round(x, digits) for x in self.t_s],
            "frequency_hz": [round(x, digits) for x in self.frequency_hz],
            "damping_ratio": [round(x, digits) for x in self.damping_ratio],
        }


def modes_at(modes: list[TrueMode], t: float, kind: str | None = None) -> list[tuple[float, float]]:
    """(frequency_hz, damping_ratio) of the modes that exist at time ``t`` [s] (of ``kind``,
    when given), sorted by frequency."""
    out = []
    for m in modes:
        if kind is not None and m.kind != kind:
            continue
        f, z = m.at(t)
        if np.isfinite(f):
            out.append((float(f), float(z)))
    return sorted(out)
