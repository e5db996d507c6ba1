"""The stepping Simulator: inputs, readouts, failures, caches and the step Functions."""

from __future__ import annotations

import math
from dataclasses import dataclass

import casadi as cs
import numpy as np
import pytest

import sarcomere.dynamics.simulation as simulation_pkg
from sarcomere.dynamics import Simulator, SolverSettings, simulate
from sarcomere.dynamics.errors import ParameterError, SolverError
from sarcomere.dynamics.modeling.component import Component, System
from sarcomere.dynamics.signals import Ramp, Sine, Staircase, Step, Table

TAU_S = 0.2
P_MAX = 2e5


class Lag(Component):
    """``tau dx/dt = u - x``: input ``u`` [Pa] in [0, P_MAX], lagged ``x`` [Pa] <= x_high."""

    def __init__(self, name: str, tau: float, x_high: float) -> None:
        super().__init__(name)
        self.tau, self.x_high = tau, x_high

    def build(self, b) -> None:
        tau = b.parameter("tau", self.tau, "s", "time constant", low=1e-9)
        u = b.input("u", "Pa", "command", low=0.0, high=P_MAX)
        x = b.state("x", 0.0, "Pa", "lagged command", high=self.x_high)
        b.der(x, (u - x) / tau)


def lag_model(tau: float = TAU_S, x_high: float = math.inf):
    sys = System("lag")
    sys.add(Lag("lag", tau, x_high))
    return sys.flatten()


def exact(u: float, h: float, x0: float = 0.0, tau: float = TAU_S) -> float:
    return u + (x0 - u) * math.exp(-h / tau)


METHODS = {
    "cvodes": SolverSettings("cvodes", rtol=1e-10, atol=1e-8),
    "rk4": SolverSettings("rk4", step=1e-3),
    "radau_fixed": SolverSettings("radau_fixed", step=1e-2, rtol=1e-8, atol=1e-6),
    "collocation": SolverSettings("collocation", step=1e-2, rtol=1e-8, atol=1e-6),
    "scipy_radau": SolverSettings("scipy_radau", rtol=1e-10, atol=1e-8),
}


# --- stepping and reading ---------------------------------------------------------------
@pytest.mark.parametrize("method", list(METHODS))
def test_closed_loop_equals_simulate_of_the_same_staircase(method):
    """A loop of steps with a new constant u each and ``simulate`` of the staircase of
    the same levels are one path: equal to round-off, and equal to the closed form."""
    model = lag_model()
    rng = np.random.default_rng(1)
    levels = rng.uniform(0, P_MAX, 8)
    sim = Simulator(model, METHODS[method], t0=0.0)
    xs, x = [], 0.0
    for level in levels:
        sim.step({"lag.u": level}, 0.05)
        xs.append(sim.x[0])
        x = exact(level, 0.05, x)
        assert sim.x[0] == pytest.approx(x, rel=1e-6)
    assert sim.t == pytest.approx(0.4)
    res = simulate(
        model,
        0.4,
        {"lag.u": Staircase(levels=tuple(levels), dwell=0.05, unit="Pa")},
        settings=METHODS[method],
        output_interval=0.05,
    )
    np.testing.assert_allclose(res["lag.x"][1:], xs, rtol=1e-12)


def test_u_as_vector_mapping_or_unit_string_is_the_same_input():
    model = lag_model()
    runs = []
    for u in ([1e5], {"lag.u": 1e5}, {"lag.u": "0.1 MPa"}, {"lag.u": "100 kPa"}):
        sim = Simulator(model, t0=0.0)
        sim.step(u, "50 ms")
        runs.append(sim.x[0])
    assert runs[0] == pytest.approx(exact(1e5, 0.05), rel=1e-5)  # default rtol 1e-6
    assert runs == [runs[0]] * 4


def test_a_mapping_that_leaves_an_input_out_keeps_the_last_applied_value():
    model = lag_model()
    sim = Simulator(model, t0=0.0)
    sim.step({"lag.u": 1e5}, 0.1)
    sim.step(None, 0.1)
    sim.step({}, 0.1)
    assert sim.u[0] == 1e5
    assert sim.x[0] == pytest.approx(exact(1e5, 0.3), rel=1e-6)


def test_signals_over_a_step_are_integrated_as_functions_of_time():
    """A ramp given to ``step`` is not held: the result is the ramp's closed form."""
    model = lag_model()
    sim = Simulator(model, METHODS["cvodes"], t0=0.0)
    ramp = Ramp(final=1e5, duration=1.0, unit="Pa")
    for _ in range(4):
        sim.step({"lag.u": ramp}, 0.25)
    t = 1.0
    slope = 1e5
    assert sim.x[0] == pytest.approx(slope * (t - TAU_S * (1 - math.exp(-t / TAU_S))), rel=1e-7)
    assert sim.u[0] == pytest.approx(1e5)


def test_readouts_after_a_step():
    model = lag_model()
    sim = Simulator(model)
    sim.reset(x0={"lag.x": 5e4}, params={"lag.tau": "100 ms"})
    sim.step([1e5], 0.1)
    assert sim.t == pytest.approx(0.1)
    assert sim.signal("lag.x") == pytest.approx(exact(1e5, 0.1, 5e4, tau=0.1), rel=1e-6)
    assert sim.signals(["lag.u", "lag.x"]) == {"lag.u": 1e5, "lag.x": sim.x[0]}
    assert set(sim.signals()) == set(model.signal_names)
    with pytest.raises(ParameterError, match="signals"):
        sim.signal("lag.y")


def test_reset_starts_again():
    model = lag_model()
    sim = Simulator(model, t0=0.0)
    sim.step([1e5], 0.1)
    sim.reset()
    assert (sim.t, sim.x[0], sim.u[0], sim.stats) == (0.0, 0.0, 0.0, {})


def test_step_before_a_start_is_refused():
    """Built without a start, the simulator refuses to step until reset() chooses one
    (it used to integrate silently from the start values: a hanging load in free fall)."""
    sim = Simulator(lag_model())
    with pytest.raises(ParameterError, match=r"'x0' = None.*never started.*reset\(x0="):
        sim.step([1e5], 0.1)
    with pytest.raises(ParameterError, match="never started"):
        sim.advance([1e5], [0.1])
    sim.reset()
    sim.step([1e5], 0.1)
    assert sim.x[0] == pytest.approx(exact(1e5, 0.1), rel=1e-6)
    started = Simulator(lag_model(), x0=[5e4])  # a start given to the constructor
    started.step([1e5], 0.1)
    assert started.x[0] == pytest.approx(exact(1e5, 0.1, 5e4), rel=1e-6)


# --- bad input: one-line errors ----------------------------------------------------------
def test_x0_of_the_wrong_length_names_x0_its_length_and_the_states():
    sim = Simulator(lag_model(), t0=0.0)
    with pytest.raises(ParameterError, match=r"'x0' = '2 values'.*1 values for \['lag.x'\]"):
        sim.reset(x0=[1.0, 2.0])
    with pytest.raises(ParameterError, match=r"'x0' = 'lag.y'"):
        sim.reset(x0={"lag.y": 1.0})
    with pytest.raises(ParameterError, match="x0"):
        simulate(lag_model(), 0.1, x0=np.zeros(3))


def test_bad_inputs_and_steps_are_refused_with_the_name():
    sim = Simulator(lag_model(), t0=0.0)
    with pytest.raises(ParameterError, match=r"'lag.u' = '300000 Pa at t = 0 s'.*\[0, 200000\]"):
        sim.step({"lag.u": 3e5}, 0.1)
    with pytest.raises(ParameterError, match=r"'lag.u' = '-0.05 m'.*wrong dimension"):
        sim.step({"lag.u": "-0.05 m"}, 0.1)
    with pytest.raises(ParameterError, match=r"'u' = '2 values'.*\['lag.u'\]"):
        sim.step([1.0, 2.0], 0.1)
    with pytest.raises(ParameterError, match="inputs"):
        sim.step({"lag.v": 1.0}, 0.1)
    with pytest.raises(ParameterError, match="'h'"):
        sim.step([1.0], 0.0)
    with pytest.raises(ParameterError, match="'lag.u' = nan"):
        sim.step([math.nan], 0.1)
    assert sim.t == 0.0  # nothing was integrated


def test_a_signal_in_another_unit_than_its_input_is_refused():
    model = lag_model()
    with pytest.raises(ParameterError, match=r"'lag.u' = 'a signal in m'.*signal in Pa"):
        simulate(model, 0.1, {"lag.u": Step(final=0.1, unit="m")})
    ok = simulate(model, 0.1, {"lag.u": Step(final=1e5, unit="Pa")})
    assert ok.final("lag.x") > 0


@pytest.mark.parametrize(
    "signal",
    [
        Step(final=100, unit="kPa"),
        Step(final="0.1 MPa", unit="kPa"),
        Step(final=1, unit="bar"),
        Staircase(levels=(0.1,), dwell=1.0, unit="MPa"),
        Table(times=(0.0, 1.0), values=(100, 100), unit="kPa"),
    ],
)
def test_a_signal_in_any_pressure_unit_drives_a_pressure_input(signal):
    """Issue 24: ``Step(unit="kPa")`` was refused (a signal in kPa for an input in Pa)."""
    assert signal.unit == "Pa"
    a = simulate(lag_model(), 0.2, {"lag.u": signal})
    b = simulate(lag_model(), 0.2, {"lag.u": 1e5})
    np.testing.assert_allclose(a["lag.x"], b["lag.x"], rtol=1e-12)
    assert Step(final=14.5038, unit="psi").final == pytest.approx(1e5, rel=1e-5)


def test_simulate_accepts_inputs_with_units():
    model = lag_model()
    a = simulate(model, 0.2, {"lag.u": "0.1 MPa"})
    b = simulate(model, 0.2, {"lag.u": 1e5})
    np.testing.assert_array_equal(a["lag.x"], b["lag.x"])
    assert a.final("lag.u") == 1e5


# --- failures: when, where, why -----------------------------------------------------------
def test_simulate_names_the_signal_and_time_where_the_domain_is_left():
    """x crosses its bound 0.5e5 at t = 0.3 + tau ln 2 = 0.4386 s: the error is stamped
    with the first output point after it (0.44 s), not the final time."""
    model = lag_model(x_high=0.5e5)
    domain = r"left the physical domain: lag.x = 5\.0\d+e\+04 Pa is outside"
    with pytest.raises(SolverError, match=domain) as info:
        simulate(model, 1.0, {"lag.u": Step(final=1e5, time=0.3)}, output_interval=0.01)
    assert info.value.time == pytest.approx(0.44)
    assert info.value.state["lag.x"] > 0.5e5
    partial = info.value.partial  # issue 24: what was computed before it is kept
    assert partial.meta["status"] == "incomplete" and "lag.x" in partial.meta["reason"]
    np.testing.assert_allclose(partial.index, np.arange(0.0, 0.305, 0.01), atol=1e-12)
    assert np.all(partial["lag.x"] <= 0.5e5)


def test_signals_expanded_over_the_points_equal_the_mapped_ones(monkeypatch):
    """Small signal Functions are expanded over the output points, larger ones mapped:
    the same values bit for bit, and the same domain error at the same time."""
    from sarcomere.dynamics.simulation import simulator

    results, errors = [], []
    for limit in (simulator.EXPAND_LIMIT, 0):
        monkeypatch.setattr(simulator, "EXPAND_LIMIT", limit)
        model = lag_model(x_high=0.5e5)  # a fresh model: nothing cached
        is_sx = simulator._points_function(model, ("lag.x", "lag.u"), 7).is_a("SXFunction")
        assert is_sx == (limit > 0)
        ramp = Ramp(final=4e4, duration=0.5, start=0.1)
        results.append(simulate(model, 1.0, {"lag.u": ramp}, output_interval=0.01))
        with pytest.raises(SolverError, match="lag.x") as info:
            simulate(model, 1.0, {"lag.u": Step(final=1e5, time=0.3)}, output_interval=0.01)
        errors.append((str(info.value), info.value.time))
    for name in ("lag.x", "lag.u"):
        np.testing.assert_array_equal(results[0][name], results[1][name])
    assert errors[0] == errors[1]
    assert errors[0][1] == pytest.approx(0.44)


def test_a_step_that_leaves_the_domain_fails_at_its_end_and_stays_at_its_start():
    model = lag_model(x_high=0.5e5)
    sim = Simulator(model, t0=0.0)
    sim.step([1e5], 0.1)
    with pytest.raises(SolverError, match="lag.x") as info:
        sim.step([1e5], 0.1)
    assert info.value.time == pytest.approx(0.2)
    assert sim.t == pytest.approx(0.1)  # the simulator stays at the last point that passed


def test_a_blow_up_in_a_step_is_an_error_not_nan():
    model = lag_model(tau=0.01)
    s = SolverSettings("euler", step=0.05, options=(("on_unstable", "ignore"),))
    sim = Simulator(model, s, t0=0.0)
    sim.reset(x0=[1e300])
    with pytest.raises(SolverError, match="non-finite"):
        for _ in range(100):
            sim.step([0.0], 1.0)
    assert np.all(np.isfinite(sim.x))


# --- output size and progress ------------------------------------------------------------
def test_output_size_is_refused_before_running_with_the_numbers():
    model = lag_model()
    with pytest.raises(ParameterError, match=r"1000001 output points x 2 signals = 2e\+06"):
        simulate(model, 100.0, output_interval=1e-4, max_values=1e6)
    res = simulate(model, 1.0, output_interval=0.1, max_values=22)
    assert len(res["time"]) == 11


def test_progress_is_reported_up_to_one():
    model = lag_model()
    seen: list[float] = []
    inputs = {"lag.u": Step(final=1e5, time=0.5)}
    simulate(model, 3.0, inputs, output_interval=1e-3, progress=seen.append)
    assert seen == sorted(seen) and seen[-1] == 1.0
    assert len(seen) == 4  # the step at 0.5 s, then 1000-point pieces: 0.5, 1.5, 2.5, 3.0
    assert seen[0] == pytest.approx(0.5 / 3)


# --- caches: held by the model, keyed by value ------------------------------------------
def _count_integrators(monkeypatch) -> list:
    built = []
    real = cs.integrator

    def counting(*args, **kwargs):
        built.append(args[1])
        return real(*args, **kwargs)

    monkeypatch.setattr(cs, "integrator", counting)
    return built


def test_twenty_simulate_calls_with_a_constant_input_build_one_integrator(monkeypatch):
    built = _count_integrators(monkeypatch)
    model = lag_model()
    for k in range(20):
        simulate(model, 0.5, {"lag.u": 1e5 if k % 2 else 5e4}, signals=["lag.x"])
    assert built == ["cvodes"]


def test_a_closed_loop_builds_one_integrator(monkeypatch):
    built = _count_integrators(monkeypatch)
    model = lag_model()
    sim = Simulator(model, t0=0.0)
    for k in range(50):
        sim.step([1e3 * k], 0.01 if k % 2 else 0.02)  # the step size is not in the key
    assert built == ["cvodes"]
    Simulator(model, t0=0.0).step([1.0], 0.3)  # another simulator on the same model shares it
    assert built == ["cvodes"]


def test_no_module_global_caches_remain():
    import importlib
    import pkgutil

    for info in pkgutil.iter_modules(simulation_pkg.__path__):
        mod = importlib.import_module(f"{simulation_pkg.__name__}.{info.name}")
        caches = [k for k, v in vars(mod).items() if "CACHE" in k.upper() and isinstance(v, dict)]
        assert not caches, (info.name, caches)


# --- the step Functions an optimal-control problem calls ---------------------------------
def rk4_gain(h: float) -> float:
    """RK4 on tau x' = u - x from 0: x1 = (1 - R(-h/tau)) u, R the stability polynomial."""
    z = -h / TAU_S
    return 1 - (1 + z + z**2 / 2 + z**3 / 6 + z**4 / 24)


def gain(method: str, h: float) -> float:
    """d x(h) / du of one step from x = 0 (exact, except one RK4 step of size h)."""
    return rk4_gain(h) if method == "rk4" else 1 - math.exp(-h / TAU_S)


@pytest.mark.parametrize("method", ["cvodes", "rk4", "radau_fixed", "collocation"])
def test_step_function_is_symbolic_and_differentiable(method):
    """``step`` is one step of the method over h (one RK4 step: not subdivided)."""
    model = lag_model()
    step = Simulator(model, METHODS[method]).step_function()
    assert step.name_in() == ["x", "z", "u", "h", "p"]
    assert step.name_out() == ["xf", "zf"]
    x, u, h = cs.MX.sym("x"), cs.MX.sym("u"), cs.MX.sym("h")
    p = model.parameters()
    xf = step(x, cs.MX(0, 1), u, h, p)[0]
    dxf_du = cs.Function("d", [x, u, h], [cs.jacobian(xf, u)])
    assert float(dxf_du(0.0, 1e5, 0.05)) == pytest.approx(gain(method, 0.05), rel=1e-6)


@pytest.mark.parametrize("method", ["cvodes", "rk4", "radau_fixed"])
def test_step_function_inside_an_nlp(method):
    """Opti finds the held command that brings x from 0 to 6e4 Pa in two steps of 50 ms."""
    model = lag_model()
    step = Simulator(model, METHODS[method]).step_function()
    opti = cs.Opti()
    u = opti.variable()
    x = cs.MX(0.0)
    for _ in range(2):
        x = step(x, cs.MX(0, 1), u, 0.05, model.parameters())[0]
    opti.minimize(((x - 6e4) / 1e4) ** 2)
    opti.subject_to(opti.bounded(0, u, P_MAX))
    opti.solver("ipopt", {"print_time": False}, {"print_level": 0, "sb": "yes"})
    sol = opti.solve()
    decay = 1 - gain(method, 0.05)
    assert sol.value(u) == pytest.approx(6e4 / (1 - decay**2), rel=1e-6)


def test_scipy_methods_have_no_step_function():
    with pytest.raises(ParameterError, match="scipy"):
        Simulator(lag_model(), SolverSettings("scipy_radau")).step_function()


def test_sine_and_step_inputs_mix_in_one_simulate():
    """A time-varying input with breakpoints goes through the signals law."""
    model = lag_model()
    sine = Sine(amplitude=1e4, frequency=2.0, offset=5e4, unit="Pa")
    res = simulate(model, 1.0, {"lag.u": sine}, settings=METHODS["cvodes"], output_interval=0.1)
    w = 2 * math.pi * 2.0
    t = res["time"]
    # tau x' + x = offset + A sin(w t), x(0) = 0
    a = 1e4 / (1 + (w * TAU_S) ** 2)
    steady = 5e4 + a * (np.sin(w * t) - w * TAU_S * np.cos(w * t))
    x0_steady = 5e4 - a * w * TAU_S
    np.testing.assert_allclose(res["lag.x"], steady - x0_steady * np.exp(-t / TAU_S), rtol=1e-6)


def test_the_stability_guard_also_guards_steps():
    """tau = 10 ms: RK4 limit 27.85 ms; a loop of 30 ms steps is refused at its first step."""
    from sarcomere.dynamics.simulation.guard import StepStabilityWarning

    model = lag_model(tau=0.01)
    with pytest.warns(StepStabilityWarning, match="stability limit 0.02785"):
        Simulator(model, SolverSettings("rk4", step=0.03), t0=0.0).step([1e5], 0.03)
    refuse = SolverSettings("rk4", step=0.03, options=(("on_unstable", "raise"),))
    sim = Simulator(model, refuse, t0=0.0)
    sim.step([1e5], 0.02)  # 20 ms steps are below the limit
    with pytest.raises(ParameterError, match="stability limit"):
        sim.step([1e5], 0.03)


def test_a_misspelled_sundials_option_is_one_line_naming_it():
    s = SolverSettings("cvodes", options=(("max_steps", 5),))
    with pytest.raises(ParameterError, match=r"unknown option 'max_steps'.*max_num_steps") as info:
        simulate(lag_model(), 0.1, settings=s)
    assert "\n" not in str(info.value)


@dataclass
class _Square:
    """``gain t^2``: an unhashable signal (eq without frozen) without breakpoints."""

    gain: float

    def __call__(self, t):
        return self.gain * np.asarray(t, dtype=float) ** 2

    def casadi(self, t):
        return self.gain * t**2


def test_a_user_signal_without_breakpoints_or_hash_is_integrated_exactly():
    model = lag_model()
    sig = _Square(1e5)
    for _ in range(2):  # the second run reuses the integrator cached for this object
        res = simulate(model, 1.0, {"lag.u": sig}, settings=METHODS["cvodes"], output_interval=0.1)
    t = res["time"]
    x = 1e5 * (t**2 - 2 * TAU_S * t + 2 * TAU_S**2 * (1 - np.exp(-t / TAU_S)))
    np.testing.assert_allclose(res["lag.x"], x, rtol=1e-7, atol=1e-6)


def test_advance_returns_the_states_at_the_times_and_refuses_bad_times():
    model = lag_model()
    sim = Simulator(model, METHODS["cvodes"], t0=0.0)
    step = Step(final=1e5, time=0.15, unit="Pa")
    X, Z, U = sim.advance({"lag.u": step}, [0.0, 0.1, 0.15, 0.2, 0.3])
    x = [0.0, 0.0, 0.0, exact(1e5, 0.05), exact(1e5, 0.15)]
    np.testing.assert_allclose(X[:, 0], x, rtol=1e-8, atol=1e-9)
    np.testing.assert_array_equal(U[:, 0], [0.0, 0.0, 1e5, 1e5, 1e5])  # right-continuous
    assert Z.shape == (5, 0) and sim.t == 0.3
    for bad in ([0.2], [0.3], [0.4, 0.35], []):
        with pytest.raises(ParameterError, match="times"):
            sim.advance(None, bad)


def test_a_dae_steps_with_idas_and_agrees_with_simulate_and_collocation():
    """static_chain keeps one algebraic unknown: IDAS and collocation step it."""
    from sarcomere.dynamics import hanging_load, solve_equilibrium

    model = hanging_load(n=1, load_kg=0.05, fidelity="static_chain")
    assert model.nz == 1
    eq = solve_equilibrium(model, {"regulator.p_cmd": 0.0})
    idas = SolverSettings("idas", rtol=1e-8, atol=1e-11)
    cmd = {"regulator.p_cmd": Step(final=1e5, time=0.1, unit="Pa")}
    kw = {"x0": eq.x, "z0": eq.z, "output_interval": 0.05, "signals": ["myofibril.length"]}
    ref = simulate(model, 0.5, cmd, settings=idas, **kw)
    col = simulate(model, 0.5, cmd, settings=SolverSettings("collocation", step=2e-3), **kw)
    np.testing.assert_allclose(col["myofibril.length"], ref["myofibril.length"], rtol=1e-6)
    sim = Simulator(model, idas, t0=0.0)
    sim.reset(x0=eq.x, z0=eq.z)
    lengths = [sim.signal("myofibril.length")]
    for k in range(10):
        sim.step([0.0 if k < 2 else 1e5], 0.05)
        lengths.append(sim.signal("myofibril.length"))
    np.testing.assert_allclose(lengths, ref["myofibril.length"], rtol=1e-7)
    assert ref["myofibril.length"][-1] < ref["myofibril.length"][0] - 1e-3  # it contracted
    assert sim.step_function().size_in("z") == (1, 1)
