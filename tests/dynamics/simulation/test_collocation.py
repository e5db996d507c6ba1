"""The one Radau IIA collocation builder against closed forms: the stability function of
3-stage Radau IIA, exactness for polynomials up to its order, the stage matrix, and the
residual's argument order as its users (radau_fixed, the NMPC) call it."""

from __future__ import annotations

import casadi as cs
import numpy as np
import pytest

from sarcomere.dynamics.errors import ParameterError
from sarcomere.dynamics.simulation import collocation


def _solve(f: cs.Function, nx: int, points: int, x0: np.ndarray, q: np.ndarray) -> np.ndarray:
    """The collocation states at the nodes (Newton on the residual; exact for linear f)."""
    R = collocation.residual(f, nx, points)
    V = cs.SX.sym("V", nx * points)
    g = cs.Function("g", [V], [R(x0, V, q)])
    return np.array(cs.rootfinder("s", "newton", g)(np.tile(x0, points))).ravel()


def test_stability_function_of_three_stage_radau_iia():
    """x' = lambda x over one step of h: x1 = R(z) x0, z = lambda h, with Radau IIA's
    R(z) = (1 + 2z/5 + z^2/20) / (1 - 3z/5 + 3z^2/20 - z^3/60) (Hairer & Wanner IV.5)."""
    tau, x, q = cs.SX.sym("tau"), cs.SX.sym("x"), cs.SX.sym("z")
    f = cs.Function("f", [tau, x, q], [q * x])  # d/dtau = h lambda x
    for z in (-0.5, -3.0, -40.0, 0.7):
        R = (1 + 2 * z / 5 + z**2 / 20) / (1 - 3 * z / 5 + 3 * z**2 / 20 - z**3 / 60)
        end = _solve(f, 1, 3, np.array([1.0]), np.array([z]))[-1]
        assert end == pytest.approx(R, rel=1e-12)


@pytest.mark.parametrize("points", [1, 2, 3, 4])
def test_exact_for_polynomials_up_to_order_two_s_minus_one(points):
    """x' = k tau^(k-1) from 0: x(1) = 1 exactly for k <= 2s - 1 (the order), not beyond."""
    tau, x, q = cs.SX.sym("tau"), cs.SX.sym("x"), cs.SX.sym("q", 0)
    order = 2 * points - 1
    for k in range(1, order + 2):
        f = cs.Function("f", [tau, x, q], [k * tau ** (k - 1)])
        end = _solve(f, 1, points, np.array([0.0]), np.zeros(0))[-1]
        if k <= order:
            assert end == pytest.approx(1.0, abs=1e-12), k
        else:
            assert abs(end - 1.0) > 1e-6, k


def test_butcher_matrix_and_nodes():
    s6 = np.sqrt(6.0)
    np.testing.assert_allclose(collocation.nodes(3), [(4 - s6) / 10, (4 + s6) / 10, 1.0])
    A = collocation.butcher(3)
    np.testing.assert_allclose(A.sum(axis=1), collocation.nodes(3), atol=1e-14)  # c = A 1
    np.testing.assert_allclose(A[-1], [(16 - s6) / 36, (16 + s6) / 36, 1 / 9], atol=1e-14)
    assert collocation.radau5_packed().shape == (36,)


def test_residual_argument_order_and_shapes():
    tau, x, q = cs.SX.sym("tau"), cs.SX.sym("x", 2), cs.SX.sym("q", 3)
    f = cs.Function("f", [tau, x, q], [x * q[0] + tau])
    R = collocation.residual(f, 2, 3)
    assert R.name_in() == ["x0", "V", "q"] and R.name_out() == ["r"]
    assert (R.size1_in(1), R.size1_out(0)) == (6, 6)


@pytest.mark.parametrize("bad", [0, 10, 2.5, True])
def test_bad_points_are_refused(bad):
    with pytest.raises(ParameterError, match="points"):
        collocation.nodes(bad)


def test_interpolation_is_the_dense_output_polynomial():
    """The Lagrange weights through (0, x0) and the nodes give the C integrator's dense
    output ``x + sum_k (sum_i Z_i P[i, k]) s^(k+1)`` (``Z_i = V_i - x``), reproduce the
    nodes exactly, and are exact for cubics (points 3)."""
    rng = np.random.default_rng(2)
    x0, V = rng.normal(size=2), rng.normal(size=(3, 2))
    s = np.linspace(-0.3, 2.0, 9)  # inside the step, and extrapolated
    W = collocation.interpolation(s)
    P = collocation.radau5_tableau()["P"]
    dense = x0 + (s[:, None] ** np.arange(1, 4)) @ P.T @ (V - x0)
    np.testing.assert_allclose(W @ np.vstack([x0, V]), dense, rtol=1e-12, atol=1e-12)
    at_nodes = collocation.interpolation(np.concatenate([[0.0], collocation.nodes(3)]))
    np.testing.assert_allclose(at_nodes, np.eye(4), atol=1e-14)
    cubic = lambda t: 1 - 2 * t + 0.5 * t**2 + 3 * t**3  # noqa: E731
    knots = np.concatenate([[0.0], collocation.nodes(3)])
    np.testing.assert_allclose(W @ cubic(knots), cubic(s), rtol=1e-12)
    with pytest.raises(ParameterError):
        collocation.interpolation(s, points=0)
