"""validate CLI: the before/after table on a bag, and one-line errors with non-zero exit."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
BAGS = ROOT / "bags" / "hidden"


def _run(*args: str, timeout: float = 120) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "sysid_node.tools.validate", *args],
        capture_output=True,
        text=True,
        timeout=timeout,
        env=os.environ.copy(),
    )


def test_table_json_and_saved_model(tmp_path):
    out = tmp_path / "v.json"
    model = tmp_path / "m.npz"
    p = _run(
        "--bag",
        str(BAGS / "input_delay"),
        "--order",
        "4",
        "--add",
        "input_delay",
        "--json",
        str(out),
        "--save-model",
        str(model),
    )
    assert p.returncode == 0, p.stderr
    assert "before" in p.stdout and "after +input_delay" in p.stdout
    r = json.loads(out.read_text())
    for key in ("before", "after", "diagnoses", "added"):
        assert key in r
    assert set(r["diagnoses"][0]) >= {"effect", "score", "evidence", "parameters"}
    assert len(r["before"]["fit_percent"]) == 1 and len(r["after"]["residual_rms"]) == 1
    assert model.is_file()


def _one_line_error(capsys, *args: str) -> str:
    """Run main() in-process; it must return non-zero with exactly one line on stderr."""
    from sysid_node.tools.validate import main

    try:
        code = main(list(args))
    except SystemExit as exc:  # argparse errors
        code = exc.code
    err = capsys.readouterr().err
    assert code != 0
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert len(lines) == 1, err
    assert "Traceback" not in err
    return lines[0]


def test_error_exit_from_the_executable():
    p = _run("--bag", str(BAGS / "clean"), "--output", "/nope")
    assert p.returncode == 2
    assert len(p.stderr.strip().splitlines()) == 1 and "/nope" in p.stderr


def test_missing_topic_one_line(capsys):
    assert "/nope" in _one_line_error(
        capsys, "--bag", str(BAGS / "clean"), "--input", "/nope2", "--output", "/nope"
    )


def test_missing_bag_one_line(capsys, tmp_path):
    assert "not found" in _one_line_error(capsys, "--bag", str(tmp_path / "none"))


def test_too_short_to_split_one_line(capsys):
    msg = _one_line_error(
        capsys, "--bag", str(BAGS / "clean"), "--split", "0.05", "--block-rows", "60"
    )
    assert "too short" in msg


def test_mismatched_model_one_line(capsys, tmp_path):
    from sysid_node.core.batch import identify

    rng = np.random.default_rng(0)
    m = identify(rng.standard_normal((600, 2)), rng.standard_normal((600, 1)), fs=50.0, order=2)
    path = tmp_path / "two_outputs.npz"
    m.save(path)
    assert "output" in _one_line_error(capsys, "--bag", str(BAGS / "clean"), "--model", str(path))


def test_unknown_effect_one_line(capsys):
    assert "gremlins" in _one_line_error(capsys, "--bag", str(BAGS / "clean"), "--add", "gremlins")


def test_bad_option_one_line(capsys):
    assert "--split" in _one_line_error(capsys, "--bag", str(BAGS / "clean"), "--split", "x")


def test_report_under_a_regular_file_one_line(capsys, tmp_path):
    f = tmp_path / "afile"
    f.write_text("x")
    msg = _one_line_error(capsys, "--bag", str(BAGS / "clean"), "--report", str(f / "r.html"))
    assert "--report" in msg and "not a directory" in msg


def test_json_onto_a_directory_one_line(capsys, tmp_path):
    msg = _one_line_error(capsys, "--bag", str(BAGS / "clean"), "--json", str(tmp_path))
    assert "--json" in msg and "directory" in msg


def test_output_in_a_missing_directory_one_line(capsys, tmp_path):
    msg = _one_line_error(
        capsys, "--bag", str(BAGS / "clean"), "--save-model", str(tmp_path / "no" / "m.npz")
    )
    assert "does not exist" in msg
