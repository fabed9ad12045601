"""The LPV model (2) of the paper from local models at operating points (Sec. IV).

    dx/dt = A(theta) x + B(theta) u,   y = C(theta) x + D(theta) u,
    A(theta) = beta A_i + (1 - beta) A_{i+1},
    beta = (theta_{i+1} - theta) / (theta_{i+1} - theta_i)

for theta_i <= theta <= theta_{i+1}, and the same for B, C and D (the paper's interpolation).

Interpolating matrices is only meaningful when every local model is written in the same
coordinates: an identified model comes in an arbitrary state basis (any T^-1 A T is as good), and
the average of two models in different bases is not a model of anything. Each local model is
therefore brought to one **real modal basis, consistently ordered and normalised**:

* continuous time (zero-order-hold inverse of the identified discrete model);
* one 2x2 block ``[[sigma, omega], [-omega, sigma]]`` per complex pole s = sigma + i omega (basis
  [Re v, Im v] of its eigenvector v), then 1x1 blocks for real poles: interpolating the blocks
  interpolates the poles linearly, and A(theta) stays block diagonal, so the predicted modes
  at any theta are read off the blocks;
* mode k at operating point i+1 is the one that continues mode k at point i (assignment on the
  distance of the poles, relative to their size, and the MAC of the output shapes), so a mode
  keeps its block across points even when two modes cross in frequency;
* the eigenvector's complex scale (a free factor per mode) is fixed so that its output shape
  C v has unit norm and the phase closest to the previous point's shape (the first point:
  largest entry real positive); B and C then vary smoothly instead of flipping sign.

File format (:meth:`LpvModel.save`, ``.npz``): arrays ``points`` (P,) [scheduling unit],
``A`` (P, n, n) [1/s], ``B`` (P, n, m), ``C`` (P, l, n), ``D`` (P, l, m), ``kind`` (n,) (0 for
the first state of a complex block, 1 for its second, 2 for a real pole), optionally
``frequency_std`` [Hz] and ``damping_std`` (P, modes) (the identified standard deviations, NaN
unknown) and ``meta`` (JSON:
format "sysid_lpv", version, scheduling name and unit, the basis and the interpolation in words,
number of modes, sample rate of the identification, free text ``source``).
"""

from __future__ import annotations

import json
import zipfile
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from scipy.optimize import linear_sum_assignment

from .inputs import InputError
from .lti import ContinuousSystem
from .modal import mac
from .model import IdentifiedModel

LPV_FORMAT = "sysid_lpv"
LPV_VERSION = 1
_BASIS_TEXT = ("continuous-time real modal form: one block [[sigma, omega], [-omega, sigma]] per "
               "complex pole sigma + i omega (basis [Re v, Im v], C v unit norm, phase continuous "
               "across points), then one 1x1 block per real pole; modes matched across points")
_INTERP_TEXT = ("M(theta) = beta M_i + (1 - beta) M_(i+1), beta = (theta_(i+1) - theta) / "
                "(theta_(i+1) - theta_i) for A, B, C, D (Mehra & Prasanth 2004, Eq. (2)); "
                "outside [points[0], points[-1]] the end model is used")


def interpolation_weights(theta: np.ndarray | float, points: np.ndarray) -> np.ndarray:
    """Weights (T, P) of the paper's linear interpolation (one nonzero pair per row; the end
    points outside the range)."""
    th = np.atleast_1d(np.asarray(theta, dtype=float))
    pts = np.asarray(points, dtype=float)
    w = np.zeros((th.size, pts.size))
    if pts.size == 1:
        w[:, 0] = 1.0
        return w
    t = np.clip(th, pts[0], pts[-1])
    j = np.clip(np.searchsorted(pts, t, side="right") - 1, 0, pts.size - 2)
    beta = (pts[j + 1] - t) / (pts[j + 1] - pts[j])
    rows = np.arange(th.size)
    w[rows, j] = beta
    w[rows, j + 1] += 1.0 - beta
    return w


@dataclass
class _Modal:
    """One local model in modal form: poles (complex then real), eigenvectors and matrices."""

    poles: np.ndarray  # complex poles (Im > 0) then real poles [1/s]
    n_complex: int
    vecs: np.ndarray  # (n, n_poles) eigenvectors (complex)
    system: ContinuousSystem


def _modal(system: ContinuousSystem) -> _Modal:
    lam, v = np.linalg.eig(system.A)
    tol = 1e-9 * np.maximum(1.0, np.abs(lam))
    cplx = np.flatnonzero(lam.imag > tol)
    real = np.flatnonzero(np.abs(lam.imag) <= tol)
    cplx = cplx[np.argsort(np.abs(lam[cplx]))]
    real = real[np.argsort(lam[real].real)]
    idx = np.concatenate([cplx, real])
    return _Modal(lam[idx], cplx.size, v[:, idx], system)


def _match(prev: _Modal, cur: _Modal) -> np.ndarray:
    """Order of cur's poles that continues prev's (complex with complex, real with real)."""
    order = np.empty(prev.poles.size, dtype=int)
    for lo, hi in ((0, prev.n_complex), (prev.n_complex, prev.poles.size)):
        if hi == lo:
            continue
        p, c = prev.poles[lo:hi], cur.poles[lo:hi]
        dist = np.abs(p[:, None] - c[None, :]) / np.maximum(np.abs(p)[:, None], 1e-12)
        sp = prev.system.C @ prev.vecs[:, lo:hi]
        sc = cur.system.C @ cur.vecs[:, lo:hi]
        shape = np.array([[1.0 - mac(sp[:, a], sc[:, b]) for b in range(hi - lo)]
                          for a in range(hi - lo)])
        rows, cols = linear_sum_assignment(dist + 0.05 * shape)
        order[lo + rows] = lo + cols
    return order


def _normalised_basis(md: _Modal, ref_shapes: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
    """Real basis T (n, n) and the output shapes used (l, poles) after scaling each
    eigenvector so that C v has unit norm and the phase closest to ``ref_shapes``."""
    c = md.system.C
    cols, shapes = [], []
    for k in range(md.poles.size):
        v = md.vecs[:, k].astype(complex)
        phi = c @ v
        nrm = np.linalg.norm(phi)
        if nrm <= 1e-300:  # unobservable mode: scale the state vector instead
            nrm, phi = np.linalg.norm(v), v[: c.shape[0]] * 0.0
        v, phi = v / nrm, phi / nrm
        if k < md.n_complex:
            if ref_shapes is None:
                big = phi[np.argmax(np.abs(phi))] if phi.size else 1.0
                rot = np.conj(big) / abs(big) if abs(big) > 0 else 1.0
            else:
                inner = np.vdot(phi, ref_shapes[:, k])  # phi^H ref
                rot = inner / abs(inner) if abs(inner) > 1e-300 else 1.0
            v, phi = v * rot, phi * rot
            cols += [v.real, v.imag]
        else:
            v, phi = v.real, phi.real
            ref = (phi[np.argmax(np.abs(phi))] if ref_shapes is None
                   else float(np.real(ref_shapes[:, k] @ phi)))
            if ref < 0:
                v, phi = -v, -phi
            cols.append(v)
        shapes.append(phi)
    return np.column_stack(cols), np.column_stack(shapes)


def _kinds(n_complex: int, n_real: int) -> np.ndarray:
    return np.concatenate([np.tile([0, 1], n_complex), np.full(n_real, 2)]).astype(int)


@dataclass
class LpvModel:
    """LPV model (2): local continuous models at sorted ``points`` in a common modal basis."""

    points: np.ndarray
    A: np.ndarray  # (P, n, n)
    B: np.ndarray  # (P, n, m)
    C: np.ndarray  # (P, l, n)
    D: np.ndarray  # (P, l, m)
    kind: np.ndarray  # (n,) 0/1 complex block, 2 real
    frequency_std: np.ndarray | None = None  # (P, modes) identified std [Hz], NaN unknown
    damping_std: np.ndarray | None = None  # (P, modes) [-]
    scheduling: str = "theta"
    unit: str = ""
    fs: float = float("nan")  # sample rate of the identification [Hz] (information)
    source: str = ""
    meta: dict = field(default_factory=dict)

    # ------------------------------------------------------------------ construction
    @classmethod
    def from_systems(cls, points, systems: list[ContinuousSystem], **kw) -> LpvModel:
        """From continuous local models at operating points (any state bases, any order of
        the points); every model must have the same numbers of complex and real poles."""
        pts = np.asarray(points, dtype=float)
        if pts.size != len(systems) or pts.size == 0:
            raise InputError("need one local model per operating point, at least one")
        if np.unique(pts).size != pts.size:
            raise InputError("operating points must be distinct")
        order = np.argsort(pts)
        pts = pts[order]
        modal = [_modal(systems[i]) for i in order]
        counts = {(md.n_complex, md.poles.size - md.n_complex) for md in modal}
        if len(counts) != 1:
            raise InputError(
                "local models differ in their numbers of (complex, real) poles: "
                + ", ".join(f"{p:g}: {md.n_complex}/{md.poles.size - md.n_complex}"
                            for p, md in zip(pts, modal, strict=True)))
        mats = []
        shapes = None
        prev = None
        for md in modal:
            if prev is not None:
                perm = _match(prev, md)
                md = _Modal(md.poles[perm], md.n_complex, md.vecs[:, perm], md.system)
            t, shapes = _normalised_basis(md, shapes)
            ti = np.linalg.inv(t)
            s = md.system
            mats.append((ti @ s.A @ t, ti @ s.B, s.C @ t, s.D))
            prev = md
        nc = modal[0].n_complex
        a = np.stack([m[0] for m in mats])
        # exact block structure (rounding of T^-1 A T removed)
        kind = _kinds(nc, modal[0].poles.size - nc)
        a = a * _block_mask(kind)[None]
        return cls(pts, a, np.stack([m[1] for m in mats]), np.stack([m[2] for m in mats]),
                   np.stack([m[3] for m in mats]), kind, **kw)

    @classmethod
    def from_models(cls, points, models: list[IdentifiedModel], **kw) -> LpvModel:
        """From identified discrete models (deterministic part, ZOH inverse to continuous);
        the modes' identified standard deviations are kept per point (NaN where unknown)."""
        kw.setdefault("fs", float(models[0].fs) if models else float("nan"))
        lpv = cls.from_systems(points, [m.to_continuous() for m in models], **kw)
        order = np.argsort(np.asarray(points, dtype=float))
        f_std = np.full((lpv.points.size, lpv.n_modes), np.nan)
        z_std = np.full_like(f_std, np.nan)
        f_p, z_p = lpv.modes(lpv.points)
        for row, i in enumerate(order):
            for k in range(lpv.n_modes):
                cand = [md for md in models[i].modes if np.isfinite(md.frequency_std_hz)]
                if not cand:
                    continue
                md = min(cand, key=lambda x: abs(x.frequency_hz - f_p[row, k])
                         + abs(x.damping_ratio - z_p[row, k]) * f_p[row, k])
                if abs(md.frequency_hz / f_p[row, k] - 1) < 1e-3:
                    f_std[row, k], z_std[row, k] = md.frequency_std_hz, md.damping_std
        lpv.frequency_std, lpv.damping_std = f_std, z_std
        return lpv

    # ------------------------------------------------------------------ evaluation
    @property
    def n_modes(self) -> int:
        return int(np.sum(self.kind == 0))

    def at(self, theta: float) -> ContinuousSystem:
        """The interpolated model at ``theta``."""
        w = interpolation_weights(theta, self.points)[0]
        return ContinuousSystem(*(np.tensordot(w, m, axes=1) for m in
                                  (self.A, self.B, self.C, self.D)))

    def poles(self, theta: np.ndarray | float) -> np.ndarray:
        """Predicted complex poles (T, modes) [1/s], column k = mode k at every theta."""
        w = interpolation_weights(theta, self.points)
        i = np.flatnonzero(self.kind == 0)
        sigma = w @ self.A[:, i, i]
        omega = w @ self.A[:, i, i + 1]
        return sigma + 1j * np.abs(omega)

    def modes(self, theta: np.ndarray | float) -> tuple[np.ndarray, np.ndarray]:
        """Predicted (frequency [Hz], damping ratio) arrays (T, modes) at ``theta``."""
        s = self.poles(theta)
        rad = np.abs(s)
        return rad / (2 * np.pi), -s.real / np.maximum(rad, 1e-300)

    def mode_std(self, theta: float) -> tuple[np.ndarray, np.ndarray]:
        """Interpolated identification standard deviations (frequency [Hz], damping) of the
        modes at ``theta`` (NaN when the local models did not carry them)."""
        if self.frequency_std is None or self.damping_std is None:
            nan = np.full(self.n_modes, np.nan)
            return nan, nan.copy()
        w = interpolation_weights(theta, self.points)[0]
        return w @ self.frequency_std, w @ self.damping_std

    def shapes(self, theta: float) -> np.ndarray:
        """Predicted complex output shapes (l, modes) at ``theta`` (C v, unit norm)."""
        c = self.at(theta).C
        i = np.flatnonzero(self.kind == 0)
        return c[:, i] + 1j * c[:, i + 1]

    # ------------------------------------------------------------------ storage
    def save(self, path: str | Path) -> None:
        """Write the documented .npz format (see the module docstring)."""
        meta = {
            "format": LPV_FORMAT, "version": LPV_VERSION,
            "scheduling": {"name": self.scheduling, "unit": self.unit},
            "time": "continuous", "basis": _BASIS_TEXT, "interpolation": _INTERP_TEXT,
            "n_modes": self.n_modes, "n_real_poles": int(np.sum(self.kind == 2)),
            "fs_identification_hz": self.fs, "source": self.source, **self.meta,
        }
        with open(path, "wb") as fh:
            extra = ({} if self.frequency_std is None else
                     {"frequency_std": self.frequency_std, "damping_std": self.damping_std})
            np.savez(fh, points=self.points, A=self.A, B=self.B, C=self.C, D=self.D,
                     kind=self.kind, meta=np.array(json.dumps(meta)), **extra)

    @classmethod
    def load(cls, path: str | Path) -> LpvModel:
        """Read a file written by :meth:`save`; InputError with a one-line reason otherwise."""
        try:
            with np.load(path, allow_pickle=False) as z:
                meta = json.loads(str(z["meta"]))
                arrays = {k: np.array(z[k]) for k in ("points", "A", "B", "C", "D", "kind")}
                for k in ("frequency_std", "damping_std"):
                    arrays[k] = np.array(z[k]) if k in z.files else None
        except (OSError, KeyError, ValueError, EOFError, zipfile.BadZipFile) as exc:
            raise InputError(f"cannot load LPV model from {path}: "
                             f"{' '.join(str(exc).split()) or type(exc).__name__}") from None
        if meta.get("format") != LPV_FORMAT:
            raise InputError(f"{path} is not an LPV model file (format {meta.get('format')!r})")
        if int(meta.get("version", 0)) > LPV_VERSION:
            raise InputError(f"{path} has LPV format version {meta['version']}, this reads "
                             f"<= {LPV_VERSION}")
        p, n = arrays["points"].size, arrays["kind"].size
        if p == 0 or np.any(np.diff(arrays["points"]) <= 0) or arrays["A"].shape != (p, n, n):
            raise InputError(f"{path}: inconsistent LPV arrays")
        sched = meta.get("scheduling", {})
        known = {"format", "version", "scheduling", "time", "basis", "interpolation", "n_modes",
                 "n_real_poles", "fs_identification_hz", "source"}
        return cls(**arrays, scheduling=str(sched.get("name", "theta")),
                   unit=str(sched.get("unit", "")),
                   fs=float(meta.get("fs_identification_hz", float("nan"))),
                   source=str(meta.get("source", "")),
                   meta={k: v for k, v in meta.items() if k not in known})


def _block_mask(kind: np.ndarray) -> np.ndarray:
    """Ones on the 2x2 complex blocks and the real diagonal, zeros elsewhere."""
    n = kind.size
    mask = np.eye(n)
    i = np.flatnonzero(kind == 0)
    mask[i, i + 1] = mask[i + 1, i] = 1.0
    return mask


def match_modes(estimated: list[tuple[float, float]], truth: list[tuple[float, float]]
                ) -> list[tuple[float, float] | None]:
    """Pair estimated (frequency [Hz], damping) modes with true ones: assignment on the
    distance of the continuous poles relative to the true pole's size. Entry k is the estimate
    matched to truth[k], or None."""
    def pole(f: float, z: float) -> complex:
        return 2 * np.pi * f * complex(-z, np.sqrt(max(1.0 - z * z, 0.0)))

    out: list[tuple[float, float] | None] = [None] * len(truth)
    if not estimated or not truth:
        return out
    pe = np.array([pole(*e) for e in estimated])
    pt = np.array([pole(*t) for t in truth])
    cost = np.abs(pe[:, None] - pt[None, :]) / np.abs(pt)[None, :]
    rows, cols = linear_sum_assignment(cost)
    for a, b in zip(rows, cols, strict=True):
        out[b] = estimated[a]
    return out


def lpv_errors(lpv: LpvModel, truth_at, thetas: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Largest relative frequency error and damping error (absolute) of the LPV-predicted
    modes against ``truth_at(theta) -> [(f, zeta), ...]`` at each theta: arrays (T,)."""
    f_p, z_p = lpv.modes(thetas)
    ef, ez = np.zeros(len(thetas)), np.zeros(len(thetas))
    for i, th in enumerate(thetas):
        tr = truth_at(float(th))
        est = list(zip(f_p[i], z_p[i], strict=True))
        pairs = match_modes(est, tr)
        ef[i] = max(abs(p[0] / t[0] - 1.0) for p, t in zip(pairs, tr, strict=True)
                    if p is not None)
        ez[i] = max(abs(p[1] - t[1]) for p, t in zip(pairs, tr, strict=True) if p is not None)
    return ef, ez


__all__ = ["LpvModel", "interpolation_weights", "lpv_errors", "match_modes"]
