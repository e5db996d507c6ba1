"""The APS myofibril model: Jacobians, dimensions, energy, equilibrium, calibration."""

import dataclasses
import math
from fnmatch import fnmatch

import numpy as np
import pint
import pytest

from sarcomere.dynamics.assemblies import hanging_load, isometric
from sarcomere.dynamics.calibration import TARGETS, evaluate
from sarcomere.dynamics.components.aps import THREAD_STRAIN_MAX, APSParams
from sarcomere.dynamics.components.chains import Myofibril
from sarcomere.dynamics.equilibrium import solve_equilibrium
from sarcomere.dynamics.errors import ParameterError, SolverError
from sarcomere.dynamics.signals import Step
from sarcomere.dynamics.simulation.simulate import SolverSettings, simulate

P = "regulator.p_cmd"


@pytest.fixture(scope="module")
def hang3():
    return hanging_load(3, load_kg=0.05)


def test_rest_length_is_the_papers_164p9_mm():
    assert Myofibril("m", 3, APSParams.from_paper()).rest_length == pytest.approx(0.16494, abs=5e-5)


def test_jacobian_matches_finite_differences(hang3):
    m = hang3
    eq = solve_equilibrium(m, {P: 0.06e6})
    rng = np.random.default_rng(1)
    x = eq.x * (1 + 1e-3 * rng.standard_normal(m.nx)) + 1e-6 * rng.standard_normal(m.nx)
    f = m.function("ode")
    A = np.array(m.function("jac")(x=x, z=[], u=eq.u, p=eq.p)["A"])
    for j in range(m.nx):
        h = 1e-6 * max(abs(x[j]), 1e-4)
        xp, xm = x.copy(), x.copy()
        xp[j] += h
        xm[j] -= h
        fd = (
            np.array(f(x=xp, z=[], u=eq.u, p=eq.p)["ode"])
            - np.array(f(x=xm, z=[], u=eq.u, p=eq.p)["ode"])
        ).ravel() / (2 * h)
        scale = np.maximum(np.abs(A[:, j]), np.abs(fd)).max() + 1e-300
        assert np.max(np.abs(A[:, j] - fd)) / scale < 1e-5, m.state_names[j]


def _dimension(ureg, unit):
    return ureg.Quantity(1.0, unit or "dimensionless").to_base_units()


@pytest.mark.parametrize("thermal", ["isothermal", "adiabatic"])
def test_every_equation_is_dimensionally_consistent(thermal):
    """Change the base units (m, kg, s, K) by random factors: if every equation is
    dimensionally consistent, each derivative scales exactly like state/time."""
    m = hanging_load(3, APSParams.from_paper(thermal=thermal), load_kg=0.05)
    ureg = pint.UnitRegistry()
    base = {"[length]": 3.7, "[mass]": 0.61, "[time]": 2.3, "[temperature]": 1.9}

    def factor(unit):
        q = _dimension(ureg, unit)
        f = q.magnitude
        for dim, power in q.dimensionality.items():
            f *= base[dim] ** power
        return f

    eq = solve_equilibrium(m, {P: 0.05e6})
    x = eq.x * 1.01 + 1e-4
    fx = np.array([factor(m.unit(n)) for n in m.state_names])
    fp = np.array([factor(m.unit(n)) for n in m.param_names])
    fu = np.array([factor(m.unit(n)) for n in m.input_names])
    f = m.function("ode")
    ode = np.array(f(x=x, z=[], u=eq.u, p=eq.p)["ode"]).ravel()
    ode_scaled = np.array(f(x=x * fx, z=[], u=eq.u * fu, p=eq.p * fp)["ode"]).ravel()
    np.testing.assert_allclose(ode_scaled, ode * fx / base["[time]"], rtol=1e-9, atol=1e-300)


def _set(m, patterns, value):
    return {n: value for n in m.param_names if any(fnmatch(n, pat) for pat in patterns)}


SEALED = ("*.tube*.C",)
UNDAMPED = ("*.loss.d", "*.actin*.c_s")


def _kicked_run(m, patterns, t_final, dt, extra=None, p_cmd=0.05e6):
    """From the equilibrium at ``p_cmd`` [Pa], kick the load; parameters matching
    ``patterns`` set to 0 (and ``extra`` overrides). Returns the result and the stored
    energy E [J] and dissipation D [W]."""
    eq = solve_equilibrium(m, {P: p_cmd})
    x0 = eq.x.copy()
    x0[m.state_names.index("load.v")] = 0.05
    over = {**_set(m, patterns, 0.0), **(extra or {})}
    res = simulate(
        m,
        t_final,
        inputs={P: p_cmd},
        x0=x0,
        params=over,
        output_interval=dt,
        settings=SolverSettings(rtol=1e-11, atol=1e-14),
    )
    n = len(res.index)
    E, D = m.function("energy").map(n)(
        np.array([res[k] for k in m.state_names]),
        np.zeros((0, n)),
        np.full((1, n), p_cmd),
        np.repeat(m.parameters(over)[:, None], n, 1),
    )[:2]
    return res, np.array(E).ravel(), np.array(D).ravel()


ADIABATIC = ("*.chamber.tau_heat",)  # 1e12 s: no wall heat (the finite default fixes the start)


# chambers: isothermal and adiabatic air, and the instant level's supply potential
# -(p - p_amb) V (conserved while the supply pressure is constant, as here); at the
# regulator's 0.6 MPa every thread is pulled straight, on its end stop (issue 24)
CHAMBERS = [
    ("isothermal", "full", 0.05e6, 0.02),
    ("adiabatic", "full", 0.05e6, 0.02),
    ("isothermal", "instant_pneumatics", 0.05e6, 0.02),
    ("isothermal", "full", 0.6e6, 0.0),  # the bottom thread (the hook's) on its stop
]
STRAINS = ("*.strain_a", "*.strain_b")


@pytest.mark.parametrize(("thermal", "fidelity", "p_cmd", "load"), CHAMBERS)
def test_energy_conserved_with_sealed_chambers_and_no_damping(thermal, fidelity, p_cmd, load):
    p = APSParams.from_paper(thermal=thermal)
    m = hanging_load(2, p, load_kg=load, fidelity=fidelity)
    res, E, D = _kicked_run(m, SEALED + UNDAMPED, 0.3, 1e-3, _set(m, ADIABATIC, 1e12), p_cmd=p_cmd)
    strains = [k for k in m.signal_names if any(fnmatch(k, s) for s in STRAINS)]
    assert (max(res[k].min() for k in strains) > 1e-3) == (p_cmd > 0.5e6)  # on its stop
    kinetic0 = 0.5 * (0.001 + load) * 0.05**2
    assert np.ptp(E) < 1e-6 * kinetic0
    assert np.max(D) == 0.0


@pytest.mark.parametrize(("thermal", "fidelity", "p_cmd", "load"), CHAMBERS)
def test_dissipation_accounts_for_energy_loss(thermal, fidelity, p_cmd, load):
    p = APSParams.from_paper(thermal=thermal)
    m = hanging_load(2, p, load_kg=load, fidelity=fidelity)
    res, E, D = _kicked_run(m, SEALED, 0.2, 2e-5, _set(m, ADIABATIC, 1e12), p_cmd=p_cmd)
    dissipated = np.sum(0.5 * (D[1:] + D[:-1]) * np.diff(res.index))
    loss = E[0] - E[-1]
    assert loss > 0
    assert dissipated == pytest.approx(loss, rel=2e-3)


def test_steady_state_of_dynamics_equals_equilibrium(hang3):
    m = hang3
    eq0 = solve_equilibrium(m, {P: 0.0})
    res = simulate(
        m, 8.0, inputs={P: 0.08e6}, x0=eq0.x, settings=SolverSettings(rtol=1e-10, atol=1e-13)
    )
    eq1 = solve_equilibrium(m, {P: 0.08e6}, guess=eq0)
    assert res.final("myofibril.length") == pytest.approx(eq1["myofibril.length"], rel=1e-8)
    assert res.final("myofibril.aps2.chamber.p_gauge") == pytest.approx(0.08e6, rel=1e-6)


def test_quasi_static_equilibrium_equals_full():
    full = solve_equilibrium(hanging_load(3, load_kg=0.02), {P: 0.1e6})
    qs = solve_equilibrium(hanging_load(3, load_kg=0.02, fidelity="quasi_static"), {P: 0.1e6})
    assert qs["myofibril.length"] == pytest.approx(full["myofibril.length"], rel=1e-9)


def test_calibrated_defaults_meet_the_papers_targets_within_1_percent():
    achieved = evaluate(APSParams.from_paper())
    for key, target in TARGETS.items():
        assert achieved[key] == pytest.approx(target, rel=0.01), key


def test_isometric_force_with_the_bodies_weight_stays_near_f1_not_near_n_f1():
    """With the 8.6 g bodies the upper units are pre-loaded by the lower ones' weight, so
    the units are no longer identical and their nonlinear force-length relations give a
    slightly different F_n; but one tension runs through the chain, so F_n stays within a
    few percent of F_1, nowhere near the paper's 2.35 F_1 and 3.28 F_1 (docs/paper.md)."""
    forces = []
    for n in (1, 2, 3):
        m = isometric(n)
        f0 = solve_equilibrium(m, {P: 0.0})["sensor.f"]
        forces.append(solve_equilibrium(m, {P: 0.1e6})["sensor.f"] - f0)
    assert forces[0] == pytest.approx(0.315, rel=0.01)
    for f in forces[1:]:
        assert f == pytest.approx(forces[0], rel=0.05)


def test_bad_inputs_name_the_value():
    with pytest.raises(ParameterError, match="w0"):
        APSParams.from_paper(w0=0.04)  # anchors wider than the 32 mm thread
    with pytest.raises(ParameterError, match="load_kg"):
        hanging_load(1, load_kg=-0.1)
    with pytest.raises(ParameterError, match="load.m"):
        hanging_load(1).parameters({"load.m": "-5 g"})
    with pytest.raises(ParameterError, match="fidelity"):
        hanging_load(1, fidelity="coarse")


def test_command_outside_the_regulating_range_is_refused(hang3):
    with pytest.raises(
        ParameterError, match=r"regulator.p_cmd.*-200000 Pa at t = 0.*\[0, 600000\]"
    ):
        simulate(hang3, 0.1, inputs={P: -2e5})


def test_equilibrium_reports_a_thread_stretched_until_it_breaks():
    m = hanging_load(1, APSParams.from_paper(A_p=1e-4), load_kg=0.0)  # 38 x the pneumatic area
    with pytest.raises(SolverError, match=r"strain_. = .* outside its physical domain.*breaks"):
        solve_equilibrium(m, {P: 6.0e5})


@pytest.mark.parametrize("n", [3, *np.random.default_rng(24).integers(1, 13, 2).tolist()])
def test_a_step_to_the_regulators_maximum_runs_onto_the_threads_end_stop(n):
    """Issue 24: at 0.3-0.8 MPa the threads were pulled straight and the run stopped; a
    straight thread now takes the expansion force through its stiffness ``k_thread``,
    and the run settles on the one equilibrium (a loaded V stays a V)."""
    m = hanging_load(n, load_kg=0.0)
    p = APSParams.from_paper()
    rest = solve_equilibrium(m, {P: 0.0})
    p_max = m.variables[P].high
    res = simulate(m, 10.0, inputs={P: Step(final=p_max, time=0.1)}, x0=rest.x)
    assert res.final("regulator.p_out") == pytest.approx(p_max, rel=1e-6)
    length = res.final("myofibril.length")
    assert n * p.A_band < length < 0.65 * rest["myofibril.length"]  # near full contraction
    # on the equilibrium's branch (a straight-locked one was 6 % shorter): the mean of
    # the lightly damped chain's swing over its last 2 s
    swing = res["myofibril.length"][res.index >= 8.0]
    assert swing.mean() == pytest.approx(
        solve_equilibrium(m, {P: p_max})["myofibril.length"], rel=1e-4
    )
    strains = [k for k in m.signal_names if fnmatch(k, "*.strain_?")]
    assert max(res[k].max() for k in strains) < THREAD_STRAIN_MAX
    # the hook's thread (its band carries 1 g) on its stop, holding most of the force
    strain = res.final(f"myofibril.actin{n}.strain_a")
    f_exp = res.final(f"myofibril.aps{n}.chamber.p_gauge") * p.A_p - res.final(
        f"myofibril.aps{n}.yeoh.f"
    )
    assert 0.5 * f_exp < 2 * p.k_thread * strain * p.l <= f_exp


def test_equilibrium_from_scratch_stays_on_the_physical_branch():
    """A direct solve at 20 kPa once found lambda < 0 (a root outside the domain)."""
    m = hanging_load(3, load_kg=0.05)
    e = solve_equilibrium(m, {P: 0.02e6})
    assert all(0.5 < e[f"myofibril.aps{i}.yeoh.lambda"] < 1.5 for i in (1, 2, 3))
    assert e["myofibril.length"] < solve_equilibrium(m, {P: 0.0})["myofibril.length"]


def test_solver_failure_names_time_and_cause(hang3):
    with pytest.raises(SolverError, match=r"too many steps.*t = "):
        simulate(hang3, 1.0, inputs={P: 1e5}, settings=SolverSettings(max_steps=5, rtol=1e-8))


def test_r1_rest_geometry():
    p = APSParams.from_paper()
    assert math.degrees(math.acos(p.w0 / p.l)) == pytest.approx(51.32, abs=0.01)


@pytest.mark.filterwarnings(
    "ignore::sarcomere.dynamics.plausibility.PlausibilityWarning"
)  # weightless bodies
def test_symmetric_reduction_is_exact_for_weightless_bodies():
    """With weightless bodies every I-band carries one tension and every unit the same
    expansion: one representative unit times n must give the full chain's equilibrium,
    up to the slack regularisation (``eps^2 k_s / (4 T)``, about 2e-8 m per I-band)."""
    p = APSParams.from_paper(m_body=1e-9)
    for n in (1, 3, 7):
        full = solve_equilibrium(hanging_load(n, p, 0.05), {P: 0.08e6})
        sym = solve_equilibrium(hanging_load(n, p, 0.05, fidelity="symmetric"), {P: 0.08e6})
        assert sym["myofibril.length"] == pytest.approx(full["myofibril.length"], abs=2e-7)
        assert hanging_load(n, p, 0.05, fidelity="symmetric").nx == 6


def test_long_chain_equilibrium_settles_first_where_newton_alone_fails():
    m = hanging_load(30, load_kg=0.05)
    e = solve_equilibrium(m, {P: 0.0})
    assert (
        np.max(np.abs(e.x[[m.state_names.index(n) for n in m.state_names if n.endswith(".v")]]))
        < 1e-9
    )
    assert 30 * 0.0549 < e["myofibril.length"] < 30 * 0.07


def test_input_without_a_casadi_expression_is_refused(hang3):
    with pytest.raises(ParameterError, match="casadi"):
        simulate(hang3, 0.1, inputs={P: lambda t: 1e5})


def _tared_force(m):
    e0 = solve_equilibrium(m, {P: 0.0})
    return solve_equilibrium(m, {P: 0.1e6}, guess=e0)["sensor.f"] - e0["sensor.f"]


def test_spring_fixture_reads_less_than_rigid_and_gap_less_still():
    rigid = _tared_force(isometric(1))
    stiff = _tared_force(isometric(1, fixture_stiffness=1e5))
    soft = _tared_force(isometric(1, fixture_stiffness=200.0))
    gap = _tared_force(isometric(1, fixture_stiffness=2e3, fixture_gap=2e-3))
    assert soft < stiff < rigid
    assert stiff == pytest.approx(rigid, rel=0.05)
    assert gap < _tared_force(isometric(1, fixture_stiffness=2e3))
    # on a compliant fixture a second unit adds far less than a second 0.315 N
    assert _tared_force(isometric(2, fixture_stiffness=200.0)) < 1.2 * soft


def test_aps_parameters_carry_unit_range_and_source_per_field():
    with pytest.raises(ParameterError, match=r"'C1' = -1000.0.*\(0, inf\) Pa"):
        APSParams.from_paper(C1=-1e3)
    with pytest.raises(ParameterError, match=r"'b_tube' = 1.0.*allowed: \[0, 1\)$"):
        APSParams(b_tube=1.0)
    with pytest.raises(ParameterError, match=r"'k_s' = '400 N/m'"):
        APSParams(k_s="400 N/m")
    with pytest.raises(ParameterError, match=r"thermal.*'isothermal', 'adiabatic'"):
        APSParams(thermal="polytropic")
    assert APSParams.unit("k_s") == "N/m" and APSParams.unit("C_tube") == "m^3/(s*Pa)"
    for name in APSParams.numeric_fields():
        meta = {f.name: f.metadata for f in dataclasses.fields(APSParams)}[name]
        assert meta["source"] and meta["description"], name
    # the model's parameters take their unit from the same field
    m = hanging_load(1)
    assert m.unit("myofibril.actin0.k_s") == APSParams.unit("k_s")
    assert m.unit("myofibril.aps1.chamber.A") == APSParams.unit("A_p")


def test_adiabatic_chambers_settle_at_ambient_temperature_through_the_wall_heat():
    """With a finite wall heat exchange the adiabatic APS has one equilibrium, at the
    ambient temperature, identical to the isothermal one; a step heats the air first."""
    iso = solve_equilibrium(hanging_load(1, load_kg=0.05), {P: 0.05e6})
    m = hanging_load(1, APSParams.from_paper(thermal="adiabatic"), load_kg=0.05)
    eq = solve_equilibrium(m, {P: 0.05e6})
    assert eq["myofibril.aps1.chamber.T"] == pytest.approx(293.15, rel=1e-9)
    assert eq["myofibril.length"] == pytest.approx(iso["myofibril.length"], rel=1e-9)
    e0 = solve_equilibrium(m, {P: 0.0})
    res = simulate(m, 0.1, inputs={P: 0.05e6}, x0=e0.x, output_interval=1e-3)
    assert res["myofibril.aps1.chamber.T"].max() > 300.0  # compression heating on filling
