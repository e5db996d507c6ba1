"""The compiled Rosenbrock method ``rodas`` (Rodas5P): observed orders against closed forms
(step ends and dense output, autonomous, driven by a signal, and the stiff
Prothero-Robinson case that Rodas4 fails), the muscle against
tight CVODES (the packaged step scene and random chains), failures with their partial
result, refusals."""

from __future__ import annotations

import numpy as np
import pytest

from sarcomere.dynamics import hanging_load
from sarcomere.dynamics.errors import ParameterError, SolverError
from sarcomere.dynamics.modeling.component import Component, System
from sarcomere.dynamics.signals import Sine, Step
from sarcomere.dynamics.simulation import rosenbrock
from sarcomere.dynamics.simulation.settings import HELD
from sarcomere.dynamics.simulation.simulate import SolverSettings, simulate
from sarcomere.dynamics.studies import workprecision as wp


class Quadratic(Component):
    """``x' = x^2`` from ``x = 1``: ``x = 1 / (1 - t)``."""

    def build(self, b) -> None:
        x = b.state("x", 1.0, "1", "blows up at t = 1 s")
        b.der(x, x**2)


class Lag(Component):
    """``tau x' = u - x``."""

    def __init__(self, name: str, tau: float) -> None:
        super().__init__(name)
        self.tau = tau

    def build(self, b) -> None:
        tau = b.parameter("tau", self.tau, "s", "time constant", low=1e-12)
        u = b.input("u", "1", "command")
        x = b.state("x", 0.0, "1", "lagged command")
        b.der(x, (u - x) / tau)


def _model(component: Component):
    sys = System(component.name)
    sys.add(component)
    return sys.flatten()


def _orders(model, t_end, inputs, name, exact, t_mid=0.0) -> tuple[np.ndarray, np.ndarray]:
    """Steps held fixed (first = max step, loose tolerance: none rejected), outputs at the
    step ends and midpoints: observed orders of the end error and of the largest error at
    the midpoints after ``t_mid``."""
    end, mid = [], []
    for h in (0.05, 0.025, 0.0125, 0.00625):
        opts = (("first_step", h), ("max_step", h))
        s = SolverSettings("rodas", rtol=0.5, atol=0.5, options=opts)
        t_out = np.linspace(0.0, t_end, round(2 * t_end / h) + 1)
        res = simulate(model, t_end, inputs, settings=s, t_out=t_out)
        assert res.meta["n_steps"] == round(t_end / h) and res.meta["n_rejected"] == 0
        err = np.abs(res[name] - exact(res["time"]))
        end.append(err[-1])
        mid.append(err[1::2][res["time"][1::2] > t_mid].max())
    return np.log2(np.array(end[:-1]) / end[1:]), np.log2(np.array(mid[:-1]) / mid[1:])


@pytest.mark.slow  # over 0.8 s: the fast loop leaves it to the full suite
def test_order_five_at_the_step_ends_and_in_between_on_a_nonlinear_closed_form():
    """x' = x^2 to t = 0.5: the end error falls as h^5 (Rodas5P), the dense output's
    (order 4, local error O(h^5)) at the midpoints likewise."""
    model = _model(Quadratic("q"))
    end, mid = _orders(model, 0.5, {}, "q.x", lambda t: 1 / (1 - t))
    assert np.all((end > 4.6) & (end < 5.5)), end
    assert np.all((mid > 4.4) & (mid < 5.5)), mid


@pytest.mark.slow  # over 0.8 s: the fast loop leaves it to the full suite
def _sine_lag(tau: float, f: float = 2.0):
    """A lag driven by a sine, and its closed form from rest."""

    def exact(t):
        wt = 2 * np.pi * f * tau
        x = np.sin(2 * np.pi * f * t) - wt * np.cos(2 * np.pi * f * t) + wt * np.exp(-t / tau)
        return x / (1 + wt**2)

    return _model(Lag("lag", tau)), {"lag.u": Sine(amplitude=1.0, frequency=f)}, exact


@pytest.mark.slow  # over 0.8 s: the fast loop leaves it to the full suite
def test_order_five_when_the_input_depends_on_time():
    """A lag (tau = 0.1 s) driven by a sine (f depends on t): order 5 needs the df/dt
    terms of the stages (rodas.c's difference), which a held input never exercises."""
    model, inputs, exact = _sine_lag(0.1)
    end, mid = _orders(model, 1.0, inputs, "lag.x", exact)
    assert np.all((end > 4.6) & (end < 5.5)), end
    assert np.all((mid > 4.4) & (mid < 5.5)), mid
    assert rosenbrock.library(model, HELD).autonomous  # a held input: no df/dt at all


@pytest.mark.slow  # over 0.8 s: the fast loop leaves it to the full suite
def test_a_stiff_state_following_a_moving_input_keeps_order_four():
    """The Prothero-Robinson case (tau = 1 us, h lambda down to -5e4): Rodas4 falls to
    order 2 at the step ends and its dense output does not converge (measured at
    tau = 0.1 ms: 3e-4 between the steps at every h); Rodas5P keeps order 4 or more at
    the step ends and order 4 in between once the initial layer (1 us) has passed
    (Steinebach 2023's design goal)."""
    model, inputs, exact = _sine_lag(1e-6)
    end, mid = _orders(model, 1.0, inputs, "lag.x", exact, t_mid=0.2)
    assert np.all(end > 3.9), end
    assert np.all((mid > 3.8) & (mid < 4.3)), mid


class Rotation(Component):
    """``x' = A x``, ``A = [[a, -b], [b, a]]``: eigenvalues ``a +- i b`` [1/s]."""

    def build(self, b) -> None:
        re = b.parameter("a", -1.0, "1/s", "real part")
        im = b.parameter("b", 0.0, "1/s", "imaginary part")
        x = b.state("x", 1.0, "1", "first coordinate")
        y = b.state("y", 0.0, "1", "second coordinate")
        b.der(x, re * x - im * y)
        b.der(y, im * x + re * y)


@pytest.mark.slow  # over 0.8 s: the fast loop leaves it to the full suite
def test_one_step_is_the_l_stable_stability_function():
    """One step of h = 1 s on x' = A x gives R(hA) x0, so the compiled method's own
    stability function R(z) at z = a + i b: |R| <= 1 on the imaginary axis (A-stable),
    R(z) -> 0 as z -> -inf (L-stable, stiffly accurate), R(z) ~ exp(z) for small z. A
    wrong coefficient in c/rodas.c breaks one of the three."""
    model = _model(Rotation("r"))
    s = SolverSettings("rodas", 0.5, 0.5, options=(("first_step", 1.0), ("max_step", 1.0)))

    def R(z: complex) -> complex:
        p = {"r.a": z.real, "r.b": z.imag}
        res = simulate(model, 1.0, params=p, x0=[1.0, 0.0], settings=s, t_out=[0.0, 1.0])
        assert res.meta["n_steps"] == 1 and res.meta["n_rejected"] == 0
        return complex(res["r.x"][-1], res["r.y"][-1])  # R(z) e1 = (Re R, Im R)

    on_axis = [abs(R(1j * y)) for y in (0.1, 1.0, 3.0, 10.0, 100.0, 1e4)]
    assert max(on_axis) <= 1 + 1e-12, on_axis
    assert abs(R(-1e8)) < 1e-6 and abs(R(-1e8 + 1e3j)) < 1e-6
    for z in (-0.01, 0.01j, -0.01 + 0.01j):
        assert abs(R(z) - np.exp(z)) < 1e-11, z  # local error O(z^6)


@pytest.mark.slow  # compiles the method for its model (1.2 s quiet)
def test_error_follows_the_tolerance(oscillator, oscillator_error):
    errors = []
    for rtol in (1e-4, 1e-6, 1e-8):
        res = simulate(oscillator, 1.0, settings=SolverSettings("rodas", rtol, rtol * 1e-3))
        errors.append(oscillator_error(res))
        assert errors[-1] < rtol, (rtol, errors[-1])
    assert errors[0] > 30 * errors[1] > 900 * errors[2]


@pytest.mark.slow  # over 0.8 s: the fast loop leaves it to the full suite
def test_n3_step_scene_against_tight_cvodes():
    """The packaged step scenario (n = 3, 50 g, 0.1 MPa step, 2 s, 201 points) at rtol
    1e-5 against CVODES at 1e-12: l2 and final errors below 2e-6 in under 300 steps."""
    sc = wp.scenarios(3)["step"]
    model, _ = sc.setup()
    ref = wp.reference(sc, check_rtol=1e-8)
    res = sc.run(SolverSettings("rodas", 1e-5, 1e-8))
    final, l2 = wp.state_errors(wp.states(res, model), ref)
    assert l2 < 2e-6 and final < 2e-6, (l2, final)
    assert l2 > 1e-9  # an honest error, not the reference itself
    assert res.meta["n_steps"] < 300 and res.meta["n_segments"] == 2
    for key in ("n_rejected", "n_rhs", "n_jac", "n_lu"):
        assert res.meta[key] > 0, key


@pytest.mark.slow  # compiles a library per drawn chain
def test_random_chains_and_loads_against_tight_cvodes():
    """Chains of 1-4 units, loads and step times drawn with a fixed seed: rodas at rtol
    1e-7 within 1e-5 (relative to each state's range) of CVODES at 1e-12."""
    rng = np.random.default_rng(27)
    for _ in range(2):
        n, load = int(rng.integers(1, 5)), float(rng.uniform(0.01, 0.2))
        model = hanging_load(n, load_kg=load)
        inputs = {"regulator.p_cmd": Step(final=float(rng.uniform(3e4, 1.5e5)), time=0.05)}
        t_out = np.linspace(0.0, 0.3, 61)

        def run(settings, model=model, inputs=inputs, t_out=t_out):
            res = simulate(model, 0.3, inputs, settings=settings, t_out=t_out)
            return np.column_stack([res[k] for k in model.state_names])

        X = run(SolverSettings("rodas", 1e-7, 1e-10))
        ref = run(SolverSettings("cvodes", 1e-12, 1e-15))
        span = np.ptp(ref, axis=0) + np.abs(ref).max(axis=0) * 1e-6 + 1e-30
        err = np.abs(X - ref).max(axis=0) / span
        assert err.max() < 1e-5, (n, load, err.max())


@pytest.mark.slow  # compiles the method for its model (1.2 s quiet)
def test_a_too_tight_step_limit_says_why_and_keeps_the_partial_result():
    """max_step 1 ms with at most 300 steps per call: the held segment before the step
    (0.1 s) runs, the one after it cannot; the error names the cause, the time and the
    state, and the outputs before the step are kept."""
    model = _model(Lag("lag", 0.05))
    s = SolverSettings("rodas", 1e-6, 1e-9, max_steps=300, options=(("max_step", 1e-3),))
    inputs = {"lag.u": Step(final=1.0, time=0.1)}
    with pytest.raises(SolverError, match="rodas: too many steps") as info:
        simulate(model, 1.0, inputs, settings=s, output_interval=0.01)
    assert 0.1 < info.value.time < 1.0 and "lag.x" in info.value.state
    partial = info.value.partial
    assert partial.meta["status"] == "incomplete"
    np.testing.assert_allclose(partial.index, np.arange(0.0, 0.105, 0.01), atol=1e-12)
    np.testing.assert_allclose(partial["lag.x"], 0.0, atol=1e-12)


@pytest.mark.slow  # over 0.8 s: the fast loop leaves it to the full suite
def test_blow_up_is_an_error_near_the_singularity_never_nan():
    model = _model(Quadratic("q"))
    with pytest.raises(SolverError, match="rodas: ") as info:
        simulate(model, 2.0, settings=SolverSettings("rodas", 1e-6, 1e-9))
    assert abs(info.value.time - 1.0) < 1e-5, info.value.time
    assert 1e5 < info.value.state["q.x"] < np.inf


def test_algebraic_unknowns_are_refused():
    model = hanging_load(n=1, load_kg=0.05, fidelity="static_chain")
    with pytest.raises(SolverError, match="rodas needs an explicit ODE"):
        simulate(model, 0.1, settings=SolverSettings("rodas"))


@pytest.mark.parametrize(
    ("option", "value"),
    [("max_step", -1.0), ("max_step", 0.0), ("first_step", 0.0), ("max_newton", 7)],
)
def test_bad_options_are_refused(oscillator, option, value):
    s = SolverSettings("rodas", options=((option, value),))
    with pytest.raises(ParameterError, match="solver.options"):
        simulate(oscillator, 0.1, settings=s)
