"""``fidelity = "auto"``: a rule on n, the scene and the predictions (full below
REDUCED_FROM_N units; beyond, the cheapest reduced level predicted within tolerance runs,
alone); the choice is checked against the full model here, not in the run. The levels
without a model of their own (``linear``, ``equilibrium_path``) run when a scene names
them, with their predicted error."""

import importlib.util
from pathlib import Path

import numpy as np
import pytest

from sarcomere.dynamics.errors import ScenarioError
from sarcomere.dynamics.fidelity import REDUCED_FROM_N, policy
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


def _scene(fidelity: str, command: str, stop: str, n: int = 3, tol: str = "1 %") -> str:
    tolerance = f'tolerance = "{tol}"\n' if fidelity == "auto" else ""
    return SCENE.format(fidelity=fidelity, command=command, stop=stop, tolerance=tolerance, n=n)


def _both(tmp_path, command, stop, n=3, level="auto", tol="1 %"):
    """(run at ``level``, full run, measured error of its length against full)."""
    out = {}
    for fid in (level, "full"):
        text = _scene(fid, command, stop, n, tol)
        out[fid] = run(parse_scenario(text, f"{fid}.toml"), tmp_path / fid, quiet=True)
    a, f = (out[k].results["main"]["myofibril.length"] for k in (level, "full"))
    return out[level], out["full"], float(np.max(np.abs(a - f)) / np.ptp(f))


def test_slow_ramp_runs_the_equilibrium_path_alone_within_its_prediction(tmp_path, monkeypatch):
    calls = []
    simulate = binding.simulate
    monkeypatch.setattr(binding, "simulate", lambda *a, **k: calls.append(1) or simulate(*a, **k))
    path, _, error = _both(tmp_path, RAMP, "2.5 s", level="equilibrium_path")
    assert path.fidelity == "equilibrium_path"
    assert len(calls) == 1  # the full run of _both only: the path integrated nothing
    assert error <= path.metrics["fidelity_predicted_error"] < 0.01  # 0.30 %, 0.39 %
    linear, _, error = _both(tmp_path, RAMP, "2.5 s", level="linear")
    assert error <= linear.metrics["fidelity_predicted_error"]
    assert linear.metrics["fidelity_predicted_error"] > 0.05  # the ramp spans the range


def test_auto_below_the_reduced_length_runs_full_and_predicts_nothing(tmp_path, monkeypatch):
    """The slow ramp at n = 3 (within 1 % on the equilibrium path): auto runs full, exact
    (the same run as fidelity = "full"), and no equilibrium path is built."""
    monkeypatch.setattr(policy, "equilibrium_path", lambda *a, **k: pytest.fail("predicted"))
    auto, _, error = _both(tmp_path, RAMP, "2.5 s")
    report = auto.extra["fidelity_auto"]
    assert auto.fidelity == report["chosen"] == "full"
    assert report["predicted_error"] == {**dict.fromkeys(policy.AUTO_LADDER), "full": 0.0}
    assert all("not cheaper at n = 3" in w for w in report["not_predicted"].values())
    assert error == 0.0


def test_small_sweep_runs_the_linear_level_within_its_prediction(tmp_path):
    linear, _, error = _both(tmp_path, SMALL_CHIRP, "4 s", level="linear")
    assert linear.fidelity == "linear"
    assert error <= linear.metrics["fidelity_predicted_error"] < 0.01


def test_step_on_a_long_chain_runs_the_grouped_level_without_a_full_model(tmp_path, monkeypatch):
    built = []
    build = binding.Binding.build
    monkeypatch.setattr(
        binding.Binding, "build", lambda self, fid, **k: built.append(fid) or build(self, fid, **k)
    )
    auto, _, error = _both(tmp_path, STEP, "2 s", n=REDUCED_FROM_N, tol="5 %")
    assert auto.fidelity == "grouped"  # weight gradient and inertia kept
    assert error <= auto.metrics["fidelity_predicted_error"] <= 0.05
    assert built.count("full") == 1  # the full run of _both only
    report = auto.extra["fidelity_auto"]
    assert report["predicted_error"]["symmetric"] > 0.05  # against grouped
    assert report["predicted_against"]["grouped"] == "grouped (2 groups)"
    assert report["groups"] == 3
    # the levels on the full model cost more than its run: not predicted
    assert f"not cheaper at n = {REDUCED_FROM_N}" in report["not_predicted"]["equilibrium_path"]


def test_a_chain_below_the_reduced_length_runs_full(tmp_path):
    text = _scene("auto", STEP, "0.5 s", n=REDUCED_FROM_N - 1, tol="50 %")
    out = run(parse_scenario(text, "t.toml"), tmp_path, quiet=True)
    assert out.fidelity == "full"
    why = out.extra["fidelity_auto"]["not_predicted"]
    assert f"not predicted at n = {REDUCED_FROM_N - 1} < {REDUCED_FROM_N}" in why["grouped"]


def test_short_chain_does_not_predict_the_reduced_chains(tmp_path):
    """At n = 3 grouped is the chain itself, and symmetric could only be predicted
    against full, which costs more than running full."""
    out = run(parse_scenario(_scene("auto", STEP, "2 s"), "t.toml"), tmp_path, quiet=True)
    assert out.fidelity == "full"
    why = out.extra["fidelity_auto"]["not_predicted"]
    assert "not cheaper at n = 3" in why["grouped"] and "not cheaper" in why["symmetric"]


def test_a_cared_signal_the_level_lacks_rules_it_out(tmp_path):
    text = _scene("auto", STEP, "0.5 s", n=REDUCED_FROM_N).replace(
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
def test_random_scene_stays_within_its_prediction(index):
    """Four scenes of the randomised study's generator (seed 5, n <= 6) at the levels
    without a model of their own: where the prediction is within the scene's tolerance,
    the error against full at rtol 1e-9 is within it too."""
    study = _study()
    rng = np.random.default_rng(5)
    scenes = [study.draw(rng, i, n_max=6) for i in range(index + 1)]
    for level in ("linear", "equilibrium_path"):
        row = study.measure(scenes[index], timing=False, level=level)
        if row["predicted"] <= row["tolerance"]:
            assert row["measured"] <= row["predicted"]


def test_staircase_with_a_round_off_breakpoint_is_finite_and_within_tolerance(tmp_path):
    """Issue 17: 3 APS, 0 g, 50/52/48/51 kPa for 0.4 s each, tolerance 2 %: a switch
    2.2e-16 s from an output time made the linear level divide by zero, and the run
    returned NaN from 1.2032 s on without an error."""
    stair = 'type = "staircase"\nlevels = ["50 kPa", "52 kPa", "48 kPa", "51 kPa"]\ndwell = "0.4 s"'
    out = {}
    for fid in ("linear", "full"):
        text = _scene(fid, stair, "1.6 s").replace('load = "50 g"', 'load = "0 g"')
        text = text.replace('output_interval = "5 ms"\n', "")
        out[fid] = run(parse_scenario(text, f"{fid}.toml"), tmp_path / fid, quiet=True)
    assert out["linear"].metrics["fidelity_predicted_error"] < 0.02
    a, f = (out[k].results["main"] for k in ("linear", "full"))
    assert all(np.all(np.isfinite(a[n])) for n in a.names)
    error = np.max(np.abs(a["myofibril.length"] - f["myofibril.length"]))
    assert error / np.ptp(f["myofibril.length"]) < 0.02
