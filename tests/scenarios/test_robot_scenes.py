"""The robot scenes: the joint and bundle bound from scene files, joint-stiffness and
bundle-recruitment, their refusals."""

import json

import numpy as np
import pytest

from sarcomere.dynamics.errors import ScenarioError
from sarcomere.scenarios import parse_scenario, run
from sarcomere.scenarios.catalog import packaged_scenarios

JOINT = """
[scenario]
name = "j"
kind = "{kind}"

[model]
name = "joint"
fidelity = "{fidelity}"
n = {n}
{options}
{parameters}
{body}
"""

STEPS = """
[sweep.pressure]
unit = "Pa"
values = {pressures}

[sweep.angle]
unit = "rad"
values = [{angle}]

[simulation]
stop_time = "4 s"
output_interval = "20 ms"

[solver]
rtol = 1e-9
atol = 1e-12
"""


def _text(kind="joint_stiffness", fidelity="full", n=2, options="", parameters="", body=""):
    return JOINT.format(
        kind=kind, fidelity=fidelity, n=n, options=options, parameters=parameters, body=body
    )


def _joint(**kwargs):
    return parse_scenario(_text(**kwargs), "j.toml")


@pytest.mark.slow
def test_packaged_joint_stiffness_linearisation_within_1_percent_of_load_steps(tmp_path):
    out = run("joint-stiffness", tmp_path, quiet=True)
    assert out.metrics["linearisation_error_max_ratio"] < 0.01
    assert out.metrics["angle_deviation_max_rad"] < 1e-9
    assert out.metrics["stiffness_range_ratio"] > 1.1  # co-contraction stiffens
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert summary["metrics"]["stiffness_highest_N_m_per_rad"] > 0


@pytest.mark.slow
def test_random_joints_stiffness_from_steps_matches_the_linearisation(tmp_path):
    rng = np.random.default_rng(2026)
    for case in range(2):
        pressures = sorted(float(v) for v in rng.uniform(0.05e6, 0.3e6, 2))
        angle = 0.0 if case == 0 else float(rng.uniform(-0.2, 0.2))
        r = f'"joint.r" = "{rng.uniform(6, 14):.2f} mm"'
        sc = _joint(
            fidelity="symmetric",
            n=int(rng.integers(1, 4)),
            parameters=f"[parameters]\n{r}",
            body=STEPS.format(pressures=pressures, angle=angle),
        )
        out = run(sc, tmp_path / str(case), quiet=True)
        assert out.metrics["linearisation_error_max_ratio"] < 0.01
        assert out.metrics["angle_deviation_max_rad"] < 1e-9
        if angle == 0.0:  # the symmetric pair at rest
            assert out.metrics["torque_at_rest_max_N_m"] < 1e-12


@pytest.mark.parametrize(
    ("kwargs", "where"),
    [
        ({"fidelity": "auto"}, "model.fidelity"),
        ({"fidelity": "linear"}, "model.fidelity"),
        ({"options": '[model.options]\nsupply = "valve_pwm"'}, "supply"),
        ({"options": "[model.options]\nfibres = 2"}, "fibres"),
        ({"options": "[model.options]\nn_extensor = 0"}, "n_extensor"),
        ({"parameters": '[parameters]\n"joint.radius" = "1 mm"'}, "joint.radius"),
        ({"body": STEPS.format(pressures=[0.1e6], angle=0).replace("[0]", "[0, 1]")}, "angle"),
        ({"body": STEPS.format(pressures=[0.1e6], angle=3.0)}, "angle"),
    ],
)
def test_joint_scene_refusals_name_the_key(tmp_path, kwargs, where):
    body = kwargs.pop("body", STEPS.format(pressures=[0.1e6], angle=0))
    with pytest.raises(ScenarioError, match=where.replace(".", r"\.")):
        run(_joint(body=body, **kwargs), tmp_path, quiet=True)


def test_the_stiffness_kind_refuses_a_chain(tmp_path):
    text = packaged_scenarios()["joint-stiffness"].read_text(encoding="utf-8")
    sc = parse_scenario(text.replace('name = "joint"', 'name = "myofibril"'), "x.toml")
    with pytest.raises(ScenarioError, match="joint"):
        run(sc, tmp_path, quiet=True)


@pytest.mark.slow
def test_packaged_bundle_recruitment_grades_in_equal_steps_like_pressure(tmp_path):
    out = run("bundle-recruitment", tmp_path, quiet=True)
    m = out.metrics
    assert m["recruitment_step_spread_ratio"] < 1e-6  # identical fibres: equal steps
    assert m["force_all_recruited_N"] == pytest.approx(4 * m["force_first_fibre_N"], rel=1e-6)
    f = json.loads((tmp_path / "summary.json").read_text())["extra"]
    assert np.all(np.diff(f["force_all_fibres_N"]) > 0)
    assert np.all(np.diff(f["matched_pressure_Pa"]) > 0)


def test_recruitment_refuses_a_hanging_bundle(tmp_path):
    text = packaged_scenarios()["bundle-recruitment"].read_text(encoding="utf-8")
    sc = parse_scenario(text.replace('"isometric"', '"hanging"'), "x.toml")
    with pytest.raises(ScenarioError, match="isometric"):
        run(sc, tmp_path, quiet=True)


TRANSIENT = """
[simulation]
stop_time = "0.5 s"

[inputs."flexor_regulator.p_cmd"]
type = "step"
unit = "Pa"
initial = "0.12 MPa"
final = "0.2 MPa"
time = "0.1 s"

[inputs."extensor_regulator.p_cmd"]
type = "step"
unit = "Pa"
initial = "0.08 MPa"
final = "0.08 MPa"
time = "0.1 s"
"""


@pytest.mark.slow
def test_linearize_the_joint_two_commands_to_angle_and_stiffness(tmp_path):
    from sarcomere.dynamics.equilibrium import solve_equilibrium
    from sarcomere.scenarios.linearize import linearize_scenario

    path = tmp_path / "j.toml"
    path.write_text(_text(kind="transient", fidelity="symmetric", body=TRANSIENT))
    summary = linearize_scenario(path, tmp_path)
    sc = parse_scenario(path.read_text(), "j.toml")
    rec = json.loads((tmp_path / "linearization.json").read_text())
    assert rec["inputs"] == ["flexor_regulator.p_cmd", "extensor_regulator.p_cmd"]
    assert rec["outputs"] == ["joint.theta", "stiffness.K"]
    assert np.array(rec["B"]).shape[1] == 2 and np.array(rec["C"]).shape[0] == 2
    # the static gains against equilibria at commands +-1 kPa (central differences)
    from sarcomere.scenarios.binding import bind

    model = bind(sc).build("symmetric")
    u = {"flexor_regulator.p_cmd": 0.12e6, "extensor_regulator.p_cmd": 0.08e6}
    for name in u:
        eq = [solve_equilibrium(model, {**u, name: u[name] + s * 1e3}) for s in (1, -1)]
        for out in rec["outputs"]:
            fd = (eq[0][out] - eq[1][out]) / 2e3
            assert rec["static_gain"][f"{out}__{name}"] == pytest.approx(fd, rel=1e-4)
    assert summary["metrics"]["slowest_pole_1_s"] < 0  # stable at the operating point


@pytest.mark.slow
def test_joint_study_stiffness_scales_with_the_radius_squared_and_falls_with_n(tmp_path):
    from sarcomere.scenarios.explore.evaluate import evaluate_batch
    from sarcomere.scenarios.explore.spec import load_study

    packaged = load_study("joint-stiffness-map")
    assert {f.name for f in packaged.factors} >= {"n", "joint.r"}
    # a symmetric co-contraction (0 rad throughout: the chains never see the radius)
    base = _text(kind="transient", fidelity="symmetric", body=TRANSIENT)
    base = base.replace("0.12 MPa", "0.08 MPa").replace('final = "0.08 MPa"', 'final = "0.2 MPa"')
    (tmp_path / "base.toml").write_text(base)
    (tmp_path / "s.toml").write_text(
        """
[study]
kind = "grid"
base = "base.toml"

[study.grid]
n = [1, 3]
"joint.r" = ["7 mm", "14 mm"]

[study.metrics]
names = ["peak_pressure"]

[study.metrics.value_at]
low = { signal = "stiffness.K", time = "0 s" }
high = { signal = "stiffness.K", time = "0.5 s" }
"""
    )
    study = load_study(tmp_path / "s.toml")
    got = evaluate_batch(study, range(4))
    assert got.status.tolist() == [0, 0, 0, 0]
    points = study.design().points  # rows: (n, r)
    K = {
        (int(p[0]), round(p[1] * 1e3)): (lo, hi)
        for p, lo, hi in zip(points, got.metrics["low"], got.metrics["high"], strict=True)
    }
    for n in (1, 3):  # at 0 rad the chains do not see the radius: K = r^2 (k_f + k_e)
        for i in (0, 1):
            assert K[n, 14][i] == pytest.approx(4 * K[n, 7][i], rel=1e-6)
    for r in (7, 14):  # longer chains are more compliant; co-contraction stiffens
        assert K[3, r][1] < K[1, r][1]
        assert K[1, r][1] > K[1, r][0] and K[3, r][1] > K[3, r][0]


VALVES = """
[simulation]
stop_time = "0.2 s"
output_interval = "2 ms"

[inputs."flexor_valve.cmd"]
type = "step"
unit = "1"
initial = 0.0
final = 0.6
time = "0.02 s"

[inputs."extensor_valve.cmd"]
type = "step"
unit = "1"
initial = 0.0
final = 0.3
time = "0.02 s"
"""


def test_a_joint_scene_on_pwm_valves_runs_and_flexes(tmp_path):
    sc = _joint(
        kind="transient",
        fidelity="symmetric",
        options='[model.options]\nsupply = "valve_pwm"',
        body=VALVES,
    )
    out = run(sc, tmp_path, quiet=True)
    assert out.results["main"]["joint.theta"][-1] > 0.01
    assert "flexor_valve.cmd" in out.results["main"].names
