"""Tests of the integration methods: each against closed forms and each other."""

from __future__ import annotations

import math
import warnings

import numpy as np
import pytest

import sarcomere.dynamics.simulation.fixed_step as methods
import sarcomere.dynamics.simulation.guard as guard
from sarcomere.dynamics.assemblies import hanging_load
from sarcomere.dynamics.equilibrium import solve_equilibrium
from sarcomere.dynamics.errors import ParameterError, SolverError
from sarcomere.dynamics.modeling.component import Component, System
from sarcomere.dynamics.signals import Ramp, Step
from sarcomere.dynamics.simulation.simulate import SolverSettings, simulate

ADAPTIVE = ["cvodes", "scipy_rk45", "scipy_radau", "scipy_bdf", "scipy_lsoda"]
FIXED = {"rk4": 1e-3, "euler": 1e-4, "radau_fixed": 1e-2, "collocation": 1e-2}
# error bounds for the closed-form tests: adaptive at rtol 1e-8; fixed at the steps above
BOUND = {"euler": 2e-3, "radau_fixed": 1e-6, "collocation": 1e-6, "rk4": 1e-6}


def settings(method: str) -> SolverSettings:
    if method in FIXED:
        return SolverSettings(method, step=FIXED[method])
    return SolverSettings(method, rtol=1e-8, atol=1e-11)


@pytest.mark.parametrize("method", ADAPTIVE + list(FIXED))
def test_oscillator_matches_closed_form(oscillator, oscillator_error, method):
    res = simulate(oscillator, 1.0, settings=settings(method), output_interval=0.01)
    err = oscillator_error(res)
    assert err < BOUND.get(method, 1e-5), err
    if method in FIXED:  # exactly one step per `step` over the 1 s run
        assert res.meta["n_steps"] == round(1.0 / FIXED[method])
    else:  # a few hundred steps at most on one smooth second; each costs >= 1 rhs call
        assert 10 <= res.meta["n_steps"] <= min(res.meta["n_rhs"], 5000), res.meta


# --- a first-order lag driven by an input: tau x' = u(t) - x -----------------------------
TAU_S = 0.2


class Lag(Component):
    """``tau dx/dt = u - x`` with input ``u`` [1]."""

    def __init__(self, name: str, tau: float) -> None:
        super().__init__(name)
        self.tau = tau

    def build(self, b) -> None:
        tau = b.parameter("tau", self.tau, "s", "time constant", low=1e-9)
        u = b.input("u", "1", "command")
        x = b.state("x", 0.0, "1", "lagged command")
        b.der(x, (u - x) / tau)


def lag_model(tau: float = TAU_S):
    sys = System("lag")
    sys.add(Lag("lag", tau))
    return sys.flatten()


@pytest.mark.parametrize("method", ADAPTIVE + list(FIXED))
def test_step_input_restarts_at_breakpoint(method):
    step = Step(final=1.0, time=0.3)
    res = simulate(
        lag_model(), 1.0, {"lag.u": step}, settings=settings(method), output_interval=0.01
    )
    t = res["time"]
    exact = np.where(t < 0.3, 0.0, 1.0 - np.exp(-(t - 0.3) / TAU_S))
    assert np.max(np.abs(res["lag.x"] - exact)) < BOUND.get(method, 1e-6)
    assert res["lag.x"][t <= 0.3].max() == 0.0  # the step never leaks into earlier steps
    assert res.meta["n_segments"] == 2


@pytest.mark.parametrize("method", ["scipy_radau", "scipy_rk45", "rk4", "radau_fixed"])
def test_ramp_input_evaluated_at_stage_times(method):
    ramp = Ramp(final=1.0, duration=1.0)
    res = simulate(
        lag_model(), 1.0, {"lag.u": ramp}, settings=settings(method), output_interval=0.05
    )
    t = res["time"]
    exact = t - TAU_S * (1.0 - np.exp(-t / TAU_S))
    assert np.max(np.abs(res["lag.x"] - exact)) < 1e-6


def test_fixed_step_methods_need_a_step(oscillator):
    for method in FIXED:
        with pytest.raises(ParameterError, match="solver.step"):
            simulate(oscillator, 0.1, settings=SolverSettings(method))


def test_unknown_option_is_refused(oscillator):
    s = SolverSettings("rk4", step=1e-3, options=(("on_unstabel", "raise"),))
    with pytest.raises(ParameterError, match="on_unstable"):
        simulate(oscillator, 0.1, settings=s)


def test_steps_land_on_outputs_and_never_exceed_the_step():
    starts, sizes, idx = methods.step_grid(0.0, 1.0, np.array([0.25, 0.5, 1.0]), 0.1)
    assert sizes.max() <= 0.1 + 1e-15
    ends = starts + sizes
    np.testing.assert_allclose(ends[idx], [0.25, 0.5, 1.0])
    assert len(starts) == 3 + 3 + 5


# --- stability guard --------------------------------------------------------------------
def test_stability_radius_of_known_regions():
    r = guard.stability_radius(guard.RK4.poly, np.array([np.pi, np.pi / 2]))
    np.testing.assert_allclose(r, [2.785293563, 2 * math.sqrt(2)], rtol=1e-6)
    th = np.array([np.pi, 3 * np.pi / 4])
    np.testing.assert_allclose(guard.stability_radius(guard.EULER.poly, th), -2 * np.cos(th))


def test_max_stable_step_ignores_growing_and_zero_modes():
    h, lam = guard.max_stable_step(np.array([-1000.0, 0.0, 5.0, -1 + 10j]), guard.RK4)
    assert lam == -1000.0
    assert h == pytest.approx(2.785293563e-3, rel=1e-6)


def test_guard_warns_above_the_limit_and_not_below():
    model = lag_model(tau=0.01)  # lambda = -100 1/s: RK4 limit 27.85 ms
    inputs = {"lag.u": Step(final=1.0, time=0.3)}
    with warnings.catch_warnings():
        warnings.simplefilter("error", guard.StepStabilityWarning)
        simulate(
            model, 1.2, inputs, settings=SolverSettings("rk4", step=0.025), output_interval=0.3
        )
    with pytest.warns(guard.StepStabilityWarning, match="stability limit 0.02785"):
        simulate(model, 1.2, inputs, settings=SolverSettings("rk4", step=0.03), output_interval=0.3)
    refuse = SolverSettings("rk4", step=0.03, options=(("on_unstable", "raise"),))
    with pytest.raises(ParameterError, match="stability limit"):
        simulate(model, 1.2, inputs, settings=refuse, output_interval=0.3)


def test_blow_up_is_an_error_naming_the_time():
    model = lag_model(tau=0.01)
    s = SolverSettings("euler", step=0.05, options=(("on_unstable", "ignore"),))
    with pytest.raises(SolverError, match="non-finite") as info:
        simulate(model, 100.0, {"lag.u": 1.0}, x0=np.array([1e300]), settings=s)
    # x_k = (-4)^k 1e300 (+ O(1)): the rhs (1 - x) / tau = -100 x leaves the doubles
    # (1.8e308) first at x_11 = 4.2e306, i.e. in the step from 0.55 s to 0.60 s
    assert 0.55 - 1e-12 <= info.value.time <= 0.60 + 1e-12, info.value.time


# --- the pneumatic muscle: methods agree -----------------------------------------------
@pytest.fixture(scope="module")
def muscle():
    model = hanging_load(1, load_kg=0.05)
    x0 = solve_equilibrium(model, {"regulator.p_cmd": 0.0}).x
    inputs = {"regulator.p_cmd": Step(final=1e5, time=0.1, unit="Pa")}
    ref = simulate(
        model,
        0.4,
        inputs,
        x0=x0,
        settings=SolverSettings(rtol=1e-10, atol=1e-13),
        output_interval=0.01,
    )
    return model, x0, inputs, ref


@pytest.mark.parametrize(
    ("method", "setting", "bound"),
    [
        ("cvodes", {"rtol": 1e-6, "atol": 1e-9}, 1e-4),
        ("scipy_radau", {"rtol": 1e-6, "atol": 1e-9}, 1e-4),
        ("scipy_bdf", {"rtol": 1e-6, "atol": 1e-9}, 1e-4),
        ("scipy_lsoda", {"rtol": 1e-6, "atol": 1e-9}, 1e-4),
        ("scipy_rk45", {"rtol": 1e-6, "atol": 1e-9}, 1e-4),
        ("rk4", {"step": 5e-4}, 1e-4),
        ("radau_fixed", {"step": 2e-3}, 1e-4),
        ("collocation", {"step": 5e-3}, 1e-3),
    ],
)
def test_methods_agree_on_the_step_scenario(muscle, method, setting, bound):
    model, x0, inputs, ref = muscle
    res = simulate(
        model, 0.4, inputs, x0=x0, settings=SolverSettings(method, **setting), output_interval=0.01
    )
    for name in model.state_names:
        scale = np.abs(ref[name]).max() or 1.0
        err = np.sqrt(np.mean(((res[name] - ref[name]) / scale) ** 2))
        assert err < bound, (name, err)
