"""Unit tests of the parameter table (params.py)."""

from __future__ import annotations

import math

import pytest

from sysid_node import params as P


def test_every_parameter_has_description_type_and_valid_default():
    for spec in P.PARAMS:
        assert spec.description, spec.name
        assert spec.kind in ("live", "structural", "read_only")
        assert P.validate(spec.name, spec.default) == "", spec.name
        if spec.type in (int, float):
            assert spec.lo is not None and spec.hi is not None, spec.name
    assert P.validate_set(P.defaults()) == ""


@pytest.mark.parametrize(
    ("name", "value", "fragment"),
    [
        ("forgetting_factor", 1.5, "above the maximum"),
        ("forgetting_factor", 0.5, "too small: use 0 (memory_time_constant)"),
        ("forgetting_factor", -0.1, "below the minimum"),
        ("memory_time_constant", 0.0, "below the minimum"),
        ("forgetting_factor", math.nan, "finite"),
        ("block_rows", 1, "too small"),
        ("block_rows", -1, "below the minimum"),
        ("block_rows", 2.5, "type int"),
        ("output_type", "PointCloud2", "not one of"),
        ("qos", "fast", "not one of"),
        ("imu_axes", "az,qq", "imu_axes"),
        ("output_topic", "vibration/", "trailing"),
        ("output_topic", "", "empty"),
        ("input_topic", "2nd/acc", "must start with a letter"),
        ("nonexistent", 1, "unknown parameter"),
    ],
)
def test_invalid_values_rejected_with_reason(name, value, fragment):
    assert fragment in P.validate(name, value)


def test_int_accepted_for_float_parameter():
    assert P.validate("forgetting_factor", 1) == ""


def test_cross_checks():
    v = P.defaults()
    assert "below freq_max" in P.validate_set({**v, "freq_min": 5.0, "freq_max": 4.0})
    assert "below damping_max" in P.validate_set({**v, "damping_min": 0.3, "damping_max": 0.2})
    assert "Nyquist" in P.validate_set({**v, "freq_max": 60.0}, sample_rate=100.0)
    assert P.validate_set({**v, "freq_max": 40.0}, sample_rate=100.0) == ""
    assert "differ" in P.validate_set({**v, "input_topic": "vibration"})


def test_memory_time_constant_gives_rate_independent_memory():
    v = {**P.defaults(), "memory_time_constant": 2.0}
    for fs in (100.0, 1000.0):
        lam = P.effective_lambda(v, fs)
        assert 1.0 / (1.0 - lam) == pytest.approx(2.0 * fs, rel=0.01)
    # the default is a memory of 1 s at any rate; an explicit forgetting factor overrides it
    for fs in (100.0, 1000.0):
        assert 1.0 / (1.0 - P.effective_lambda(P.defaults(), fs)) == pytest.approx(fs, rel=0.01)
    assert P.effective_lambda({**v, "forgetting_factor": 0.98}, 1000.0) == 0.98


def test_default_band_is_safe_fraction_of_nyquist():
    assert P.effective_band(P.defaults(), 100.0) == (0.0, pytest.approx(40.0))
    assert P.effective_band({**P.defaults(), "freq_max": 12.0}, 100.0) == (0.0, 12.0)


def test_structural_changes_listed():
    old = P.defaults()
    new = {"block_rows": 30, "forgetting_factor": 0.95, "output_topic": "/imu"}
    assert sorted(P.structural_changes(old, new)) == ["block_rows", "output_topic"]


def _shown(value: object) -> str:
    """A default as the README table shows it."""
    if isinstance(value, bool):
        return "true" if value else "false"
    return repr(value)


def test_readme_table_and_config_file_show_the_defaults():
    """The documented defaults are the real ones (README table and config/sysid_node.yaml)."""
    import re
    from pathlib import Path

    import yaml

    pkg = Path(__file__).resolve().parents[1]
    rows = {
        m.group(1): m.group(2)
        for m in re.finditer(r"^\| `(\w+)` \| \w+ \| `([^`]*)` \|", (pkg / "README.md").read_text(),
                             re.MULTILINE)
    }
    config = yaml.safe_load((pkg / "config" / "sysid_node.yaml").read_text())
    config = config["/**/sysid_node"]["ros__parameters"]
    for spec in P.PARAMS:
        assert rows.get(spec.name) == _shown(spec.default), f"README row of {spec.name}"
        assert config.get(spec.name) == spec.default, f"config/sysid_node.yaml {spec.name}"


@pytest.mark.parametrize(
    ("outputs", "inputs", "extra", "rows"),
    [(1, 1, {}, 35), (1, 0, {}, 35), (6, 1, {}, 10), (2, 2, {}, 18), (6, 0, {}, 12),
     (1, 1, {"block_rows": 20}, 20), (6, 1, {"max_order": 80}, 15)],
)
def test_auto_block_rows_bound_the_window_and_fit_the_order(outputs, inputs, extra, rows):
    values = {**P.defaults(), **extra}
    assert P.effective_block_rows(values, outputs, inputs) == rows


def test_online_lpv_parameters_checked_with_one_line_reasons(tmp_path):
    """scheduling_topic / lpv_model (read-only): a missing or corrupt model file, a model
    without its scheduling signal and a bad topic name are refused with the reason."""
    base = P.defaults()
    missing = str(tmp_path / "csm.lpv.npz")
    reason = P.validate_set({**base, "scheduling_topic": "rotor_speed", "lpv_model": missing})
    assert reason == f"LPV model file {missing} does not exist"
    (tmp_path / "bad.npz").write_text("not an npz")
    reason = P.validate_set({**base, "scheduling_topic": "rotor_speed",
                             "lpv_model": str(tmp_path / "bad.npz")})
    assert reason.startswith("cannot load LPV model from") and "\n" not in reason
    import numpy as np
    from sysid_node.core.lpv import LpvModel
    from sysid_node.scenarios.csm_rotor import csm_at

    good = tmp_path / "good.npz"
    LpvModel.from_systems(np.array([32.0, 38.0]), [csm_at(32.0), csm_at(38.0)]).save(good)
    assert "needs scheduling_topic" in P.validate_set({**base, "lpv_model": str(good)})
    assert "scheduling_topic" in P.validate("scheduling_topic", "rotor speed")
    assert "must differ" in P.validate_set({**base, "scheduling_topic": "vibration"})
    assert P.validate_set({**base, "scheduling_topic": "rotor_speed"}) == ""
    assert P.SPECS["lpv_model"].kind == P.SPECS["scheduling_topic"].kind == "read_only"


@pytest.mark.parametrize(
    ("outputs", "inputs", "fs", "low", "rows"),
    [(2, 1, 877.0, 9.0, 46),  # half of 9 Hz's period at 877 Hz (49 rows), capped: 276 rows
     (3, 1, 100.0, 1.9, 27),  # 26.3 rows
     (1, 1, 100.0, 2.0, 35),  # the cost rule already spans it
     (1, 0, 1000.0, 0.5, 140),  # capped at MAX_AUTO_WINDOW_ROWS rows of the window
     (6, 1, 1000.0, 0.5, 20),
     (2, 1, 877.0, float("nan"), 23),  # no lowest peak known: the cost rule
     (2, 0, 133.0, 1.559, 43),  # output-only from two outputs: half a period
     (1, 0, 133.0, 1.559, 86),  # ... from one output: a full period (43 rows before)
     (1, 0, 310.0, 1.816, 140)],  # 171 rows capped (86 before)
)
def test_auto_block_rows_span_half_a_period_of_the_lowest_peak(outputs, inputs, fs, low, rows):
    got = P.effective_block_rows(P.defaults(), outputs, inputs, fs, low)
    assert got == rows
    assert 2 * got * (outputs + inputs) <= max(P.MAX_AUTO_WINDOW_ROWS, 2 * 35 * (outputs + inputs))
    assert P.effective_block_rows({**P.defaults(), "block_rows": 12}, outputs, inputs, fs,
                                  low) == 12  # a configured value is kept


@pytest.mark.parametrize(
    ("outputs", "inputs", "fs", "mode", "rows"),
    [(1, 1, 200.0, 2.6, 70),  # a full period is 77 rows: 70 output rows l i at most
     (1, 1, 200.0, 4.0, 50),  # a full period
     (1, 1, 200.0, 10.0, 35),  # the automatic window spans it already
     (6, 1, 500.0, 2.0, 11),  # 250 rows asked: 70 // 6
     (5, 0, 128.0, 1.2, 14),  # the automatic 14 rows have l i = 70 already
     (1, 1, 200.0, float("nan"), 35),  # no mode: the automatic window
     (1, 0, 200.0, 4.0, 50)],  # output-only from one output: a full period too, not two
)
def test_a_configured_band_window_spans_a_full_period_within_its_cost(outputs, inputs, fs,
                                                                     mode, rows):
    got = P.period_block_rows(P.defaults(), outputs, inputs, fs, mode)
    assert got == rows
    assert got * outputs <= max(P.MAX_GROWN_FUTURE_ROWS, outputs * P.effective_block_rows(
        P.defaults(), outputs, inputs))
    assert P.period_block_rows({**P.defaults(), "block_rows": 12}, outputs, inputs, fs,
                               mode) == 12  # a configured value is kept


def test_one_output_without_input_spans_a_full_period_but_splits_only_short_of_half():
    """The m + l rows of a block row hold one period's samples: a full period from one output
    without input, half of one otherwise; the band splits only when half a period does not
    fit (a one-output window capped between half and a full period keeps one estimator)."""
    assert P.window_periods(1, 0) == 1.0
    assert P.window_periods(1, 1) == P.window_periods(2, 0) == P.window_periods(6, 1) == 0.5
    v = P.defaults()
    assert P.effective_block_rows(v, 1, 0, 310.0, 1.816) == P.max_auto_rows(1, 0) == 140
    assert not P.window_capped(v, 1, 0, 310.0, 1.816)  # 86 rows span half a period
    assert P.window_capped(v, 1, 0, 499.0, 1.75)  # 143 rows do not fit in 140
