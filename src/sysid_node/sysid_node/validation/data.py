"""Validation data: outputs, inputs and candidate explanatory signals on one time base.

Outputs come from one topic (default ``/vibration``), inputs from another (default
``/excitation``; absent means output-only), and every other numeric topic of the bag becomes a
candidate explanatory signal (a scheduling variable such as ``/airspeed``, a rotating speed such
as ``/rotor_speed``), interpolated onto the output sample times.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..bag_io import BagError, read_signals


class ValidationError(ValueError):
    """Data or options that cannot be validated; ``str(err)`` is a one-line reason."""


@dataclass
class ValidationData:
    """Uniformly sampled record: t (N,), y (N, l), u (N, m) (m = 0 output-only), signals."""

    t: np.ndarray
    y: np.ndarray
    u: np.ndarray
    fs: float
    output_names: list[str] = field(default_factory=list)
    input_names: list[str] = field(default_factory=list)
    signals: dict[str, np.ndarray] = field(default_factory=dict)

    @property
    def n(self) -> int:
        return int(self.y.shape[0])

    @property
    def n_inputs(self) -> int:
        return int(self.u.shape[1])

    @property
    def n_outputs(self) -> int:
        return int(self.y.shape[1])

    def split_index(self, fraction: float, min_samples: int) -> int:
        """Index of the first validation sample; raises ValidationError if a part is too short."""
        if not 0.05 <= fraction <= 0.95:
            raise ValidationError(f"--split must be in [0.05, 0.95], got {fraction}")
        k = int(round(fraction * self.n))
        if k < min_samples or self.n - k < max(50, min_samples // 4):
            raise ValidationError(
                f"record too short to split: {self.n} samples, split {fraction} gives "
                f"{k} for estimation (need {min_samples}) and {self.n - k} for validation "
                f"(need {max(50, min_samples // 4)})"
            )
        return k


def _interp_columns(t_new: np.ndarray, t: np.ndarray, v: np.ndarray) -> np.ndarray:
    order = np.argsort(t, kind="stable")
    t, v = t[order], v[order]
    return np.column_stack([np.interp(t_new, t, v[:, c]) for c in range(v.shape[1])])


def _finite(sig_t: np.ndarray, sig_v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    ok = np.isfinite(sig_t) & np.isfinite(sig_v).all(axis=1)
    return sig_t[ok], sig_v[ok]


def load_bag(
    path: str,
    output_topic: str = "/vibration",
    input_topic: str | None = "/excitation",
    signal_topics: list[str] | None = None,
    input_optional: bool = True,
) -> ValidationData:
    """Read a bag into :class:`ValidationData` (raises BagError / ValidationError).

    ``input_topic`` None or absent from the bag (when ``input_optional``) gives output-only
    data. ``signal_topics`` None uses every other numeric topic as a candidate signal.
    """
    from ..bag_io import list_topics

    topics = list_topics(path)
    if output_topic not in topics:
        raise BagError(
            f"no output topic {output_topic} in bag {path}; available: "
            + (", ".join(sorted(topics)) or "-")
        )
    if input_topic is not None and input_topic not in topics:
        if not input_optional:
            raise BagError(f"no input topic {input_topic} in bag {path}")
        input_topic = None
    for s in signal_topics or []:
        if s not in topics:
            raise BagError(f"no signal topic {s} in bag {path}")
    sigs = read_signals(path, None)  # every readable topic
    if output_topic not in sigs:
        raise BagError(f"topic {output_topic} is of type {topics[output_topic][0]}, not a signal")
    out = sigs[output_topic]
    t, y = _finite(out.t, out.values)
    if t.size < 2:
        raise ValidationError(f"topic {output_topic} has fewer than 2 finite samples")
    dt = np.median(np.diff(t))
    if not dt > 0:
        raise ValidationError(f"topic {output_topic} has no increasing time stamps")
    fs = float(1.0 / dt)
    t0 = t[0]
    if input_topic is not None:
        inp = sigs.get(input_topic)
        if inp is None:
            raise BagError(f"topic {input_topic} is of type {topics[input_topic][0]}, not a signal")
        ti, ui = _finite(inp.t, inp.values)
        if ti.size < 2:
            raise ValidationError(f"topic {input_topic} has fewer than 2 finite samples")
        keep = (t >= ti.min() - 0.5 * dt) & (t <= ti.max() + 0.5 * dt)
        t, y = t[keep], y[keep]
        u = _interp_columns(t, ti, ui)
        in_names = inp.channel_names or [f"{input_topic}[{c}]" for c in range(ui.shape[1])]
    else:
        u = np.zeros((t.size, 0))
        in_names = []
    names = signal_topics if signal_topics is not None else sorted(sigs)
    signals: dict[str, np.ndarray] = {}
    for name in names:
        if name in (output_topic, input_topic) or name not in sigs:
            continue
        s = sigs[name]
        ts, vs = _finite(s.t, s.values)
        if ts.size < 2:
            continue
        v = _interp_columns(t, ts, vs)
        for c in range(v.shape[1]):
            key = name if v.shape[1] == 1 else f"{name}[{c}]"
            signals[key] = v[:, c]
    return ValidationData(
        t - t0,
        y,
        u,
        fs,
        out.channel_names or [f"{output_topic}[{c}]" for c in range(y.shape[1])],
        in_names,
        signals,
    )


def _columns(spec: str | None, names: list[str], flag: str) -> list[int]:
    """Column indices from '0,2' or header names 'V1,V2' ('' or None: none)."""
    if not spec:
        return []
    out = []
    for item in (s.strip() for s in spec.split(",")):
        if item.lstrip("-").isdigit():
            k = int(item)
            if not 0 <= k < len(names):
                raise ValidationError(f"{flag}: no column {k} (the file has {len(names)})")
            out.append(k)
        elif item in names:
            out.append(names.index(item))
        else:
            raise ValidationError(f"{flag}: no column {item!r}; columns: {', '.join(names)}")
    return out


def _read_table(path: str) -> tuple[np.ndarray, list[str]]:
    """(N, c) float table and column names from .npy or delimited text (optional header)."""
    from pathlib import Path

    p = Path(path)
    if not p.is_file():
        raise ValidationError(f"data file {path} not found")
    try:
        if p.suffix == ".npy":
            x = np.load(p, allow_pickle=False)
            x = x[:, None] if x.ndim == 1 else x
            if x.ndim != 2 or not np.issubdtype(x.dtype, np.number):
                raise ValidationError(f"{path}: expected a numeric (N, channels) array")
            return x.astype(float), [str(k) for k in range(x.shape[1])]
        with open(p) as fh:
            first = fh.readline()
            second = fh.readline()
        delim = "," if "," in second else (";" if ";" in second else None)
        fields = [f.strip() for f in (second.split(delim) if delim else second.split())]
        usecols = [k for k, f in enumerate(fields) if f]
        try:
            [float(f) for f in (first.split(delim) if delim else first.split()) if f.strip()]
            header, skip = None, 0
        except ValueError:
            parts = first.split(delim) if delim else first.split()
            header, skip = [f.strip().strip('"').strip("'") for f in parts], 1
        x = np.loadtxt(p, delimiter=delim, skiprows=skip, usecols=usecols, ndmin=2)
    except (OSError, ValueError) as err:
        raise ValidationError(f"cannot read {path}: {' '.join(str(err).split())}") from None
    names = [header[k] if header and k < len(header) and header[k] else str(k) for k in usecols]
    return x, names


def load_arrays(
    path: str,
    rate: float,
    outputs: str | None = None,
    inputs: str | None = None,
    signals: str | None = None,
    rows: str | None = None,
    remove_mean: bool = False,
) -> ValidationData:
    """Plain arrays as validation data: a .npy (N, c) array or a delimited text file (.csv,
    optional header line) sampled at ``rate`` [Hz]. ``outputs`` / ``inputs`` / ``signals`` pick
    columns by index or header name (outputs default: every column that is not an input or a
    signal); ``rows`` 'START:STOP' keeps a slice (0-based, half-open); ``remove_mean``
    subtracts each column's mean (offset errors of the acquisition; it also hides a sensor
    offset from the diagnosis)."""
    if not (np.isfinite(rate) and rate > 0):
        raise ValidationError(f"--rate must be a positive sample rate [Hz], got {rate}")
    x, names = _read_table(path)
    if rows:
        a, sep, b = rows.partition(":")
        try:
            sl = slice(int(a) if a.strip() else None, int(b) if sep and b.strip() else None)
        except ValueError:
            raise ValidationError(f"--rows expects START:STOP, got {rows!r}") from None
        x = x[sl]
    ic = _columns(inputs, names, "--inputs")
    sc = _columns(signals, names, "--signals")
    oc = _columns(outputs, names, "--outputs") or [
        k for k in range(len(names)) if k not in ic and k not in sc
    ]
    if not oc:
        raise ValidationError("no output column (use --outputs)")
    if set(oc) & set(ic):
        raise ValidationError("a column cannot be both an output and an input")
    if x.shape[0] < 2:
        raise ValidationError(f"{path}: fewer than 2 rows")
    if remove_mean:
        x = x - x.mean(axis=0)
    bad = ~np.isfinite(x[:, oc + ic]).all(axis=1)
    if bad.any():
        raise ValidationError(
            f"{path}: {int(bad.sum())} row(s) with NaN/Inf, first at row {int(np.argmax(bad))}"
        )
    t = np.arange(x.shape[0]) / float(rate)
    return ValidationData(
        t,
        x[:, oc],
        x[:, ic] if ic else np.zeros((x.shape[0], 0)),
        float(rate),
        [names[k] for k in oc],
        [names[k] for k in ic],
        {names[k]: x[:, k] for k in sc},
    )
