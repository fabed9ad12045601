"""Acceptance of the validate tool on the hidden-effect bags (bags/hidden, fixed seeds)."""

from __future__ import annotations

from pathlib import Path

import pytest
from sysid_node.tools.validate import build_parser, run
from sysid_node.validation.hidden_effects import make

BAGS = Path(__file__).resolve().parents[3] / "bags" / "hidden"
EFFECT_BAGS = [
    "missing_mode",
    "periodic_disturbance",
    "parameter_varying",
    "input_delay",
    "nonlinear_stiffness",
    "sensor_bias",
    "feedback",
]
# Shortfalls measured on these bags (see the README section): the re-fit does not reach -50 %.
SHORT = {"nonlinear_stiffness", "feedback"}


@pytest.fixture(scope="module")
def results():
    cache: dict = {}

    def get(name: str, *extra: str) -> dict:
        key = (name, extra)
        if key not in cache:
            args = build_parser().parse_args(["--bag", str(BAGS / name), "--order", "4", *extra])
            cache[key] = run(args)
        return cache[key]

    return get


def test_clean_bag_no_significant_hypothesis_and_tests_pass(results):
    r = results("clean")
    assert not any(d["significant"] for d in r["diagnoses"])
    assert r["before"]["whiteness_passed"]
    assert r["before"]["xcorr_passed"]


@pytest.mark.parametrize("name", EFFECT_BAGS)
def test_effect_ranked_first(results, name):
    r = results(name)
    assert r["diagnoses"][0]["effect"] == name


@pytest.mark.parametrize("name", EFFECT_BAGS)
def test_adding_the_effect_halves_the_residual(results, name):
    if name in SHORT:
        pytest.xfail(f"{name}: re-fit lowers the residual RMS by less than 50 % on this bag")
    r = results(name, "--add", name)
    assert r["added"] == [name]
    assert r["residual_rms_reduction"] >= 0.5


def test_parameters_are_estimated(results):
    seeds = {}
    from importlib import import_module

    gen = import_module("sysid_node.validation.hidden_effects")
    truth = {n: make(n, seed=100 + gen.SCENARIOS.index(n)).truth for n in EFFECT_BAGS}
    del seeds
    p = results("missing_mode")["diagnoses"][0]["parameters"]
    assert abs(p["frequency_hz"] / truth["missing_mode"]["frequency_hz"] - 1) < 0.02
    p = results("periodic_disturbance")["diagnoses"][0]["parameters"]
    assert p["source"] == "/rotor_speed"
    assert set(p["harmonics"]) == {1, 3}
    assert abs(p["frequency_hz"] / truth["periodic_disturbance"]["frequency_hz"] - 1) < 0.02
    p = results("parameter_varying")["diagnoses"][0]["parameters"]
    assert p["signal"] == "/airspeed"
    slope = truth["parameter_varying"]["slope_hz_per_unit"]
    assert abs(p["frequency_slope_hz_per_unit"] / slope - 1) < 0.1
    p = results("input_delay")["diagnoses"][0]["parameters"]
    assert abs(p["samples"] - truth["input_delay"]["samples"]) <= 1
    p = results("sensor_bias")["diagnoses"][0]["parameters"]
    assert abs(p["offset"][0] / truth["sensor_bias"]["offset"] - 1) < 0.2
    p = results("nonlinear_stiffness")["diagnoses"][0]["parameters"]
    assert p["channel"] == 0


def test_auto_adds_the_top_effect(results):
    r = results("input_delay", "--auto")
    assert r["added"][:1] == ["input_delay"]
    assert r["residual_rms_reduction"] >= 0.5
