"""On/off valves, the PWM input law and the valve supply (issue 26)."""

import casadi as cs
import numpy as np
import pytest

from sarcomere.dynamics.assemblies import hanging_load, isometric
from sarcomere.dynamics.equilibrium import solve_equilibrium
from sarcomere.dynamics.errors import ParameterError
from sarcomere.dynamics.signals import Ramp, Staircase, Step
from sarcomere.dynamics.simulation.pwm import PWM
from sarcomere.dynamics.simulation.simulate import SolverSettings, simulate
from sarcomere.dynamics.simulation.simulator import Simulator

U = "valve.cmd"
TIGHT = SolverSettings(rtol=1e-10, atol=1e-13)


@pytest.fixture(scope="module")
def pwm3():
    return hanging_load(2, load_kg=0.02, supply="valve_pwm", valve={"frequency": 50})


def _const(v):
    return Step(final=v, initial=v)


def test_pulse_train_values_and_edges_with_delay_and_a_duty_change():
    pwm = PWM(frequency=50.0, delay=2e-3)
    duty = Staircase(levels=(0.25, 0.6), dwell=0.05)  # 0.6 from t = 0.05 s
    train = pwm.law(duty, _const(0.0), 0.0)
    t = np.linspace(0.0, 0.1, 100_001)[:-1] + 0.5e-6  # never on an edge
    s = t - 2e-3
    d = np.where(s >= 0.0, np.where(s >= 0.05, 0.6, 0.25), 0.0)
    phase = np.mod(s, 0.02)
    expected = (phase < d * 0.02).astype(float)
    assert np.array_equal(train(t), expected)
    edges = train.breakpoints(0.0, 0.1)
    jumps = t[1:][np.diff(expected) != 0]
    # every jump of the command lies on an edge (to the grid's 1 us)
    assert all(np.min(np.abs(np.array(edges) - j)) < 1.1e-6 for j in jumps)
    assert edges[:4] == pytest.approx([0.002, 0.007, 0.022, 0.027])


def test_minimum_on_time_drops_short_pulses_and_gaps():
    pwm = PWM(frequency=100.0, min_on=1e-3)
    assert pwm.effective_duty(np.array([0.05, 0.1, 0.5, 0.9, 0.95])).tolist() == [
        0.0,
        0.1,
        0.5,
        0.9,
        1.0,
    ]


@pytest.mark.parametrize(
    ("kwargs", "name"),
    [
        ({"frequency": 0.0}, "pwm_frequency"),
        ({"frequency": 50.0, "min_on": 0.011}, "pwm_min_on"),
        ({"frequency": 50.0, "delay": 0.03}, "valve_delay"),
        ({"level": "smooth"}, "valve_level"),
    ],
)
def test_bad_pwm_settings_are_refused_by_name(kwargs, name):
    with pytest.raises(ParameterError) as err:
        PWM(**kwargs)
    assert err.value.name == name


def test_bad_supply_options_are_refused_by_name():
    with pytest.raises(ParameterError, match="supply"):
        hanging_load(1, supply="bellows")
    with pytest.raises(ParameterError, match="valve options"):
        hanging_load(1, supply="valve_pwm", valve={"frequence": 50})
    with pytest.raises(ParameterError, match="valve.ways"):
        hanging_load(1, supply="valve_pwm", valve={"ways": "5/2"})
    with pytest.raises(ParameterError, match="no valve options"):
        hanging_load(1, valve={"frequency": 50})
    with pytest.raises(ParameterError, match="regulator_p_max"):
        hanging_load(1, supply="valve_pwm", regulator_p_max=3e5)


def test_a_continuously_varying_duty_is_refused(pwm3):
    sim = Simulator(pwm3)
    sim.reset()
    with pytest.raises(ParameterError, match="piecewise-constant"):
        sim.step({U: Ramp(final=0.5, duration=0.1)}, 0.1)


@pytest.mark.parametrize("method", ["cvodes", pytest.param("scipy_radau", marks=pytest.mark.slow)])
def test_the_valve_opening_follows_the_pulse_train_exactly(pwm3, method):
    """Each method stops at every edge: the opening, a first-order lag of the command
    (independent of the pressures), matches its closed form; one step across an edge
    would smear it by the step's length."""
    tau = pwm3.variables["valve.tau"].value
    pwm = pwm3.modulators[U]
    eq = solve_equilibrium(pwm3, {U: 0.3})
    x0 = eq.x.copy()
    x0[pwm3.state_names.index("valve.x")] = 0.0
    settings = SolverSettings(method=method, rtol=1e-10, atol=1e-13)
    res = simulate(pwm3, 0.1, inputs={U: 0.3}, x0=x0, output_interval=1e-4, settings=settings)
    # closed form: x' = (c - x)/tau piecewise, from 0 at t = 0 (command 0 before the delay)
    train = pwm.law(_const(0.3), _const(0.3), 0.0)
    edges = [0.0, *train.breakpoints(0.0, 0.1), 0.1]
    t, x, xa = res.index, np.empty_like(res.index), 0.0
    for a, b in zip(edges[:-1], edges[1:], strict=True):
        c = train(0.5 * (a + b))
        inside = (t >= a) & (t <= b)
        x[inside] = c + (xa - c) * np.exp(-(t[inside] - a) / tau)
        xa = c + (xa - c) * np.exp(-(b - a) / tau)
    assert np.max(np.abs(res["valve.x"] - x)) < 1e-7
    assert np.all(res[U] == 0.3)  # the rows show the duty as given


def test_averaged_opening_is_the_effective_duty_and_the_equilibrium_holds():
    m = hanging_load(
        2, load_kg=0.02, supply="valve_pwm", valve={"level": "averaged", "min_on": 2e-3}
    )
    eq = solve_equilibrium(m, {U: 0.5})
    res = simulate(m, 0.05, inputs={U: 0.5}, x0=eq.x, output_interval=1e-2, settings=TIGHT)
    assert np.max(np.abs(res["myofibril.length"] - eq["myofibril.length"])) < 1e-9
    res = simulate(m, 0.05, inputs={U: 0.05}, x0=eq.x, output_interval=1e-2)
    assert res["valve.x"][-1] < 0.5 * np.exp(-0.05 / 1.5e-3) + 1e-9  # 1 ms pulse: none


def _energy_balance(m, duty, t_end, x0):
    """``E(t_end) - E(0) + int D dt`` and ``int power dt`` [J] of the switched run,
    integrated as quadratures beside the model's ODE (CVODES, rtol 1e-12) between the
    PWM's edges: independent of the Simulator."""
    f, en, sig = m.function("ode"), m.function("energy"), m.function("signals")
    x, u = cs.SX.sym("x", m.nx), cs.SX.sym("u", 1)
    p = m.parameters()
    power = sig(x, cs.SX(0, 1), u, p)[m.signal_names.index("valve_source.power")]
    rhs = cs.vertcat(f(x, cs.SX(0, 1), u, p), en(x, cs.SX(0, 1), u, p)[1], power)
    q = cs.SX.sym("q", 2)
    ode = {"x": cs.vertcat(x, q), "p": u, "ode": rhs}
    opts = {"reltol": 1e-12, "abstol": 1e-15, "max_num_steps": 200_000}
    train = m.modulators[U].law(_const(duty), _const(duty), 0.0)
    edges = [0.0, *train.breakpoints(0.0, t_end), t_end]
    w = np.concatenate([x0, [0.0, 0.0]])
    for a, b in zip(edges[:-1], edges[1:], strict=True):
        step = cs.integrator("seg", "cvodes", ode, 0.0, b - a, opts)
        w = np.array(step(x0=w, p=train(0.5 * (a + b)))["xf"]).ravel()
    E0 = float(en(x0, np.zeros(0), duty, p)[0])
    E1 = float(en(w[: m.nx], np.zeros(0), duty, p)[0])
    return E1 - E0 + w[m.nx], w[m.nx + 1]


@pytest.mark.parametrize("ways", ["3/2", "2/2"])
def test_energy_balance_closes_with_the_switched_valve(ways):
    """The supply's work = the stored energy's change + the dissipated energy (valve,
    tubes, dampers), to 1e-9 of the work, through 5 PWM periods from rest."""
    m = hanging_load(2, load_kg=0.02, supply="valve_pwm", valve={"ways": ways})
    # at rest, vented (a closed 2/2 valve has no equilibrium of its own: any pressure)
    x0 = solve_equilibrium(hanging_load(2, load_kg=0.02, supply="valve_pwm"), {U: 0.0}).x
    lhs, work = _energy_balance(m, 0.4, 0.1, x0)
    assert work > 1e-3
    assert abs(lhs - work) < 1e-9 * work


def test_isometric_takes_the_valve_supply_too():
    m = isometric(1, supply="valve_pwm", valve={"level": "averaged"})
    assert m.input_names == [U] and m.modulators[U].level == "averaged"
    assert solve_equilibrium(m, {U: 0.5})["sensor.f"] > 0.5
