"""Modal structures: continuous LTI systems built from modal data, and their simulation.

A structure is a set of modes (natural frequency f_i [Hz], damping ratio zeta_i), each driven by
the inputs through its row of input gains and seen by the outputs through its column of mode
shapes: q_i'' + 2 zeta_i w_i q_i' + w_i^2 q_i = b_i . u, y = sum_i phi_i q_i^(d) with d = 0, 1
or 2 derivatives (displacement, velocity or acceleration sensors). Output-only (ambient)
records drive the same structure with an unmeasured input. A mode may be marked
``rigid_body``: a low-frequency flight-mechanics response below the structural band that the
notches must leave alone.

Modes are uncoupled, so :meth:`ModalStructure.mode_responses` simulates each mode on its own
(2 states, ``lfilter`` via :func:`sysid_node.core.lti.simulate`) and the output is their sum;
scaling a mode's contribution is then a multiplication.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field, replace

import numpy as np

from ..core.lti import ContinuousSystem, simulate

OUTPUT_KINDS = ("displacement", "velocity", "acceleration")


def modal_system(
    frequencies_hz,
    damping_ratios,
    input_gains,
    shapes,
    output: str = "acceleration",
) -> ContinuousSystem:
    """Modal state-space model, state [q_1, q_1', q_2, q_2', ...].

    ``input_gains`` (modes, inputs) is b_i, ``shapes`` (outputs, modes) is phi_i. Outputs are
    ``displacement`` (C = phi (x) [1, 0]), ``velocity`` (C = phi (x) [0, 1]) or
    ``acceleration`` (C = phi (x) [-w^2, -2 zeta w], D = phi b: the feed-through of the force).
    """
    if output not in OUTPUT_KINDS:
        raise ValueError(f"output must be one of {', '.join(OUTPUT_KINDS)}, got {output!r}")
    w = 2 * np.pi * np.atleast_1d(np.asarray(frequencies_hz, dtype=float))
    z = np.broadcast_to(np.asarray(damping_ratios, dtype=float), w.shape)
    b = np.asarray(input_gains, dtype=float).reshape(w.size, -1)
    phi = np.asarray(shapes, dtype=float).reshape(-1, w.size)
    n = w.size
    a = np.zeros((2 * n, 2 * n))
    bb = np.zeros((2 * n, b.shape[1]))
    c = np.zeros((phi.shape[0], 2 * n))
    idx = 2 * np.arange(n)
    a[idx, idx + 1] = 1.0
    a[idx + 1, idx] = -(w**2)
    a[idx + 1, idx + 1] = -2 * z * w
    bb[idx + 1] = b
    d = np.zeros((phi.shape[0], b.shape[1]))
    if output == "displacement":
        c[:, idx] = phi
    elif output == "velocity":
        c[:, idx + 1] = phi
    else:
        c[:, idx] = -phi * w**2
        c[:, idx + 1] = -phi * 2 * z * w
        d = phi @ b
    return ContinuousSystem(a, bb, c, d)


@dataclass(frozen=True)
class ModalStructure:
    """Modes with their input gains and shapes; ``kinds[i]`` is ``structural`` or ``rigid_body``.

    ``input_gains`` (modes, inputs), ``shapes`` (outputs, modes); ``output`` is the sensor kind
    (see :func:`modal_system`).
    """

    frequencies_hz: np.ndarray
    damping_ratios: np.ndarray
    input_gains: np.ndarray
    shapes: np.ndarray
    output: str = "acceleration"
    kinds: tuple[str, ...] = field(default=())

    def __post_init__(self) -> None:
        f = np.atleast_1d(np.asarray(self.frequencies_hz, dtype=float))
        z = np.broadcast_to(np.asarray(self.damping_ratios, dtype=float), f.shape).copy()
        b = np.asarray(self.input_gains, dtype=float).reshape(f.size, -1)
        phi = np.asarray(self.shapes, dtype=float).reshape(-1, f.size)
        kinds = tuple(self.kinds) or ("structural",) * f.size
        if len(kinds) != f.size:
            raise ValueError(f"{len(kinds)} kinds for {f.size} modes")
        if np.any(f <= 0) or np.any(z < 0):
            raise ValueError("frequencies must be > 0 and damping ratios >= 0")
        for name, value in (("frequencies_hz", f), ("damping_ratios", z), ("input_gains", b),
                            ("shapes", phi), ("kinds", kinds)):
            object.__setattr__(self, name, value)

    @property
    def n_modes(self) -> int:
        return self.frequencies_hz.size

    @property
    def n_inputs(self) -> int:
        return self.input_gains.shape[1]

    @property
    def n_outputs(self) -> int:
        return self.shapes.shape[0]

    def system(self) -> ContinuousSystem:
        """The whole structure as one continuous LTI system."""
        return modal_system(self.frequencies_hz, self.damping_ratios, self.input_gains,
                            self.shapes, self.output)

    def mode_system(self, i: int) -> ContinuousSystem:
        """Mode ``i`` alone (2 states, all inputs and outputs)."""
        return modal_system(self.frequencies_hz[i], self.damping_ratios[i],
                            self.input_gains[i : i + 1], self.shapes[:, i : i + 1], self.output)

    def with_mode(self, i: int, frequency_hz: float | None = None,
                  damping_ratio: float | None = None) -> ModalStructure:
        """A copy with mode ``i`` moved (frequency and/or damping)."""
        f, z = self.frequencies_hz.copy(), self.damping_ratios.copy()
        if frequency_hz is not None:
            f[i] = frequency_hz
        if damping_ratio is not None:
            z[i] = damping_ratio
        return replace(self, frequencies_hz=f, damping_ratios=z)

    def modes(self) -> list[tuple[float, float]]:
        """``(frequency_hz, damping_ratio)`` per mode, in the structure's order."""
        return [(float(f), float(z)) for f, z in
                zip(self.frequencies_hz, self.damping_ratios, strict=True)]

    def mode_responses(self, u: np.ndarray, fs: float) -> np.ndarray:
        """Each mode's contribution to the outputs, (N, outputs, modes); their sum is the
        structure's response to u (N, inputs) at ``fs`` [Hz] (ZOH, zero initial state)."""
        u = np.asarray(u, dtype=float).reshape(len(u), self.n_inputs)
        out = np.empty((u.shape[0], self.n_outputs, self.n_modes))
        for i in range(self.n_modes):
            out[:, :, i] = simulate(self.mode_system(i), u, fs)
        return out

    def simulate(self, u: np.ndarray, fs: float) -> np.ndarray:
        """Response y (N, outputs) to u (N, inputs) at ``fs`` [Hz]."""
        return self.mode_responses(u, fs).sum(axis=2)


def rigid_body_structure(
    frequency_hz: float = 1.0,
    damping_ratio: float = 0.05,
    input_gains=(1.0,),
    shapes=(1.0,),
    output: str = "acceleration",
) -> ModalStructure:
    """A single low-frequency ``rigid_body`` mode (e.g. a 1 Hz short-period-like response that
    the flight controller needs and the notches must not touch); combine with :func:`combine`."""
    return ModalStructure([frequency_hz], [damping_ratio], np.reshape(input_gains, (1, -1)),
                          np.reshape(shapes, (-1, 1)), output, ("rigid_body",))


def combine(*structures: ModalStructure) -> ModalStructure:
    """The modes of several structures with the same inputs, outputs and sensor kind."""
    first = structures[0]
    if any(s.output != first.output or s.n_inputs != first.n_inputs
           or s.n_outputs != first.n_outputs for s in structures):
        raise ValueError("structures differ in sensor kind, inputs or outputs")
    return ModalStructure(
        np.concatenate([s.frequencies_hz for s in structures]),
        np.concatenate([s.damping_ratios for s in structures]),
        np.vstack([s.input_gains for s in structures]),
        np.hstack([s.shapes for s in structures]),
        first.output,
        tuple(k for s in structures for k in s.kinds),
    )


def scheduled_mode(
    structure: ModalStructure,
    mode: int,
    frequency_of: Callable[[float], float],
    damping_of: Callable[[float], float] | None = None,
) -> Callable[[float], ContinuousSystem]:
    """LPV structure (paper eq. (2)): ``system_at(value)`` with mode ``mode`` at
    ``frequency_of(value)`` [Hz] (and ``damping_of(value)``) of a scheduling value such as
    airspeed or rotor speed; simulate it with ``timevarying.simulate_scheduled``."""

    def system_at(value: float) -> ContinuousSystem:
        z = None if damping_of is None else float(damping_of(value))
        return structure.with_mode(mode, float(frequency_of(value)), z).system()

    return system_at
