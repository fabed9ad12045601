"""Analysis and HTML report of a demo run (recorded /modal_estimate, /notch_bank, signals)."""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from rosbags.highlevel import AnyReader
from scipy import signal as sps
from sysid_node.bag_io import read_signals, typestore

MODE_STATUS = {0: "tentative", 1: "tracked", 2: "lost"}
NOTCH_STATE = {0: "tracking", 1: "holding", 2: "parked", 3: "disabled", 4: "predicted"}
BANK_STATE = {0: "tracking", 1: "holding", 2: "predicted", 3: "fallback"}
REQUIRED_DB = 15.0  # the notch node's default peak_reduction


@dataclass
class DemoResult:
    """What the demo measured, in arrays ready for the table and the plots."""

    bag: Path
    t0: float
    estimates: list[dict] = field(default_factory=list)  # t, modes[(id, status, f, fstd, z)]
    banks: list[dict] = field(default_factory=list)  # t, notches[(mode_id, state, fc, bw, depth,
    # shape depth, peak reduction)]: sections
    t_in: np.ndarray | None = None
    y_in: np.ndarray | None = None
    t_out: np.ndarray | None = None
    y_out: np.ndarray | None = None
    truth: dict | None = None

    def table(self, step: float = 2.0) -> str:
        """Modes and notch centres every ``step`` seconds of data time."""
        lines = [f"{'t [s]':>6}  {'modes: id f[Hz] zeta[%] (status)':<58}  "
                 "notch centres [Hz] (p: a pair)"]
        if not self.estimates:
            return "\n".join([*lines, "  (no /modal_estimate received)"])
        t_end = self.estimates[-1]["t"]
        t = step
        while t <= t_end + 1e-9:
            est = _last_before(self.estimates, t)
            bank = _last_before(self.banks, t)
            modes = " ".join(
                f"#{m[0]} {m[2]:.2f} {100 * m[4]:.1f}"
                + ("" if m[1] == 1 else f"({MODE_STATUS[m[1]][0]})")
                for m in (est["modes"] if est else [])
                if m[1] != 2
            )
            notches = " ".join(
                f"{c:.2f}" + ("p" if k > 1 else "") + ("" if st == 0 else f"({NOTCH_STATE[st][0]})")
                for _, st, c, k in notch_groups(bank["notches"] if bank else [])
                if st != 3
            )
            lines.append(f"{t:6.1f}  {modes or '-':<58}  {notches or '-'}")
            t += step
        return "\n".join(lines)

    def peak_reduction(self, settle_s: float = 5.0) -> list[dict]:
        """Per true structural mode (the bag's truth): how far each /notch_bank message's
        sections lower the mode's resonance peak (mode x bank frequency response), over the
        messages from ``settle_s`` after the mode appears (or the first estimate) to the end."""
        if self.truth is None or not self.banks or self.t_in is None:
            return []
        from notch_filter_node import resonance as R

        fs = 1.0 / float(np.median(np.diff(self.t_in)))
        t0 = (self.estimates[0]["t"] if self.estimates else 0.0) + settle_s
        out = []
        for m in self.truth["modes"]:
            if m.get("kind", "structural") != "structural":
                continue
            tk, fk, zk = (np.array(m[k]) for k in ("t_s", "frequency_hz", "damping_ratio"))
            start = max(tk[0] + settle_s, t0)
            banks = [b for b in self.banks if start <= b["t"] <= tk[-1]]
            if not banks:
                continue
            pr = np.array([float(R.peak_reduction_db(
                np.array(np.interp(b["t"], tk, fk)), np.array(np.interp(b["t"], tk, zk)),
                *R.section_damping([n[2] for n in b["notches"]], [n[3] for n in b["notches"]],
                                   [n[4] for n in b["notches"]], fs,
                                   [n[5] for n in b["notches"]]), fs)) for b in banks])
            claimed = [n[6] for b in banks for n in b["notches"]
                       if abs(n[2] / np.interp(b["t"], tk, fk) - 1.0) < 0.1 and n[1] != 2]
            out.append({"mode": m["name"], "frequency_hz": float(fk[-1]),
                        "damping_ratio": float(zk[-1]), "messages": len(banks),
                        "median_db": float(np.median(pr)), "min_db": float(pr.min()),
                        "share_at_least_required": float(np.mean(pr >= REQUIRED_DB)),
                        "claimed_median_db": float(np.nanmedian(claimed)) if claimed
                        else float("nan")})
        return out

    def peak_table(self) -> str:
        """Peak reduction per mode, one line each."""
        rows = self.peak_reduction()
        if not rows:
            return "(no truth or no /notch_bank: peak reduction not measured)"
        lines = [f"{'mode':<10} {'f [Hz]':>7} {'zeta':>6} {'peak reduction median/min [dB]':>32} "
                 f"{f'>= {REQUIRED_DB:g} dB':>9} {'claimed [dB]':>13}"]
        for r in rows:
            lines.append(f"{r['mode']:<10} {r['frequency_hz']:>7.2f} {r['damping_ratio']:>6.3f} "
                         f"{r['median_db']:>20.1f} / {r['min_db']:<9.1f} "
                         f"{100 * r['share_at_least_required']:>8.0f}% "
                         f"{r['claimed_median_db']:>13.1f}")
        states = [b["state"] for b in self.banks]
        lines.append("bank states over the run: " + ", ".join(
            f"{BANK_STATE[k]} {100 * states.count(k) / len(states):.0f}%"
            for k in sorted(set(states))))
        return "\n".join(lines)

    def summary(self) -> dict:
        last = self.estimates[-1] if self.estimates else None
        return {
            "bag": str(self.bag),
            "estimates_received": len(self.estimates),
            "notch_bank_messages": len(self.banks),
            "final_modes": [
                {
                    "id": m[0],
                    "status": MODE_STATUS[m[1]],
                    "frequency_hz": m[2],
                    "frequency_std_hz": m[3],
                    "damping_ratio": m[4],
                }
                for m in (last["modes"] if last else [])
            ],
            "final_notches": [
                {
                    "mode_id": n[0],
                    "state": NOTCH_STATE[n[1]],
                    "centre_hz": n[2],
                    "bandwidth_hz": n[3],
                    "depth_db": n[4],
                }
                for n in (self.banks[-1]["notches"] if self.banks else [])
            ],
            "peak_reduction": self.peak_reduction(),
        }


def notch_groups(notches: list[tuple]) -> list[tuple[int, int, float, int]]:
    """The notches of a /notch_bank message: the sections that follow one mode in one state
    (a pair) as one notch, ``(mode_id, state, centre [Hz], sections)``, its centre the mean of
    its sections' (a pair sits symmetrically about it)."""
    groups: dict = {}
    for i, n in enumerate(notches):
        groups.setdefault((n[0], n[1]) if n[0] else i, []).append(n)
    return [(g[0][0], g[0][1], float(np.mean([n[2] for n in g])), len(g))
            for g in groups.values()]


def _last_before(records: list[dict], t: float) -> dict | None:
    best = None
    for r in records:
        if r["t"] <= t:
            best = r
        else:
            break
    return best


def _stamp(header) -> float:
    return header.stamp.sec + 1e-9 * header.stamp.nanosec


def analyse(bag: Path, recorded: Path, params: Path | None = None) -> DemoResult:
    """Read the input bag and the recording of a demo run (``params``: the notch node's YAML,
    for the depths whose poles its sections keep in recordings without Notch.shape_depth)."""
    values = {"depth": 30.0, "fallback_depth": 30.0}
    if params is not None and params.exists():
        import yaml

        doc = yaml.safe_load(params.read_text()) or {}
        for key, section in doc.items():  # 'notch_filter_node', '/**/notch_filter_node', ...
            if str(key).split("/")[-1] == "notch_filter_node" and isinstance(section, dict):
                values.update(section.get("ros__parameters") or {})
    shape = {0: float(values["depth"]), 2: float(values["fallback_depth"])}
    sig_in = read_signals(bag, ["/vibration"])["/vibration"]
    res = DemoResult(
        bag=bag, t0=float(sig_in.t[0]), t_in=sig_in.t - sig_in.t[0], y_in=sig_in.values
    )
    truth = bag.parent / f"{bag.name}.truth.json"
    if truth.exists():
        res.truth = json.loads(truth.read_text())
    with AnyReader([recorded], default_typestore=typestore()) as reader:
        conns = [c for c in reader.connections if c.topic in ("/modal_estimate", "/notch_bank")]
        for conn, _, raw in reader.messages(connections=conns):
            msg = reader.deserialize(raw, conn.msgtype)
            t = _stamp(msg.header) - res.t0
            if conn.topic == "/modal_estimate":
                modes = [
                    (m.id, m.status, m.frequency, m.frequency_std, m.damping_ratio)
                    for m in msg.modes
                ]
                res.estimates.append({"t": t, "modes": modes, "converged": msg.converged})
            else:
                notches = [
                    (n.mode_id, n.state, n.center_frequency, n.bandwidth, n.depth,
                     getattr(n, "shape_depth", shape.get(n.state, shape[0])), n.peak_reduction)
                    for n in msg.notches
                ]
                res.banks.append({"t": t, "notches": notches, "fallback": msg.fallback_active,
                                  "state": int(msg.bank_state), "reason": msg.reason,
                                  "phase_lag": msg.phase_lag, "age": msg.estimate_age})
    res.estimates.sort(key=lambda r: r["t"])
    res.banks.sort(key=lambda r: r["t"])
    out = read_signals(recorded, ["/vibration_filtered"]).get("/vibration_filtered")
    if out is not None:
        res.t_out, res.y_out = out.t - res.t0, out.values
    return res


def write_report(res: DemoResult, path: Path) -> Path:
    """HTML report with the figures embedded (one self-contained file)."""
    from sysid_node.report import ModePoint, Page, figure, plot_mode_tracks
    from sysid_node.scenarios.truth import TrueMode

    page = Page(f"Adaptive notch demo: {res.bag.name}")
    points = [ModePoint(e["t"], m[0], MODE_STATUS[m[1]], m[2], m[3], m[4])
              for e in res.estimates for m in e["modes"]]
    truth = [TrueMode(m["name"], m.get("kind", "structural"), m["t_s"], m["frequency_hz"],
                      m["damping_ratio"]) for m in (res.truth or {}).get("modes", [])]
    fig, ax = figure(2, 1, 9, 3.2, sharex=True)
    plot_mode_tracks(ax[0, 0], ax[1, 0], points, truth=truth)
    ax[0, 0].set_title("Identified modes against time (2-sigma band; dashed: truth; faint: "
                       "tentative or lost), cf. the paper's Fig. 2")
    page.heading("Modes tracked against time").figure(fig)

    fig, ax = figure(1, 1, 9, 4)
    ax = ax[0, 0]
    for e in res.estimates:
        tracked = [m[2] for m in e["modes"] if m[1] == 1]
        ax.plot([e["t"]] * len(tracked), tracked, ".", color="0.6", ms=3)
    for j in range(max((len(b["notches"]) for b in res.banks), default=0)):
        pts = [(b["t"], b["notches"][j][2]) for b in res.banks if len(b["notches"]) > j]
        ax.step(*zip(*pts, strict=True), where="post", lw=1.5, label=f"notch {j}")
    ax.set_xlabel("time [s]")
    ax.set_ylabel("frequency [Hz]")
    ax.set_title("Notch centres (lines) over the tracked modes (grey)")
    if res.banks:
        ax.legend(fontsize=8)
    page.heading("Notch centres over the estimated modes").figure(fig)

    if res.y_out is not None and res.y_in is not None:
        fs = 1.0 / np.median(np.diff(res.t_in))
        half = res.t_in[-1] / 2
        a, b = res.y_in[res.t_in >= half, 0], res.y_out[res.t_out >= half, 0]
        n = min(a.size, b.size)
        f, pa = sps.welch(a[:n], fs=fs, nperseg=min(1024, n))
        _, pb = sps.welch(b[:n], fs=fs, nperseg=min(1024, n))
        fig, ax = figure(1, 1, 9, 4)
        ax = ax[0, 0]
        ax.semilogy(f, pa, label="before the notch bank (/vibration)")
        ax.semilogy(f, pb, label="after (/vibration_filtered)")
        ax.set_xlim(0, min(fs / 2, 15))
        ax.set_xlabel("frequency [Hz]")
        ax.set_ylabel("PSD [unit^2/Hz]")
        ax.set_title("Spectrum before and after the notch bank (second half of the run)")
        ax.legend()
        page.heading("Spectrum before and after").figure(fig)

    page.heading("Peak reduction per mode (true mode x published bank)").pre(res.peak_table())
    page.heading("Modes and notch centres over time").pre(res.table())
    page.heading("Summary").summary(res.summary())
    return page.write(path)
