"""Radau IIA collocation, written once: its constants and its equations.

Every Radau IIA in the project takes them from here: the fixed-step ``radau_fixed``
(:mod:`.fixed_step`), the NMPC's collocation intervals (``controllers/nmpc.py``) and the
compiled adaptive ``radau`` (:mod:`.radau`, ``c/radau.c``: the constants of
:func:`radau5_tableau`, packed by :func:`radau5_packed`), which the FMU's Co-Simulation
runs too (``fmu/codegen.py``).

One convention for the equations (:func:`residual`): an interval ``[t0, t0 + h]`` in
normalised time ``tau = (t - t0) / h`` in ``[0, 1]``; the unknowns ``V`` are the states
at the ``points`` Radau nodes ``tau_1 < ... < tau_s = 1`` (so the last one is the
interval's end), stacked into one column; the right-hand side is a derivative with
respect to ``tau`` (``h`` times the time derivative), in whatever scaled units its
caller chose. The residual

    r_j = f(tau_j, V_j, q) - sum_r C[r, j] [x0, V]_r,   j = 1..s

is zero on the collocation solution; ``C`` is the differentiation matrix of the
interpolating polynomial through ``(0, x0), (tau_r, V_r)`` at the nodes
(``casadi.collocation_coeff``).
"""

from __future__ import annotations

from functools import cache

import casadi as cs
import numpy as np

from ..errors import ParameterError


def _check_points(points: int) -> None:
    if isinstance(points, bool) or not isinstance(points, int) or not 1 <= points <= 9:
        raise ParameterError("points", points, "an integer in 1..9 (Radau IIA nodes)")


@cache
def _nodes_and_derivative(points: int) -> tuple[np.ndarray, np.ndarray]:
    tau = cs.collocation_points(points, "radau")
    return np.array(tau, dtype=float), np.array(cs.collocation_coeff(tau)[0], dtype=float)


def nodes(points: int = 3) -> np.ndarray:
    """The Radau IIA nodes ``tau_1 .. tau_s`` in ``(0, 1]`` (the last is 1) [-]."""
    _check_points(points)
    return _nodes_and_derivative(points)[0].copy()


def differentiation(points: int = 3) -> np.ndarray:
    """``C``, ``(points + 1) x points``: the slope at node ``j`` of the polynomial through
    ``(0, x0), (tau_r, V_r)`` is ``sum_r C[r, j] [x0, V]_r`` [1/unit of tau]."""
    _check_points(points)
    return _nodes_and_derivative(points)[1].copy()


def interpolation(theta, points: int = 3) -> np.ndarray:
    """Weights ``(len(theta), points + 1)`` of the interpolating polynomial through ``(0,
    x0), (tau_r, V_r)`` at the normalised times ``theta`` (any, extrapolation too): the
    state there is ``sum_r W[., r] [x0, V]_r`` (the same polynomial as the dense output
    ``P`` of :func:`radau5_tableau`, in the Lagrange basis)."""
    _check_points(points)
    theta = np.asarray(theta, dtype=float).ravel()
    tau = np.concatenate([[0.0], _nodes_and_derivative(points)[0]])
    w = np.ones((len(theta), len(tau)))
    for i, ti in enumerate(tau):
        for j, tj in enumerate(tau):
            if j != i:
                w[:, i] *= (theta - tj) / (ti - tj)
    return w


def butcher(points: int = 3) -> np.ndarray:
    """The Runge-Kutta matrix ``A`` of Radau IIA (``V_i = x0 + sum_j A[i, j] f_j`` in
    normalised time): the inverse of the stage block of :func:`differentiation`."""
    return np.linalg.inv(differentiation(points)[1:, :].T)


def residual(f: cs.Function, nx: int, points: int = 3) -> cs.Function:
    """The collocation equations of one interval (module docstring) as an SX Function.

    Parameters
    ----------
    f : casadi.Function
        ``f(tau, x, q) -> dx/dtau`` (``h`` times the time derivative; ``tau`` [-]);
        ``q`` holds everything else (inputs, parameters, ``h``, scales).
    nx : int
        Number of states.
    points : int
        Radau nodes (1..9; 3: order 5).

    Returns
    -------
    casadi.Function
        ``radau_residual(x0, V, q) -> r``, ``V`` and ``r`` of length ``nx * points``
        (node after node).
    """
    C = differentiation(points)
    tau = nodes(points)
    x0, V = cs.SX.sym("x0", nx), cs.SX.sym("V", nx * points)
    q = cs.SX.sym("q", f.size1_in(2), f.size2_in(2))
    X = cs.horzcat(x0, cs.reshape(V, nx, points))
    res = [f(tau[j], X[:, j + 1], q) - cs.mtimes(X, C[:, j]) for j in range(points)]
    return cs.Function("radau_residual", [x0, V, q], [cs.vertcat(*res)], ["x0", "V", "q"], ["r"])


@cache
def _radau5() -> dict:
    c = nodes(3)
    Ainv = np.linalg.inv(butcher(3))
    lam, vec = np.linalg.eig(Ainv)
    r = int(np.argmin(np.abs(lam.imag)))
    q = int(np.argmin(lam.imag))  # Hairer's sign convention for T
    v_r = np.real(vec[:, r]) / np.linalg.norm(vec[:, r])
    v_r *= np.sign(v_r[2])
    v_c = vec[:, q] / vec[2, q]  # last component 1: T[2] = [., 1, 0]
    T = np.column_stack([v_r, v_c.real, v_c.imag])
    s6 = np.sqrt(6.0)
    # error weights: the embedded method's difference, e = gamma0 * [(13+7s6), ...]
    e = np.array([-13 - 7 * s6, -13 + 7 * s6, -1.0]) / 3
    P = np.linalg.inv(np.vander(c, 4, increasing=True)[:, 1:]).T
    return {
        "A": butcher(3),
        "c": c,
        "T": T,
        "TI": np.linalg.inv(T),
        "mu_r": float(lam[r].real),
        "mu_c": complex(np.conj(lam[q])),
        "e": e,
        "P": P,
    }


def radau5_tableau() -> dict:
    """The 3-node Radau IIA constants of the adaptive integrator (RADAU5, Hairer & Wanner
    IV.8), from :func:`butcher`.

    Returns
    -------
    dict
        ``A``, ``c`` (nodes), ``T`` and ``TI = T^-1`` with
        ``TI A^-1 T = [[mu_r, 0, 0], [0, a, -b], [0, b, a]]``, ``mu_r``, ``mu_c = a + ib``,
        ``e`` (error weights: ``err = (mu_r/h - J)^-1 (f0 + sum_i e_i Z_i / h)``) and
        ``P`` (dense output: ``x(t + s h) = x + sum_k (sum_i Z_i P[i, k]) s^(k+1)``).
    """
    return {k: (v.copy() if isinstance(v, np.ndarray) else v) for k, v in _radau5().items()}


def radau5_packed() -> np.ndarray:
    """:func:`radau5_tableau` as the 36 doubles of ``c/radau.c``'s ``Tableau`` struct:
    ``T``, ``TI`` (row-major), ``mu_r``, ``Re mu_c``, ``Im mu_c``, ``c``, ``e``, ``P``."""
    t = _radau5()
    return np.concatenate(
        [
            t["T"].ravel(),
            t["TI"].ravel(),
            [t["mu_r"], t["mu_c"].real, t["mu_c"].imag],
            t["c"],
            t["e"],
            t["P"].ravel(),
        ]
    )
