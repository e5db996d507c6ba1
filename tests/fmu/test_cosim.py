"""The co-simulation master: FMUs (FMI 2.0, 3.0) and native models as interchangeable
participants, Jacobi and Gauss-Seidel orderings, hold and extrapolation, and failures that
stop the run naming the participant, the time and the status."""

from __future__ import annotations

import json

import numpy as np
import pytest

from sarcomere.dynamics.errors import ParameterError, ScenarioError
from sarcomere.fmu.archive import open_fmu
from sarcomere.fmu.cosim import Connection, CosimError, cosimulate
from sarcomere.fmu.participants import FmuParticipant, NativeParticipant
from sarcomere.scenarios import resolve_scenario, run
from sarcomere.scenarios.cli import main
from sarcomere.scenarios.export_fmu import scenario_setup

pytestmark = pytest.mark.slow  # exports, builds and runs FMUs: the full suite (CI)

P_CMD = "regulator.p_cmd"
P_OUT = "regulator.p_out"
SIGNALS = ["myofibril.length", "myofibril.actin0.T", P_OUT]


def step_50g(t: float) -> float:
    """step-50g's command [Pa]: 0 -> 0.1 MPa at 0.1 s."""
    return 1e5 if t >= 0.1 else 0.0


def iso_step(t: float) -> float:
    """The isometric scene's command [Pa]: 0.01 -> 0.08 MPa at 0.05 s."""
    return 8e4 if t >= 0.05 else 1e4


@pytest.fixture(scope="session")
def step_setup():
    return scenario_setup("step-50g")


@pytest.fixture(scope="session")
def iso_setup(iso_scene):
    return scenario_setup(iso_scene)


def _rel_error(a, b, names) -> float:
    return max(float(np.max(abs(a[n] - b[n])) / np.max(abs(b[n]))) for n in names)


def _alone(participant, command, stop_time=2.0, step=2e-3):
    return cosimulate(
        [participant],
        stop_time=stop_time,
        step=step,
        sources={f"m.{P_CMD}": command},
        record=[f"m.{n}" for n in SIGNALS],
    )


def test_the_fmu_reproduces_the_native_model_in_the_master(step_fmu, step_setup):
    model, params, _, _ = step_setup
    native = _alone(NativeParticipant(model, "m", params), step_50g)
    with open_fmu(step_fmu) as fmu:
        exported = _alone(FmuParticipant(fmu, "m", params), step_50g)
    np.testing.assert_allclose(exported.index, np.linspace(0, 2, 1001), rtol=0, atol=1e-12)
    assert exported["m.myofibril.length"][-1] < exported["m.myofibril.length"][0] - 0.003
    assert _rel_error(exported, native, [f"m.{n}" for n in SIGNALS]) < 3e-5  # 1.3e-5 here
    assert exported.units["m.myofibril.length"] == "m"


def test_fmi3_and_fmi2_fmus_and_the_native_model_agree(iso_fmu, iso_fmu3, iso_setup):
    model, params, _, _ = iso_setup
    names = [f"m.{n}" for n in ("myofibril.actin0.T", P_OUT)]
    native = _alone(NativeParticipant(model, "m", params), iso_step, 0.3, 1e-3).select(names)
    for path in (iso_fmu, iso_fmu3):
        with open_fmu(path) as fmu:
            result = _alone(FmuParticipant(fmu, "m", params), iso_step, 0.3, 1e-3)
        assert _rel_error(result, native, names) < 1e-4, path


def _chain(a, b, ordering: str, inputs: str, on_step=None):
    """``a``'s regulator output drives ``b``'s command."""
    return cosimulate(
        [a, b],
        [Connection(f"a.{P_OUT}", f"b.{P_CMD}")],
        stop_time=0.2,
        step=0.01,
        ordering=ordering,
        inputs=inputs,
        sources={f"a.{P_CMD}": iso_step},
        record=[f"a.{P_OUT}", f"b.{P_CMD}", f"b.{P_OUT}"],
        on_step=on_step,
    )


@pytest.mark.parametrize(
    "ordering, inputs, expected",
    [
        ("jacobi", "hold", lambda y: y[1:-1]),
        ("gauss-seidel", "hold", lambda y: y[2:]),
        ("jacobi", "extrapolate", lambda y: y[1:-1] + 0.5 * (y[1:-1] - y[:-2])),
        ("gauss-seidel", "extrapolate", lambda y: 0.5 * (y[1:-1] + y[2:])),
    ],
)
def test_orderings_and_input_laws_feed_the_documented_value(iso_setup, ordering, inputs, expected):
    model, params, _, _ = iso_setup
    reported = []
    r = _chain(
        NativeParticipant(model, "a", params),
        NativeParticipant(model, "b", params),
        ordering,
        inputs,
        reported.append,
    )
    np.testing.assert_allclose(reported, r.index[1:], rtol=0, atol=1e-15)
    y, fed = r[f"a.{P_OUT}"], r[f"b.{P_CMD}"]
    # the input held over step k (read back at its end, row k + 1), from step 1 on
    np.testing.assert_allclose(fed[2:], expected(y), rtol=1e-12)
    assert np.ptp(y) > 5e4  # the command step passed through the regulator


def test_a_native_participant_and_its_fmu_are_interchangeable(iso_fmu, iso_setup):
    model, params, _, _ = iso_setup
    both_native = _chain(
        NativeParticipant(model, "a", params),
        NativeParticipant(model, "b", params),
        "gauss-seidel",
        "hold",
    )
    with open_fmu(iso_fmu) as fmu:
        mixed = _chain(
            NativeParticipant(model, "a", params),
            FmuParticipant(fmu, "b", params),
            "gauss-seidel",
            "hold",
        )
    assert _rel_error(mixed, both_native, [f"b.{P_OUT}", f"b.{P_CMD}"]) < 1e-4


def test_an_fmu_error_mid_run_stops_with_the_fmu_time_status_and_results(step_fmu):
    with open_fmu(step_fmu) as fmu:
        with pytest.raises(CosimError) as info:
            _alone(FmuParticipant(fmu, "m"), lambda t: -1e5 if t >= 0.1 else 0.0, 0.3, 0.01)
    err = info.value
    assert err.participant == f"FMU 'm' ({step_fmu.name})" and err.status == "error"
    assert err.time == pytest.approx(0.1)
    assert "at t = 0.1 s" in str(err) and "regulator.p_cmd = -100000 is outside" in str(err)
    assert "(results kept: up to t = 0.1 s)" in str(err)
    np.testing.assert_allclose(err.result.index, np.arange(11) * 0.01, atol=1e-12)
    assert np.all(np.isfinite(err.result["m.myofibril.length"]))


def test_a_native_failure_mid_run_keeps_the_results_so_far(iso_setup):
    model, params, _, _ = iso_setup
    with pytest.raises(CosimError) as info:
        _alone(
            NativeParticipant(model, "m", params),
            lambda t: np.nan if t >= 0.05 else 1e4,
            0.2,
            0.01,
        )
    err = info.value
    assert err.participant == "model 'm'" and err.status == "error"
    assert err.time == pytest.approx(0.05) and err.result.index[-1] == pytest.approx(0.05)


def test_a_failure_to_start_is_reported_with_no_results(iso_setup):
    model, params, _, _ = iso_setup
    with pytest.raises(
        CosimError, match=r"at t = 0 s: model 'm' returned error: start: .*nan.* not finite"
    ) as info:
        _alone(NativeParticipant(model, "m", params), lambda t: np.nan, 0.1, 0.01)
    assert str(info.value).endswith("(results kept: none)")
    assert len(info.value.result.index) == 0


@pytest.mark.parametrize(
    "change, message",
    [
        ({"connections": [Connection("c.x", f"b.{P_CMD}")]}, "connection source"),
        ({"connections": [Connection(f"a.{P_CMD}", f"b.{P_CMD}")]}, "an output of 'a'"),
        ({"connections": [Connection(f"a.{P_OUT}", f"b.{P_OUT}")]}, "an input of 'b'"),
        ({"sources": {f"b.{P_CMD}": iso_step}}, "an input with one driver"),
        ({"step": 0.03}, "whole number"),
        ({"ordering": "random"}, "jacobi or gauss-seidel"),
        ({"inputs": "cubic"}, "hold or extrapolate"),
        ({"record": ["a.nothing"]}, "a variable of 'a'"),
    ],
)
def test_bad_configurations_are_refused(iso_setup, change, message):
    model, _, _, _ = iso_setup
    parts = [NativeParticipant(model, "a"), NativeParticipant(model, "b")]
    config = {
        "connections": [Connection(f"a.{P_OUT}", f"b.{P_CMD}")],
        "stop_time": 0.1,
        "step": 0.01,
        "sources": {},
    } | change
    if "sources" in change:
        config["connections"] = [Connection(f"a.{P_OUT}", f"b.{P_CMD}")]
    with pytest.raises(ParameterError, match=message):
        cosimulate(parts, **config)


KEYS = ("native", "cosim")


def _column(csv, header: str) -> np.ndarray:
    names = csv.read_text().splitlines()[0].split(",")
    return np.loadtxt(csv, delimiter=",", skiprows=1, usecols=names.index(header))


def test_the_roundtrip_scene_runs_from_the_cli(tmp_path, step_fmu):
    """``cosim-roundtrip`` as packaged (its own export), and pointed at an FMU file."""
    out = tmp_path / "out"
    assert main(["run", "cosim-roundtrip", "--out", str(out), "--quiet"]) == 0
    summary = json.loads((out / "summary.json").read_text())
    error = summary["metrics"]["max_rel_error_vs_native"]
    # 9.3e-7 (thread stretch): the native run's own rtol 1e-6; 2.6e-5 (the chamber
    # pressure at the step) with the fixed 1 ms substeps before the adaptive Radau IIA
    assert 1e-8 < error < 5e-6
    assert summary["checks"]["max_rel_error_vs_native"]["ok"]
    assert summary["extra"]["worst_signal"].endswith(".e")
    native, cosim = (_column(out / f"timeseries_{k}.csv", "regulator.p_cmd [Pa]") for k in KEYS)
    assert len(cosim) == len(native) == 1001 and native[-1] == 1e5
    np.testing.assert_array_equal(cosim, native)  # the commands at the communication points
    scene = resolve_scenario("cosim-roundtrip").read_text()
    given = tmp_path / "given.toml"
    given.write_text(scene.replace("fmi = 2", f'fmu = "{step_fmu}"'))
    again = run(given, tmp_path / "again", quiet=True)
    assert again.metrics["max_rel_error_vs_native"] == pytest.approx(error, rel=1e-6)


def test_the_cosim_kind_refuses_unknown_keys(tmp_path):
    scene = resolve_scenario("cosim-roundtrip").read_text()
    bad = tmp_path / "bad.toml"
    bad.write_text(scene.replace('ordering = "jacobi"', 'ordering = "parallel"'))
    with pytest.raises(ScenarioError, match="'parallel': one of jacobi, gauss-seidel"):
        run(bad, tmp_path / "out", quiet=True)
    bad.write_text(scene.replace('ordering = "jacobi"', "order = 1"))
    with pytest.raises(ScenarioError, match="unknown key 'order'"):
        run(bad, tmp_path / "out", quiet=True)


@pytest.mark.parametrize(
    ("change", "message"),
    [
        (
            ("n = 3", "n = 2"),  # the bug: ran with exit 0, signals compared by name
            "step-50g.fmu \\(model 'hanging_n3_full'\\) is not this scene's model "
            "'hanging_n2_full': states: 18 in the FMU, 13 in the scene's model; only in the "
            "FMU: myofibril.aps3.body.s",
        ),
        (('load = "50 g"', 'load = "80 g"'), "load.m = 0.051 kg in the FMU, 0.081 kg in the scene"),
    ],
)
def test_an_fmu_of_another_model_is_refused_before_running(tmp_path, step_fmu, change, message):
    """docs/cosim.md: ``fmu`` is an FMU of the scene's model. Another model's (n = 3 for an
    n = 2 scene), or the same structure with another parameter value the scene does not
    set, is refused naming what differs, before the native run."""
    scene = resolve_scenario("cosim-roundtrip").read_text()
    given = tmp_path / "other.toml"
    given.write_text(scene.replace("fmi = 2", f'fmu = "{step_fmu}"').replace(*change))
    with pytest.raises(ScenarioError, match=message) as info:
        run(given, tmp_path / "out", quiet=True)
    assert "key 'cosim.fmu'" in str(info.value)
    assert not (tmp_path / "out").exists()


def test_an_fmi_version_the_given_fmu_does_not_have_is_refused(tmp_path, step_fmu):
    """``fmi = 3`` with an FMI 2.0 ``fmu`` was silently ignored."""
    scene = resolve_scenario("cosim-roundtrip").read_text()
    given = tmp_path / "other.toml"
    given.write_text(scene.replace("fmi = 2", f'fmu = "{step_fmu}"\nfmi = 3'))
    message = "key 'cosim.fmi': 3, but step-50g.fmu is an FMI 2.0 FMU"
    with pytest.raises(ScenarioError, match=message):
        run(given, tmp_path / "out", quiet=True)
    assert not (tmp_path / "out").exists()
