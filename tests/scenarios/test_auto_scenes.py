"""The packaged ``fidelity = "auto"`` scenes: the level each picks is checked here against
full at the scene's own settings (the run itself never runs full, except as "full first"):
error over the scene's ``[outputs] signals`` within its tolerance. The dither (n = 3)
integrates full within the full-first budget and so runs full; without the budget its
ladder picks linear, checked here too."""

import re
from pathlib import Path

import numpy as np
import pytest

from sarcomere.dynamics.fidelity import policy
from sarcomere.scenarios import parse_scenario, transient
from sarcomere.scenarios.loader import packaged_scenarios

SCENES = [  # name, the level auto picks (the dither: with no time for full first)
    ("dither-50g-auto", "linear"),
    ("step-50g-n30-auto", "grouped"),
    pytest.param("ramp-50g-n60-auto", "grouped", marks=pytest.mark.slow),
    pytest.param("cycle-50g-n60-auto", "grouped", marks=pytest.mark.slow),
]


def _run(text: str):
    sc = parse_scenario(text, "scene.toml")
    return sc, transient.run_transient(sc, Path("."))


@pytest.mark.parametrize(("name", "level"), SCENES)
@pytest.mark.slow  # end to end or compiles: the full suite (CI) runs it
def test_auto_scene_picks_a_cheaper_level_within_its_tolerance_of_full(name, level, monkeypatch):
    monkeypatch.setattr(policy, "FULL_FIRST_BUDGET_S", 0.0)  # no full first (n > 6: none)
    text = packaged_scenarios()[name].read_text()
    sc, auto = _run(text)
    report = auto.extra["fidelity_auto"]
    assert auto.fidelity == report["chosen"] == level
    assert report["tolerance"] == sc.outputs.tolerance
    full_text = re.sub(r"(?m)^tolerance = .*\n", "", text.replace('"auto"', '"full"'))
    _, full = _run(full_text)
    a, f = auto.results["main"], full.results["main"]
    error = max(np.max(np.abs(a[n] - f[n])) / np.ptp(f[n]) for n in sc.outputs.signals)
    assert error <= sc.outputs.tolerance
    # the prediction is what chose the level; here it is checked against the measurement
    predicted = report["predicted_error"][level]
    assert predicted <= sc.outputs.tolerance
    # predicted/measured: 1.24 (linear: 0.80 / 0.65 %), 1.5-1.7 (grouped: 2.8-4.7 %)
    assert error <= predicted < 2 * error


@pytest.mark.slow  # end to end or compiles: the full suite (CI) runs it
def test_dither_runs_full_when_full_is_cheaper_than_predicting(monkeypatch):
    """Full integrates the dither in ~80 ms: given the time, auto runs it and predicts
    nothing (linear, its ladder's pick, costs 1.2x full end to end)."""
    monkeypatch.setattr(policy, "FULL_FIRST_BUDGET_S", np.inf)
    monkeypatch.setattr(policy, "equilibrium_path", lambda *a, **k: pytest.fail("predicted"))
    text = packaged_scenarios()["dither-50g-auto"].read_text()
    sc, auto = _run(text)
    report = auto.extra["fidelity_auto"]
    assert auto.fidelity == report["chosen"] == "full"
    assert report["full_first"]["finished"] is True
    full_text = re.sub(r"(?m)^tolerance = .*\n", "", text.replace('"auto"', '"full"'))
    _, full = _run(full_text)
    a, f = auto.results["main"], full.results["main"]
    error = max(np.max(np.abs(a[n] - f[n])) / np.ptp(f[n]) for n in sc.outputs.signals)
    assert error < 1e-4  # full in 4 pieces against full in one (rtol 1e-6)
