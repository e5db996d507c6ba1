"""Scenes on the PWM valve supply: ``[model.options] supply = "valve_pwm"`` through the
binding, ``fidelity = "auto"`` picking the valve's level, and the refusals (issue 26)."""

import json
import re
from importlib import resources

import numpy as np
import pytest

from sarcomere.dynamics.assemblies import hanging_load
from sarcomere.dynamics.equilibrium import solve_equilibrium
from sarcomere.dynamics.errors import SarcomereError, ScenarioError
from sarcomere.dynamics.fidelity.ripple import choose_level
from sarcomere.scenarios import parse_scenario, run
from sarcomere.scenarios.binding import bind
from sarcomere.scenarios.explore import spec
from sarcomere.scenarios.loader import scenario_from_dict


def _text() -> str:
    return resources.files("sarcomere.scenarios").joinpath("pwm-step-auto.toml").read_text()


def _short(tolerance: str) -> str:
    """The packaged scene, 0.3 s, at another tolerance."""
    text = _text().replace('stop_time = "1.5 s"', 'stop_time = "0.3 s"')
    text = text.replace('output_interval = "1 ms"', 'output_interval = "5 ms"')
    return text.replace('tolerance = "1 %"', f'tolerance = "{tolerance}"')


def _scene(options: dict, kind: str = "transient", fidelity: str = "full") -> dict:
    return {
        "scenario": {"name": "valve", "kind": kind},
        "model": {"name": "myofibril", "n": 2, "fidelity": fidelity, "options": options},
        "inputs": {
            "valve.cmd": {"type": "step", "initial": 0.5, "final": 0.5, "time": "0 s", "unit": "1"}
        },
        "simulation": {"stop_time": "0.1 s"},
    }


@pytest.mark.slow
def test_binding_builds_a_valve_supplied_chain_from_a_scene_dict():
    rng = np.random.default_rng(26)
    for _ in range(3):
        f, hose = float(rng.uniform(20, 100)), float(rng.uniform(1, 6))
        ways = str(rng.choice(["3/2", "2/2"]))
        load = float(rng.uniform(10, 60))
        valve = {"frequency": f"{f} Hz", "ways": ways, "hose_volume": f"{hose} cm^3"}
        options = {"load": f"{load} g", "supply": "valve_pwm", "valve": valve}
        b = bind(scenario_from_dict(_scene(options)))
        model = b.build("full")
        assert "valve.cmd" in model.input_names and "regulator.p_cmd" not in model.input_names
        assert model.modulators["valve.cmd"].frequency == pytest.approx(f, rel=1e-12)
        direct = hanging_load(
            2,
            b.aps,
            load * 1e-3,
            "full",
            supply="valve_pwm",
            valve={"frequency": f, "ways": ways, "hose_volume": hose * 1e-6},
        )
        d = float(rng.uniform(0.1, 0.9))
        got, want = (solve_equilibrium(m, {"valve.cmd": d}) for m in (model, direct))
        assert got["myofibril.length"] == pytest.approx(want["myofibril.length"], rel=1e-12)
        assert got["valve_hose.V"] == pytest.approx(hose * 1e-6, rel=1e-12)


@pytest.mark.slow
@pytest.mark.parametrize(("tolerance", "level"), [("1 %", "averaged"), ("0.5 %", "switched")])
def test_auto_picks_the_valve_level_by_its_predicted_error(tmp_path, tolerance, level):
    out = tmp_path / "out"
    run(parse_scenario(_short(tolerance), "pwm-step-auto.toml"), out, quiet=True)
    summary = json.loads((out / "summary.json").read_text())
    auto = summary["extra"]["fidelity_auto"]
    assert summary["fidelity"] == "full" and auto["chosen"] == "full"
    valve = auto["valve"]
    assert valve["chosen"] == level and valve["why"].startswith(level)
    assert ("within" if level == "averaged" else "outside") in valve["why"]
    assert sorted(valve["duties"]) == ["0.2", "0.4"]
    # the decision against the rule at each held duty, on the model built directly
    b = bind(parse_scenario(_text()))
    model = b.build("full")
    tol = float(tolerance.split()[0]) / 100
    levels = {choose_level(model, d, ["myofibril.length"], tol).level for d in (0.2, 0.4)}
    assert level == ("averaged" if levels == {"averaged"} else "switched")
    worst = max(e["predicted_relative_error"]["myofibril.length"] for e in valve["duties"].values())
    assert summary["metrics"]["valve_predicted_error"] == pytest.approx(worst, rel=1e-12)
    assert (worst <= tol) == (level == "averaged")


@pytest.mark.slow
def test_averaged_valve_stays_within_its_predicted_error_on_the_packaged_scene(tmp_path):
    """The packaged scene run on both valve levels: the averaged length within the
    predicted error of the switched one over the whole run (the step's transient
    included), and the deviation not zero (the two levels differ)."""
    runs = {}
    for level in ("switched", "averaged"):
        text = _text().replace('fidelity = "auto"', 'fidelity = "full"')
        text = text.replace('tolerance = "1 %"\n', "")
        text = text.replace('frequency = "100 Hz"', f'frequency = "100 Hz"\nlevel = "{level}"')
        out = tmp_path / level
        run(parse_scenario(text, "pwm.toml"), out, quiet=True)
        runs[level] = np.loadtxt(out / "timeseries.csv", delimiter=",", skiprows=1)
    b = bind(parse_scenario(_text()))
    model = b.build("full")
    predicted = max(
        choose_level(model, d, ["myofibril.length"], 0.01).prediction.error["myofibril.length"]
        for d in (0.2, 0.4)
    )
    gap = np.abs(runs["switched"][:, 1] - runs["averaged"][:, 1])
    assert 1e-6 < np.max(gap) <= predicted


@pytest.mark.parametrize(
    ("options", "kind", "fidelity", "key"),
    [
        ({"supply": "valve"}, "transient", "full", "supply"),
        ({"supply": "valve_pwm"}, "equilibrium", "full", "supply"),
        ({"valve": {"frequency": "50 Hz"}}, "transient", "full", "valve"),
        ({"supply": "valve_pwm", "valve": {"wobble": 1}}, "transient", "full", "valve"),
        ({"supply": "valve_pwm", "valve": {"frequency": 50}}, "transient", "full", "valve"),
        ({"supply": "valve_pwm", "valve": {"ways": "5/2"}}, "transient", "full", "valve"),
        ({"supply": "valve_pwm", "regulator_tau": "10 ms"}, "transient", "full", "regulator_tau"),
        ({"supply": "valve_pwm", "valve": {"level": "averaged"}}, "transient", "auto", "level"),
        ({"supply": "valve_pwm"}, "transient", "linear", "fidelity"),
    ],
)
def test_bad_valve_settings_are_refused_naming_the_key(tmp_path, options, kind, fidelity, key):
    scene = _scene(options, kind, fidelity)
    if kind == "equilibrium":
        del scene["inputs"], scene["simulation"]
        scene["sweep"] = {"pressure": {"values": ["0.1 MPa"]}}
    with pytest.raises(ScenarioError, match=re.escape(key)):
        run(scenario_from_dict(scene), tmp_path / "out", quiet=True)


def test_auto_on_a_valve_refuses_a_long_chain_and_a_missing_duty(tmp_path):
    scene = _scene({"supply": "valve_pwm"}, fidelity="auto")
    scene["model"]["n"] = 30
    with pytest.raises(ScenarioError, match="fidelity.*below n = 24"):
        run(scenario_from_dict(scene), tmp_path / "a", quiet=True)
    scene = _scene({"supply": "valve_pwm"}, fidelity="auto")
    del scene["inputs"]
    with pytest.raises(ScenarioError, match=re.escape('inputs."valve.cmd"')):
        run(scenario_from_dict(scene), tmp_path / "b", quiet=True)


def test_a_study_on_the_valve_auto_scene_is_refused_saying_what_to_set():
    text = '[study]\nkind = "grid"\nbase = "pwm-step-auto"\n[study.grid]\nload = ["20 g", "30 g"]\n'
    with pytest.raises(SarcomereError, match=r"valve's level.*fidelity = \"full\""):
        spec.parse_study(text, "/nonexistent/s.toml")
