"""Report building blocks shared by the demo, ``validate`` and ``offline``: one self-contained
HTML page (tables, figures embedded as PNG) and the figures they have in common.

* :class:`Page`: ``heading``, ``text``, ``table`` (header + rows, numbers formatted),
  ``summary`` (a nested dict as a two-column table, never raw JSON), ``figure`` (a matplotlib
  figure, closed after embedding), ``pre``; ``write(path)``.
* :func:`figure`: a matplotlib figure on the Agg backend (no display needed).
* :func:`plot_mode_tracks`: identified modes against time, one colour per mode id; the legend
  lists the modes tracked for a good part of the run only, tentative and lost estimates are
  drawn faint.
* :func:`mode_points`: the points of :func:`plot_mode_tracks` from estimate records
  (``sysid_node.records.EstimateRecord``) or from ``sysid_msgs/ModalEstimate`` messages.

matplotlib is imported on first use, so importing this module costs nothing.
"""

from __future__ import annotations

import base64
import html
import io
import math
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

STATUS_NAMES = {0: "tentative", 1: "tracked", 2: "lost"}
_STYLE = (
    "body{font-family:sans-serif;max-width:1100px;margin:auto;padding:0 1em}"
    "img{max-width:100%}table{border-collapse:collapse;margin:0.5em 0}"
    "td,th{border:1px solid #ccc;padding:3px 6px;font-size:12px;vertical-align:top;"
    "text-align:left}th{background:#f0f0f0}td.num{text-align:right;font-variant-numeric:"
    "tabular-nums}pre{background:#f4f4f4;padding:8px;font-size:12px;overflow-x:auto}"
    "figcaption{font-size:12px;color:#555}"
)


def fmt(value: Any, digits: int = 4) -> str:
    """A cell: floats with ``digits`` significant digits, NaN as '-', lists joined."""
    if isinstance(value, bool) or value is None:
        return "-" if value is None else ("yes" if value else "no")
    if isinstance(value, float | np.floating):
        return "-" if not math.isfinite(value) else f"{value:.{digits}g}"
    if isinstance(value, np.ndarray):
        value = value.tolist()
    if isinstance(value, list | tuple):
        return ", ".join(fmt(v, digits) for v in value)
    return str(value)


def _num(value: Any) -> bool:
    return isinstance(value, int | float | np.number) and not isinstance(value, bool)


class Page:
    """An HTML page built piece by piece; :meth:`write` gives one self-contained file."""

    def __init__(self, title: str) -> None:
        self.title = title
        self.parts: list[str] = [f"<h1>{html.escape(title)}</h1>"]

    def heading(self, text: str, level: int = 2) -> Page:
        self.parts.append(f"<h{level}>{html.escape(text)}</h{level}>")
        return self

    def text(self, text: str) -> Page:
        self.parts.append(f"<p>{html.escape(text)}</p>")
        return self

    def pre(self, text: str) -> Page:
        self.parts.append(f"<pre>{html.escape(text)}</pre>")
        return self

    def table(self, header: Sequence[str], rows: Iterable[Sequence[Any]],
              digits: int = 4) -> Page:
        """A table; numbers right-aligned with ``digits`` significant digits."""
        head = "".join(f"<th>{html.escape(str(h))}</th>" for h in header)
        body = "".join(
            "<tr>" + "".join(
                f"<td{' class=num' if _num(c) else ''}>{html.escape(fmt(c, digits))}</td>"
                for c in row) + "</tr>"
            for row in rows)
        self.parts.append(f"<table><tr>{head}</tr>{body}</table>")
        return self

    def summary(self, values: Mapping[str, Any], digits: int = 4) -> Page:
        """A (nested) mapping as a two-column table: nested keys joined with '.', lists of
        mappings as their own tables below."""
        flat: list[tuple[str, Any]] = []
        lists: list[tuple[str, list]] = []

        def walk(prefix: str, v: Any) -> None:
            if isinstance(v, Mapping):
                for k, x in v.items():
                    walk(f"{prefix}.{k}" if prefix else str(k), x)
            elif isinstance(v, list) and v and all(isinstance(x, Mapping) for x in v):
                lists.append((prefix, v))
            else:
                flat.append((prefix, v))

        walk("", values)
        if flat:
            self.table(["quantity", "value"], flat, digits)
        for name, items in lists:
            keys = list(dict.fromkeys(k for it in items for k in it))
            self.heading(name.replace("_", " "), 3)
            self.table(keys, ([it.get(k) for k in keys] for it in items), digits)
        return self

    def figure(self, fig: Any, caption: str = "", dpi: int = 100) -> Page:
        """Embed a matplotlib figure as PNG and close it."""
        import matplotlib.pyplot as plt

        buf = io.BytesIO()
        fig.savefig(buf, format="png", dpi=dpi, bbox_inches="tight")
        plt.close(fig)
        img = base64.b64encode(buf.getvalue()).decode()
        cap = f"<figcaption>{html.escape(caption)}</figcaption>" if caption else ""
        self.parts.append(f"<figure><img src='data:image/png;base64,{img}'/>{cap}</figure>")
        return self

    def html(self) -> str:
        return ("<!doctype html><html><head><meta charset='utf-8'>"
                f"<title>{html.escape(self.title)}</title><style>{_STYLE}</style></head>"
                f"<body>{''.join(self.parts)}</body></html>")

    def write(self, path: str | Path) -> Path:
        path = Path(path)
        path.write_text(self.html())
        return path


def figure(rows: int = 1, cols: int = 1, width: float = 10.0, height: float = 3.0, **kw: Any):
    """(fig, axes) on the Agg backend; ``axes`` is always a 2-D array (rows, cols)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt.subplots(rows, cols, figsize=(width, height * rows), squeeze=False, **kw)


@dataclass(frozen=True)
class ModePoint:
    """One mode of one estimate: time [s], stable id, status name, frequency [Hz] and its
    standard deviation, damping ratio [-]."""

    t: float
    id: int
    status: str
    frequency_hz: float
    frequency_std_hz: float
    damping_ratio: float


def mode_points(estimates: Iterable[Any], t0_s: float = 0.0) -> list[ModePoint]:
    """Points of estimate records (``stamp_ns``, ``modes`` of ModeRecord) or of
    ``ModalEstimate`` messages (``header.stamp``, ``modes`` of Mode), time from ``t0_s``."""
    out = []
    for e in estimates:
        if hasattr(e, "stamp_ns"):
            t = e.stamp_ns * 1e-9
        else:
            t = e.header.stamp.sec + 1e-9 * e.header.stamp.nanosec
        for m in e.modes:
            status = m.status if isinstance(m.status, str) else STATUS_NAMES.get(
                int(m.status), "tentative")
            f_std = getattr(m, "frequency_std_hz", getattr(m, "frequency_std", math.nan))
            f = getattr(m, "frequency_hz", getattr(m, "frequency", math.nan))
            out.append(ModePoint(t - t0_s, int(m.id), status, float(f), float(f_std),
                                 float(m.damping_ratio)))
    return out


def plot_mode_tracks(ax_f: Any, ax_z: Any | None, points: Sequence[ModePoint],
                     sigma: float = 2.0, truth: Iterable[Any] = (), legend_max: int = 10,
                     legend_share: float = 0.15) -> None:
    """Frequency (with a ``sigma`` band) and, on ``ax_z``, damping [%] of each mode id against
    time. Tracked points are solid, tentative and lost ones faint. The legend names the modes
    tracked in at least ``legend_share`` of the estimates (at most ``legend_max``, the longest
    tracked first). ``truth``: ``scenarios.truth.TrueMode``-like objects (``t_s``,
    ``frequency_hz``, ``damping_ratio``) drawn as dashed black lines on top."""
    from matplotlib import colormaps

    colours = colormaps["tab10"]
    n_estimates = len({p.t for p in points})
    tracked_count: dict[int, int] = {}
    for p in points:
        if p.status == "tracked":
            tracked_count[p.id] = tracked_count.get(p.id, 0) + 1
    named = sorted((i for i, c in tracked_count.items() if c >= legend_share * n_estimates),
                   key=lambda i: -tracked_count[i])[:legend_max]
    ids = named + sorted({p.id for p in points} - set(named))  # distinct colours for the named
    for k, mid in enumerate(ids):
        c = colours(k % 10)
        pts = [p for p in points if p.id == mid]
        for tracked in (False, True):
            sel = [p for p in pts if (p.status == "tracked") == tracked]
            if not sel:
                continue
            t = np.array([p.t for p in sel])
            f = np.array([p.frequency_hz for p in sel])
            s = np.array([p.frequency_std_hz for p in sel])
            z = np.array([p.damping_ratio for p in sel])
            alpha = 1.0 if tracked else 0.15
            label = f"mode #{mid}" if tracked and mid in named else None
            ax_f.plot(t, f, ".", ms=3, color=c, alpha=alpha, label=label)
            ok = np.isfinite(s)
            if tracked and ok.any():
                ax_f.fill_between(t[ok], (f - sigma * s)[ok], (f + sigma * s)[ok], color=c,
                                  alpha=0.15, lw=0)
            if ax_z is not None:
                ax_z.plot(t, 100 * z, ".", ms=3, color=c, alpha=alpha)
    for m in truth:
        ax_f.plot(m.t_s, m.frequency_hz, "k--", lw=1.0, zorder=5)
        if ax_z is not None:
            ax_z.plot(m.t_s, 100 * np.asarray(m.damping_ratio), "k--", lw=1.0, zorder=5)
    ax_f.set_ylabel("frequency [Hz]")
    if named:
        ax_f.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=8, frameon=False)
    if ax_z is not None:
        ax_z.set_ylabel("damping ratio [%]")
        ax_z.set_xlabel("time [s]")
    else:
        ax_f.set_xlabel("time [s]")


def mode_table(points: Sequence[ModePoint]) -> tuple[list[str], list[list[Any]]]:
    """(header, rows) of the last estimate's modes, for :meth:`Page.table`."""
    if not points:
        return ["id"], []
    t_last = max(p.t for p in points)
    rows = [[p.id, p.status, p.frequency_hz, p.frequency_std_hz, 100 * p.damping_ratio]
            for p in points if p.t == t_last]
    return ["id", "status", "frequency [Hz]", "std [Hz]", "damping [%]"], rows
