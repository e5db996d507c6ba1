"""The one damped Newton method: its stopping rules and failures, and the three solvers
that use it (the equilibrium, the calibration, the MPC target calculation)."""

import numpy as np
import pytest
import scipy.sparse as sp

import sarcomere.controllers.target as target
import sarcomere.dynamics.calibration as calibration
import sarcomere.dynamics.equilibrium as equilibrium
import sarcomere.dynamics.newton as newton
from sarcomere.dynamics.assemblies import hanging_load
from sarcomere.dynamics.components.aps import APSParams
from sarcomere.dynamics.newton import NewtonFailure, damped_newton


def _arctan(x):
    """``atan(x) = 0``: full Newton steps diverge from |x| > 1.39; damped ones do not."""
    return np.arctan(x), np.array([[1.0 / (1.0 + x[0] ** 2)]])


def test_the_line_search_converges_where_full_steps_diverge():
    sol = damped_newton(_arctan, np.array([3.0]), tol=1e-12, max_iter=30)
    assert abs(sol.x[0]) < 1e-12 and sol.residual <= 1e-12 and not sol.stalled
    with pytest.raises(NewtonFailure, match="no convergence in 2 iterations") as exc:
        damped_newton(_arctan, np.array([3.0]), tol=1e-12, max_iter=2)
    assert exc.value.iterations == 2 and exc.value.residual > 1e-6


def test_sparse_jacobians_weights_and_step_tolerance():
    def fun(x):
        return np.array([1e6 * (x[0] - 1.0), x[1] ** 2 - 4.0]), sp.csc_matrix(
            np.diag([1e6, 2 * x[1]])
        )

    sol = damped_newton(fun, np.array([0.0, 1.0]), tol=1e-14, max_iter=30)
    np.testing.assert_allclose(sol.x, [1.0, 2.0], rtol=1e-14)
    w = newton.row_weights(fun(sol.x)[1], np.array([1.0, 2.0]))
    np.testing.assert_allclose(w, [1e-6, 1 / 8])
    step = damped_newton(fun, np.array([0.0, 1.0]), tol=0.0, max_iter=30, step_tol=1e-8)
    np.testing.assert_allclose(step.x, [1.0, 2.0], rtol=1e-14)


def test_singular_jacobian_fails_or_stalls_below_the_stall_tolerance():
    def flat(x):
        return np.array([1e-9 + 0 * x[0]]), np.zeros((1, 1))

    with pytest.raises(NewtonFailure, match="singular Jacobian"):
        damped_newton(flat, np.zeros(1), tol=1e-12, max_iter=5)
    sol = damped_newton(flat, np.zeros(1), tol=1e-12, max_iter=5, stall_tol=1e-8)
    assert sol.stalled and sol.iterations == 0


def test_no_descent_and_non_finite_residuals_are_failures():
    def nan_beyond(x):  # a root at 1, undefined past 0.5: every trial is rejected
        r = np.array([x[0] - 1.0 if x[0] < 0.5 else np.nan])
        return r, np.array([[1.0]])

    with pytest.raises(NewtonFailure, match="line search failed"):
        damped_newton(nan_beyond, np.array([0.4999]), tol=1e-12, max_iter=5)
    with pytest.raises(NewtonFailure, match="not finite"):
        damped_newton(nan_beyond, np.array([0.6]), tol=1e-12, max_iter=5)


@pytest.fixture
def calls(monkeypatch):
    """Counts the damped Newton calls of the equilibrium and the MPC target (the
    calibration's equilibria are the equilibrium's)."""
    counts = {}

    def spy(module):
        def counted(*args, **kwargs):
            counts[module.__name__] = counts.get(module.__name__, 0) + 1
            return damped_newton(*args, **kwargs)

        monkeypatch.setattr(module, "damped_newton", counted)

    for module in (equilibrium, target):
        spy(module)
    return counts


def test_equilibrium_calibration_and_target_use_the_one_newton(calls):
    model = hanging_load(1, load_kg=0.02)
    eq = equilibrium.solve_equilibrium(model, {"regulator.p_cmd": 4e4})
    assert calls.pop(equilibrium.__name__) >= 1
    steady = target.SteadyTarget(model, "myofibril.length", np.ones(model.nx + 1))
    x, u = steady(np.concatenate([eq.x, eq.u]), eq["myofibril.length"], eq.p)
    assert u[0] == pytest.approx(4e4, rel=1e-9)
    assert calls.pop(target.__name__) == 1
    calibration.fit(APSParams.from_paper())
    assert calls.pop(equilibrium.__name__) >= 1


def test_continuation_halves_a_failed_step_and_says_how_far_it_got():
    """Steps beyond 0.3 fail: the path is 1 (fails), 0.5 (fails), 0.25 (the next step
    doubled), 0.75 (fails), 0.5 (fails), ...; below the smallest step it stops, naming
    the fraction reached."""
    tried = []

    def advance(x, frac):
        tried.append(frac)
        if frac > 0.3:
            raise NewtonFailure("too far", 1.0, 3)
        return frac

    with pytest.raises(newton.ContinuationFailure) as stop:
        newton.continuation(advance, 0.0, min_step=0.01)
    assert tried[:5] == [1.0, 0.5, 0.25, 0.75, 0.5] and 0.29 < stop.value.fraction <= 0.3
    assert stop.value.failure.why == "too far"
    assert newton.continuation(lambda x, frac: frac, 0.0, min_step=0.01) == 1.0
