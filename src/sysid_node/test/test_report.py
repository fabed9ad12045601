"""The report building blocks (sysid_node.report) and offline --report."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest
from sysid_node.report import ModePoint, Page, figure, mode_points, plot_mode_tracks
from sysid_node.scenarios.paper import paper_example_data, paper_example_truth
from sysid_node.tools import offline

from sysid_node import bag_io

BAGS = Path(__file__).resolve().parents[3] / "bags"


def test_page_tables_summary_and_figures(tmp_path):
    fig, ax = figure(1, 1, 4, 2)
    ax[0, 0].plot([0, 1], [0, 1])
    page = Page("a <title>")
    page.table(["name", "value"], [["<b>", 1.234567], ["nan", float("nan")]], digits=3)
    page.summary({"counters": {"gaps": 2}, "rate": 100.0,
                  "modes": [{"id": 1, "f": 2.0}, {"id": 2, "f": 4.0}]})
    page.figure(fig, "caption")
    text = page.write(tmp_path / "r.html").read_text()
    assert "&lt;b&gt;" in text and "<b>" not in text.replace("<body>", "")
    assert ">1.23<" in text and ">-<" in text  # digits; NaN as '-'
    assert ">counters.gaps<" in text and "<th>id</th><th>f</th>" in text  # no raw JSON
    assert len(re.findall("data:image/png;base64,", text)) == 1


def test_mode_tracks_legend_names_the_long_tracked_modes_only():
    pts = [ModePoint(t, 1, "tracked", 2.0, 0.01, 0.02) for t in range(100)]
    pts += [ModePoint(t, 2, "tentative", 5.0, 0.1, 0.05) for t in range(100)]
    pts += [ModePoint(t, 3, "tracked", 7.0, 0.1, 0.05) for t in range(2)]  # a blip
    fig, ax = figure(2, 1)
    plot_mode_tracks(ax[0, 0], ax[1, 0], pts, truth=paper_example_truth())
    labels = [t.get_text() for t in ax[0, 0].get_legend().get_texts()]
    assert labels == ["mode #1"]
    faint = [ln.get_alpha() for ln in ax[0, 0].lines if ln.get_alpha() is not None]
    assert min(faint) < 0.5 <= max(faint)
    fig.clf()


def test_offline_report(tmp_path):
    t, u, y = paper_example_data(duration_s=8.0, seed=3)
    bag = tmp_path / "short"
    bag_io.write_signals(bag, {"/vibration": (1.7e9 + t, y, ["y"]),
                               "/excitation": (1.7e9 + t, u, ["u"])})
    out = tmp_path / "est"
    rc = offline.main(["--bag", str(bag), "--output", str(out), "--quiet",
                       "--report", str(tmp_path / "r.html")])
    assert rc == 0
    text = (tmp_path / "r.html").read_text()
    assert "Modes against time" in text and "Final estimate" in text
    assert "data:image/png;base64," in text and ">realtime_factor<" in text


def test_mode_points_from_records():
    from sysid_node.records import EstimateRecord, ModeRecord

    rec = EstimateRecord(2_000_000_000, [ModeRecord(4, "tracked", 2.0, 0.01, 0.02, 0.001, 1.0,
                                                    1.0, np.ones(1, complex))],
                         4, 20, 0.99, 100.0, np.zeros(1), True, 100)
    (p,) = mode_points([rec], t0_s=1.0)
    assert (p.t, p.id, p.status, p.frequency_hz) == (1.0, 4, "tracked", 2.0)


def test_offline_report_directory_missing_is_one_line(tmp_path, capsys):
    rc = offline.main(["--bag", str(BAGS / "paper_example"), "--output", str(tmp_path / "o"),
                       "--report", str(tmp_path / "no" / "r.html"), "--quiet"])
    assert rc == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("offline: error: report directory") and "\n" not in err


@pytest.fixture(autouse=True)
def _agg():
    import matplotlib

    matplotlib.use("Agg")
