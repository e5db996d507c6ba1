"""``fidelity = "auto"``: the cheapest level predicted within tolerance runs, alone; the
choice is checked against the full model here, not in the run. At n <= 6 auto runs full
first: the ladder's tests give it no budget (``ladder_only``): the ladder predicts at
once."""

import importlib.util
import math
from pathlib import Path

import numpy as np
import pytest

from sarcomere.dynamics.errors import ScenarioError
from sarcomere.dynamics.fidelity import policy
from sarcomere.scenarios import binding, parse_scenario, run

SCENE = """
[scenario]
kind = "transient"
[model]
fidelity = "{fidelity}"
n = {n}
[model.options]
setup = "hanging"
load = "50 g"
[inputs.pressure]
{command}
[simulation]
stop_time = "{stop}"
output_interval = "5 ms"
[outputs]
signals = ["myofibril.length"]
{tolerance}"""
RAMP = 'type = "ramp"\nfinal = "0.1 MPa"\nduration = "2 s"\nstart = "0.1 s"'
SMALL_CHIRP = (
    'type = "chirp"\noffset = "0.05 MPa"\namplitude = "3 kPa"\nf0 = "0.5 Hz"\nf1 = "10 Hz"\n'
    'duration = "4 s"'
)
STEP = 'type = "step"\nfinal = "0.1 MPa"\ntime = "0.1 s"'


@pytest.fixture
def ladder_only(monkeypatch):
    """No full first: the ladder predicts at once."""
    monkeypatch.setattr(policy, "FULL_FIRST_BUDGET_S", 0.0)


def _scene(fidelity: str, command: str, stop: str, n: int = 3) -> str:
    tolerance = 'tolerance = "1 %"\n' if fidelity == "auto" else ""
    return SCENE.format(fidelity=fidelity, command=command, stop=stop, tolerance=tolerance, n=n)


def _both(tmp_path, command, stop, n=3):
    """(auto run, full run, measured error of the auto run's length against full)."""
    out = {}
    for fid in ("auto", "full"):
        text = _scene(fid, command, stop, n)
        out[fid] = run(parse_scenario(text, f"{fid}.toml"), tmp_path / fid, quiet=True)
    a, f = (out[k].results["main"]["myofibril.length"] for k in ("auto", "full"))
    return out["auto"], out["full"], float(np.max(np.abs(a - f)) / np.ptp(f))


def test_slow_ramp_runs_the_equilibrium_path_alone_within_tolerance(
    tmp_path, monkeypatch, ladder_only
):
    calls = []
    simulate = binding.simulate
    monkeypatch.setattr(binding, "simulate", lambda *a, **k: calls.append(1) or simulate(*a, **k))
    auto, _, error = _both(tmp_path, RAMP, "2.5 s")
    assert auto.fidelity == "equilibrium_path"
    assert len(calls) == 1  # the full run of _both only: auto integrated nothing
    report = auto.extra["fidelity_auto"]
    assert report["chosen"] == "equilibrium_path" and report["wall_time_s"] > 0
    assert auto.metrics["fidelity_predicted_error"] == report["predicted_error"]["equilibrium_path"]
    assert error <= report["predicted_error"]["equilibrium_path"] < 0.01  # 0.30 %, 0.39 %
    assert report["predicted_error"]["linear"] > 0.05  # the ramp spans the nonlinear range
    assert "full_first" not in report


def test_full_first_returns_full_when_it_is_cheaper_than_predicting(tmp_path, monkeypatch):
    """With the budget to finish, the slow ramp (equilibrium_path on the ladder) runs full,
    exact to the solver's tolerance, and predicts nothing: no equilibrium path is built."""
    monkeypatch.setattr(policy, "FULL_FIRST_BUDGET_S", math.inf)
    monkeypatch.setattr(policy, "equilibrium_path", lambda *a, **k: pytest.fail("predicted"))
    auto, _, error = _both(tmp_path, RAMP, "2.5 s")
    report = auto.extra["fidelity_auto"]
    assert auto.fidelity == report["chosen"] == "full"
    assert report["full_first"]["finished"] is True
    assert report["predicted_error"] == {**dict.fromkeys(policy.AUTO_LADDER), "full": 0.0}
    assert all("cheaper than predicting" in w for w in report["not_predicted"].values())
    assert error == 0.0  # one piece of 501 points: simulate's run


def test_paused_full_goes_on_when_the_ladder_ends_at_full(tmp_path, monkeypatch):
    """The step at n = 3 rules out linear and the path: the paused full run (1201 points,
    two pieces) is finished, not run again."""
    monkeypatch.setattr(policy, "FULL_FIRST_BUDGET_S", 1e-9)  # pauses after a piece
    monkeypatch.setattr(policy, "FULL_FIRST_FINISH_S", 0.0)  # and always asks the ladder
    calls = []
    simulate = binding.simulate
    monkeypatch.setattr(binding, "simulate", lambda *a, **k: calls.append(1) or simulate(*a, **k))
    auto, _, error = _both(tmp_path, STEP, "6 s")
    report = auto.extra["fidelity_auto"]
    assert auto.fidelity == "full" and report["full_first"]["finished"] is False
    assert 0 < report["full_first"]["fraction_run"] < 1
    assert len(calls) == 1  # the full run of _both only
    assert report["predicted_error"]["linear"] > 0.01
    assert error == 0.0  # paused where simulate restarts anyway: a held input


def test_a_paused_full_run_with_a_short_rest_is_finished_not_predicted(tmp_path, monkeypatch):
    """The small sweep on a 2 ms grid pauses after its first piece; the rest, extrapolated
    from the pace so far, is far below FULL_FIRST_FINISH_S: full is finished and nothing
    is predicted (before: the ladder ran and the paused work was dropped)."""
    monkeypatch.setattr(policy, "FULL_FIRST_BUDGET_S", 1e-9)  # pauses after a piece
    monkeypatch.setattr(policy, "FULL_FIRST_FINISH_S", 1e3)
    out = {}
    for fid in ("auto", "full"):
        text = _scene(fid, SMALL_CHIRP, "4 s").replace('"5 ms"', '"2 ms"')
        out[fid] = run(parse_scenario(text, f"{fid}.toml"), tmp_path / fid, quiet=True)
    report = out["auto"].extra["fidelity_auto"]
    first = report["full_first"]
    assert out["auto"].fidelity == "full" and first["finished_after_pause"] is True
    assert 0 < first["fraction_run"] < 1 and first["extrapolated_rest_s"] < 1e3
    assert report["predicted_error"]["linear"] is None  # nothing predicted
    a, f = (out[k].results["main"]["myofibril.length"] for k in ("auto", "full"))
    assert np.max(np.abs(a - f)) / np.ptp(f) < 1e-4  # one restart more: solver tolerance


def test_small_sweep_runs_the_linear_level_within_tolerance(tmp_path, ladder_only):
    auto, _, error = _both(tmp_path, SMALL_CHIRP, "4 s")
    assert auto.fidelity == "linear"
    assert error <= auto.extra["fidelity_auto"]["predicted_error"]["linear"] < 0.01


def test_step_on_a_long_chain_runs_the_grouped_level_without_a_full_model(tmp_path, monkeypatch):
    built = []
    build = binding.Binding.build
    monkeypatch.setattr(
        binding.Binding, "build", lambda self, fid, **k: built.append(fid) or build(self, fid, **k)
    )
    auto, _, error = _both(tmp_path, STEP, "2 s", n=10)
    assert auto.fidelity == "grouped"  # weight gradient and inertia kept
    assert error < 0.01  # measured 0.37 %
    assert built.count("full") == 1  # the full run of _both only
    report = auto.extra["fidelity_auto"]
    assert report["predicted_error"]["symmetric"] > 0.05  # against grouped: 65 %
    assert report["predicted_against"]["grouped"] == "grouped (2 groups)"
    assert report["groups"] == 3
    # beyond n = 6 the levels on the full model cost more than its run: not predicted
    assert "not cheaper at n = 10" in report["not_predicted"]["equilibrium_path"]


def test_paused_full_is_dropped_when_the_ladder_picks_a_level(tmp_path, monkeypatch):
    """The small sweep on a 2 ms grid (two pieces): paused full, then linear within
    tolerance; the report says full first did not finish."""
    monkeypatch.setattr(policy, "FULL_FIRST_BUDGET_S", 1e-9)  # pauses after a piece
    monkeypatch.setattr(policy, "FULL_FIRST_FINISH_S", 0.0)  # and always asks the ladder
    out = {}
    for fid in ("auto", "full"):
        text = _scene(fid, SMALL_CHIRP, "4 s").replace('"5 ms"', '"2 ms"')
        out[fid] = run(parse_scenario(text, f"{fid}.toml"), tmp_path / fid, quiet=True)
    report = out["auto"].extra["fidelity_auto"]
    assert out["auto"].fidelity == "linear" and report["full_first"]["finished"] is False
    a, f = (out[k].results["main"]["myofibril.length"] for k in ("auto", "full"))
    assert np.max(np.abs(a - f)) / np.ptp(f) <= report["predicted_error"]["linear"] < 0.01


def test_short_chain_does_not_predict_the_reduced_chains(tmp_path, ladder_only):
    """At n = 3 grouped is the chain itself, and symmetric could only be predicted
    against full, which costs more than running full."""
    out = run(parse_scenario(_scene("auto", STEP, "2 s"), "t.toml"), tmp_path, quiet=True)
    assert out.fidelity == "full"  # linear 9.5 % and equilibrium path 10 % predicted
    why = out.extra["fidelity_auto"]["not_predicted"]
    assert "not cheaper at n = 3" in why["grouped"] and "not cheaper" in why["symmetric"]


def test_a_cared_signal_the_level_lacks_rules_it_out(tmp_path):
    text = _scene("auto", STEP, "2 s", n=10).replace(
        '["myofibril.length"]', '["myofibril.length", "myofibril.aps3.chamber.p_gauge"]'
    )
    out = run(parse_scenario(text, "t.toml"), tmp_path, quiet=True)
    assert out.fidelity == "full"
    why = out.extra["fidelity_auto"]["not_predicted"]
    assert "aps3" in why["grouped"] and "aps3" in why["symmetric"]


@pytest.mark.parametrize(("level", "n"), [("grouped", 10), ("symmetric", 3)])
def test_reduced_levels_run_as_fixed_fidelity(tmp_path, level, n):
    text = _scene(level, STEP, "0.5 s", n=n)
    out = run(parse_scenario(text, "t.toml"), tmp_path, quiet=True)
    assert out.metrics["pressure_final_kPa"] == pytest.approx(100.0, rel=0.02)


def test_grouped_on_a_short_chain_is_refused_at_validation(tmp_path):
    """At n <= 6 the grouped chain is the chain itself: refused with the reason, before
    a plot of an inner unit's signal fails (it names the chain ends only)."""
    text = _scene("grouped", STEP, "0.5 s").replace(
        "[outputs]", '[outputs.plots]\ntension = ["myofibril.actin3.T"]\n[outputs]'
    )
    with pytest.raises(ScenarioError, match=r"model\.n.*grouped needs n > 6: at n = 3"):
        run(parse_scenario(text, "t.toml"), tmp_path, quiet=True)


def _study():
    """benchmarks/auto_study.py (the scene generator of the randomised study)."""
    path = Path(__file__).parents[2] / "benchmarks" / "auto_study.py"
    spec = importlib.util.spec_from_file_location("auto_study", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.mark.parametrize("index", range(4))
@pytest.mark.slow  # end to end or compiles: the full suite (CI) runs it
def test_random_scene_stays_within_its_tolerance(index, ladder_only):
    """Four scenes of the randomised study's generator (seed 5, n <= 6: where linear and
    equilibrium_path are on the ladder): the chosen level's error against full at rtol
    1e-9 is within the tolerance, and within its prediction."""
    study = _study()
    rng = np.random.default_rng(5)
    scenes = [study.draw(rng, i, n_max=6) for i in range(index + 1)]
    row = study.measure(scenes[index], timing=False)
    assert row["measured"] <= row["tolerance"]
    if row["chosen"] != "full":
        assert row["measured"] <= row["predicted"]


def test_staircase_with_a_round_off_breakpoint_is_finite_and_within_tolerance(
    tmp_path, ladder_only
):
    """Issue 17: 3 APS, 0 g, 50/52/48/51 kPa for 0.4 s each, tolerance 2 %: a switch
    2.2e-16 s from an output time made the linear level divide by zero, and the run
    returned NaN from 1.2032 s on without an error."""
    stair = 'type = "staircase"\nlevels = ["50 kPa", "52 kPa", "48 kPa", "51 kPa"]\ndwell = "0.4 s"'
    out = {}
    for fid in ("auto", "full"):
        text = _scene(fid, stair, "1.6 s").replace('load = "50 g"', 'load = "0 g"')
        text = text.replace('output_interval = "5 ms"\n', "").replace('"1 %"', '"2 %"')
        out[fid] = run(parse_scenario(text, f"{fid}.toml"), tmp_path / fid, quiet=True)
    assert out["auto"].fidelity == "linear"
    a, f = (out[k].results["main"] for k in ("auto", "full"))
    assert all(np.all(np.isfinite(a[n])) for n in a.names)
    error = np.max(np.abs(a["myofibril.length"] - f["myofibril.length"]))
    assert error / np.ptp(f["myofibril.length"]) < 0.02
