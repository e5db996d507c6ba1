"""The set-ups: fixture placement, chain compliance, shared environment, options, arguments."""

import math
import warnings

import casadi as cs
import numpy as np
import pytest

from sarcomere.dynamics.assemblies import HOOK_MASS_KG, hanging_load, isometric
from sarcomere.dynamics.components.aps import APSParams
from sarcomere.dynamics.equilibrium import solve_equilibrium
from sarcomere.dynamics.errors import ParameterError
from sarcomere.dynamics.simulation.simulate import SolverSettings, simulate

P = "regulator.p_cmd"
G = 9.80665


def _tared(m):
    e0 = solve_equilibrium(m, {P: 0.0})
    return solve_equilibrium(m, {P: 0.1e6}, guess=e0)["sensor.f"] - e0["sensor.f"], e0


@pytest.mark.parametrize("n", [1, 2, 3])
def test_isometric_sensor_is_attached_to_the_hanging_chain_without_pretension(n):
    """The fixture sits where the chain hangs at rest at 0 MPa: the sensor reads zero and
    no I-band is slack (at the geometric length the bottom band was 0.6-3.4 mm slack)."""
    e0 = solve_equilibrium(isometric(n), {P: 0.0})
    assert abs(e0["sensor.f"]) < 1e-9
    spring = solve_equilibrium(isometric(n, fixture_stiffness=2e3), {P: 0.0})
    assert abs(spring["sensor.f"]) < 1e-9
    # the bottom band (one V, 2 k_s) carries the 1 g hook: softplus(e) = T / (2 k_s) > 0
    p = APSParams.from_paper()
    sp = HOOK_MASS_KG * G / (2 * p.k_s)
    assert e0[f"myofibril.actin{n}.e"] == pytest.approx(sp - p.eps_slack**2 / (4 * sp), rel=1e-6)


@pytest.mark.filterwarnings(
    "ignore::sarcomere.dynamics.plausibility.PlausibilityWarning"
)  # weightless bodies
def test_identical_units_in_series_give_the_same_isometric_force_for_any_n():
    """One tension through identical units on a rigid fixture: F_n = F_1. Weightless bodies
    make the units identical; what remains is the slack regularisation near the hook's
    9.8 mN pre-load (k_s eps_slack = 7 mN acting over the first ~10 um of stretch): 0.2 %.
    (With the chain compliance (n + 1)/k_s, F_n was F_1 2n/(n + 1).)"""
    p = APSParams.from_paper(m_body=1e-9)
    forces = [_tared(isometric(n, p))[0] for n in (1, 2, 3)]
    for f in forces[1:]:
        assert f == pytest.approx(forces[0], rel=2e-3)


@pytest.mark.filterwarnings(
    "ignore::sarcomere.dynamics.plausibility.PlausibilityWarning"
)  # weightless bodies
@pytest.mark.parametrize("n", [1, 2, 3])
def test_chain_compliance_is_n_over_k_s(n):
    """n - 1 inner I-bands (two V's, k_s) and two end bands (one V, 2 k_s): the chain's
    series compliance is n / k_s. A very stiff SPA (A_r x 1e6: the threads' pull on the
    expansion adds 2e-5 of the compliance) and weightless bodies leave only the bands; the
    load increment is 1 g on a chain taut under 200 g (there the softplus slope of the end
    bands differs from 1 by 1.2e-5)."""
    p = APSParams.from_paper(m_body=1e-9, A_r=1e6 * APSParams().A_r)
    m = hanging_load(n, p, load_kg=0.2)
    e1 = solve_equilibrium(m, {P: 0.0})
    e2 = solve_equilibrium(m, {P: 0.0}, {"load.m": HOOK_MASS_KG + 0.201}, guess=e1)
    compliance = (e2["myofibril.length"] - e1["myofibril.length"]) / (1e-3 * G)
    assert compliance == pytest.approx(n / p.k_s, rel=1e-4)


def test_slack_threads_neither_push_nor_damp():
    """Venting (vent-0g): the SPAs relax faster than the chain falls and the threads go
    slack. Tension-only means T >= 0 exactly (it is k softplus(e + c/k de/dt)); the damping
    used to push with -0.015 N on a thread 0.23 mm slack."""
    m = hanging_load(3, load_kg=0.0, regulator_tau=0.005)
    eq = solve_equilibrium(m, {P: 0.1e6})
    res = simulate(
        m,
        0.3,
        inputs={P: 0.0},
        x0=eq.x,
        output_interval=2e-4,
        settings=SolverSettings(rtol=1e-8, atol=1e-11),
    )
    assert min(res[f"myofibril.actin{i}.e"].min() for i in range(4)) < -5e-4  # slack
    assert min(res[f"myofibril.actin{i}.T"].min() for i in range(4)) >= 0.0


def test_one_ambient_pressure_for_the_whole_model():
    """Overriding ambient.p moves the regulator's and every chamber's reference together
    (a regulator-only p_amb left the chambers at -6.3 kPa gauge)."""
    m = hanging_load(3, load_kg=0.02)
    assert [n for n in m.param_names if n.endswith(".p_amb")] == []
    eq = solve_equilibrium(m, {P: 0.0}, {"ambient.p": 95e3})
    for i in (1, 2, 3):
        assert abs(eq[f"myofibril.aps{i}.chamber.p_gauge"]) < 1e-6
        assert eq[f"myofibril.aps{i}.chamber.p"] == pytest.approx(95e3, rel=1e-12)


def test_gravity_is_one_parameter():
    m = hanging_load(2, load_kg=0.05)
    assert "ambient.g" in m.param_names
    assert [n for n in m.param_names if n.endswith(".g")] == [
        "ambient.g",
        "myofibril.aps1.expansion.g",
        "myofibril.aps2.expansion.g",
    ]
    light = solve_equilibrium(m, {P: 0.0}, {"ambient.g": 0.5 * G})
    heavy = solve_equilibrium(m, {P: 0.0})
    assert light["load.s"] < heavy["load.s"]


@pytest.mark.parametrize("setup", [hanging_load, isometric])
def test_regulator_range_is_published_and_saturation_optional(setup):
    for saturate in (True, False):
        m = setup(1, saturate=saturate)
        var = m.variables[P]
        assert (var.low, var.high) == (0.0, 6e5)
    plant, optimiser = setup(1), setup(1, saturate=False)
    u = cs.SX.sym("u")
    slopes = []
    for m in (plant, optimiser):
        rate = m.function("ode")(x=m.x0(), z=m.z0(), u=u, p=m.parameters())["ode"][0]
        slopes.append(float(cs.Function("d", [u], [cs.jacobian(rate, u)])(7e5)))
    assert slopes[0] == 0.0 and slopes[1] > 0.0
    with pytest.raises(ParameterError, match="saturate"):
        setup(1, saturate="yes")


@pytest.mark.parametrize("setup", [hanging_load, isometric])
def test_flow_law_is_chosen_from_the_set_up(setup):
    exact, smooth = setup(1, flow_law="iso6358"), setup(1, flow_law="smooth")
    e1 = solve_equilibrium(exact, {P: 0.05e6})
    e2 = solve_equilibrium(smooth, {P: 0.05e6})
    assert e2["myofibril.length"] == pytest.approx(e1["myofibril.length"], rel=1e-9)
    # the laws differ in the laminar region: a 50 Pa drop across the tube
    x = e1.x.copy()
    x[exact.state_names.index("myofibril.aps1.chamber.m_air")] *= 1 - 50 / 151325
    flows = []
    for m in (exact, smooth):
        y = np.array(m.function("y")(x=x, z=e1.z, u=e1.u, p=e1.p)["y"]).ravel()
        flows.append(y[m.output_names.index("myofibril.tube1.m_flow")])
    assert flows[0] > 0 and flows[1] > 0
    assert flows[1] != pytest.approx(flows[0], rel=1e-3)
    with pytest.raises(ParameterError, match=r"flow_law.*'iso6358', 'smooth'"):
        setup(1, flow_law="laminar")


def test_start_values_follow_parameter_changes():
    m = hanging_load(2)
    x_default = m.x0()
    p = m.parameters({"myofibril.aps1.chamber.V0": 8e-6, "myofibril.actin0.l": 34e-3})
    x = m.x0(p)
    i_m = m.state_names.index("myofibril.aps1.chamber.m_air")
    assert x[i_m] == pytest.approx(2 * x_default[i_m], rel=1e-12)
    i_s = m.state_names.index("myofibril.aps1.body.s")
    r1 = math.sqrt(0.017**2 - 0.010**2)  # the top V with a 34 mm thread
    assert x[i_s] == pytest.approx(0.015 + r1, rel=1e-12)
    amb = m.x0(m.parameters({"ambient.p": 95e3}))
    assert amb[i_m] == pytest.approx(x_default[i_m] * 95e3 / 101325, rel=1e-12)


def test_set_up_arguments_take_quantities_or_name_the_bad_one():
    a = hanging_load(1, load_kg="50 g", regulator_tau="20 ms")
    assert a.variables["load.m"].value == pytest.approx(HOOK_MASS_KG + 0.05)
    assert a.variables["regulator.tau"].value == pytest.approx(0.02)
    with pytest.raises(ParameterError, match=r"load_kg.*'50 m'"):
        hanging_load(1, load_kg="50 m")
    with pytest.raises(ParameterError, match=r"fixture_stiffness.*-1.*\(0, inf\) N/m"):
        isometric(1, fixture_stiffness=-1.0)
    with pytest.raises(ParameterError, match=r"regulator_tau"):
        isometric(1, regulator_tau="0 s")
    assert isometric(1, fixture_stiffness="2 kN/m").variables["fixture_spring.c"].value == 2e3
    with pytest.raises(ParameterError, match=r"fixture_gap.*rigid"):
        isometric(1, fixture_gap="1 mm")


def test_chain_longer_than_the_level_handles_is_refused_at_once(monkeypatch):
    """The measured per-level limits (assemblies.N_LIMITS) hold at the API, before building."""
    from sarcomere.dynamics import assemblies
    from sarcomere.dynamics.assemblies import N_LIMITS

    def no_build(*args, **kwargs):
        raise AssertionError("a chain over the limit was built")

    for cls in ("Myofibril", "SymmetricMyofibril", "GroupedMyofibril"):
        monkeypatch.setattr(assemblies, cls, no_build)
    for level, limit in N_LIMITS.items():
        with pytest.raises(ParameterError, match=rf"'n' = {limit + 1} .*\[1, {limit}\]"):
            hanging_load(limit + 1, fidelity=level)


@pytest.mark.parametrize("fidelity", ["full", "grouped", "symmetric"])
def test_a_chain_that_would_invert_leaves_the_physical_domain(fidelity):
    """The length is bounded below by 0: a load thrown up at 1000 m/s is reported with the
    signal named, not integrated through a chain of negative length."""
    from sarcomere.dynamics.errors import SolverError

    model = hanging_load(3, load_kg=0.05, fidelity=fidelity)
    rest = solve_equilibrium(model, {"regulator.p_cmd": 0.0})
    x0 = dict(zip(model.state_names, rest.x, strict=True))
    x0["load.v"] = -1000.0
    with pytest.raises(SolverError, match="myofibril.length"):
        simulate(model, 0.01, x0=x0)


def test_the_split_muscle_and_load_meet_the_sprung_load_equilibrium():
    """force_driven pulled by the load's weight, and spring_mass_load driven at its end,
    are the two halves of sprung_load: the same length and the same coupling force."""
    from sarcomere.dynamics.assemblies import (
        force_driven,
        spring_mass_load,
        sprung_load,
    )

    mono = solve_equilibrium(sprung_load(2, mass_kg="30 g"), {"regulator.p_cmd": 4e4})
    weight = mono["sensor.f"]
    assert weight == pytest.approx(0.03 * G, rel=1e-9)
    muscle = solve_equilibrium(force_driven(2), {"regulator.p_cmd": 4e4, "pull.f": weight})
    assert muscle["end.s"] == pytest.approx(mono["end.s"], rel=1e-9)
    load = solve_equilibrium(spring_mass_load("30 g"), {"drive.s": muscle["end.s"]})
    assert load["mass.s"] == pytest.approx(mono["mass.s"], rel=1e-9)
    with pytest.raises(ParameterError, match="stiffness"):
        spring_mass_load(stiffness="-1 N/m")


def test_an_implausible_load_or_aps_parameter_warns_from_python():
    """Issue 24: `hanging_load(load_kg=50)` (a 2.3 m muscle) and `k_s = 2e-12 N/m` (a
    9e11 m chain) ran without a word from Python; scenes warned."""
    from sarcomere.dynamics import PlausibilityWarning

    with pytest.warns(PlausibilityWarning, match=r"load_kg = 50 kg is outside the plaus") as w:
        hanging_load(1, load_kg=50)
    assert w[0].filename == __file__  # at the caller's line
    aps = APSParams.from_paper(k_s=2e-12)
    with pytest.warns(PlausibilityWarning, match=r"params.k_s = 2e-12 N/m is more than 1000"):
        hanging_load(1, aps)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        hanging_load(1, APSParams.from_paper(k_s=800.0), load_kg=0.1)  # plausible: silent


@pytest.mark.parametrize("name", ["ambient.T", "ambient.p", "ambient.R"])
def test_an_impossible_ambient_is_refused_naming_the_range(name):
    """Issue 24: `ambient.T = 0 K` passed."""
    model = hanging_load(1)
    with pytest.raises(ParameterError, match=rf"'{name}' = 0.0 .*allowed: \[1e-12, inf\)"):
        model.parameters({name: 0.0})
