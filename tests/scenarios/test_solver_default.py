"""A transient scene without ``[solver] method`` gets the default rule's method, named in
summary.json with its reason (``extra.solver``); a scene that names its method keeps it."""

import json

import pytest

from sarcomere.scenarios.cli import main

SCENE = """
[scenario]
kind = "transient"
[model]
fidelity = "symmetric"
[inputs.pressure]
type = "{signal}"
final = "0.1 MPa"
{more}
[simulation]
stop_time = "0.05 s"
output_interval = "0.01 s"
{solver}
"""


def _summary(tmp_path, name, signal="step", more="", solver=""):
    path = tmp_path / f"{name}.toml"
    path.write_text(SCENE.format(signal=signal, more=more, solver=solver))
    assert main(["run", str(path), "--out", str(tmp_path / name), "--quiet"]) == 0
    return json.loads((tmp_path / name / "summary.json").read_text())


@pytest.fixture
def empty_cache(tmp_path, monkeypatch):
    monkeypatch.setenv("SARCOMERE_CACHE_DIR", str(tmp_path / "cache"))


def test_no_method_and_an_empty_cache_run_cvodes_and_say_why(tmp_path, empty_cache):
    s = _summary(tmp_path, "a")
    assert s["solver"] == "cvodes" and s["extra"]["solver"]["method"] == "cvodes"
    assert "not in" in s["extra"]["solver"]["method_reason"]
    assert not any((tmp_path / "cache").rglob("*.so"))  # the default compiles nothing


def test_a_named_method_is_kept_without_a_reason(tmp_path, empty_cache):
    s = _summary(tmp_path, "b", solver='[solver]\nmethod = "cvodes"')
    assert s["solver"] == "cvodes" and "solver" not in s["extra"]


@pytest.mark.slow  # compiles radau once
def test_the_second_run_after_a_radau_run_gets_radau(tmp_path, empty_cache):
    ramp = 'duration = "0.03 s"'
    first = _summary(tmp_path, "c", "ramp", ramp)
    _summary(tmp_path, "r", "ramp", ramp, '[solver]\nmethod = "radau"')  # builds the library
    second = _summary(tmp_path, "d", "ramp", ramp)
    assert (first["solver"], second["solver"]) == ("cvodes", "radau")
    assert "cached" in second["extra"]["solver"]["method_reason"]
    # the numbers agree within the default tolerance (rtol 1e-6), not to the bit
    a, b = first["metrics"]["length_final_mm"], second["metrics"]["length_final_mm"]
    assert a != b and abs(a - b) <= 1e-6 * abs(a)
    # another input law (a step) has no library yet: CVODES
    assert _summary(tmp_path, "e")["solver"] == "cvodes"
