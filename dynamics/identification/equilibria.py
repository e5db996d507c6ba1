"""How a fit solves its equilibria (each record's first sample, every static point) at a
trial point: first quickly, by the damped Newton of :mod:`sarcomere.dynamics.newton` on
the fit's own Functions from the Gauss-Newton step's prediction (:func:`quick_newton`,
with :func:`check_domain` on the result), else by
:func:`~sarcomere.dynamics.equilibrium.solve_equilibrium` continued from the last
solution (:func:`continued`)."""

from __future__ import annotations

import functools

import numpy as np

from ..equilibrium import EQUILIBRIUM_TOL, out_of_domain, solve_equilibrium
from ..errors import SolverError
from ..newton import NewtonFailure, damped_newton, row_weights

QUICK_ITERATIONS = 10
"""Most damped Newton iterations of a quick solve (from the Gauss-Newton step's prediction
it needs 2-4) before the fit's
:meth:`~sarcomere.dynamics.identification.problem.Problem.restore` continues
:func:`solve_equilibrium` from the last solution instead."""


def quick_newton(fun, x0: np.ndarray) -> np.ndarray:
    """The root of ``fun`` (``x -> (r, J)``, J dense) from ``x0`` by damped Newton with
    :func:`solve_equilibrium`'s row weights and tolerance; raises NewtonFailure."""
    scale = np.maximum(np.abs(x0), 1e-6)
    weights = functools.partial(row_weights, scale=scale)
    return damped_newton(fun, x0, tol=EQUILIBRIUM_TOL, max_iter=QUICK_ITERATIONS, weights=weights).x


def check_domain(model, signals: np.ndarray) -> None:
    """Raise NewtonFailure where a signal (rows of ``signals``) is outside its domain."""
    bad = out_of_domain(model, signals)
    if bad:
        raise NewtonFailure(bad, np.inf, 0)


def continued(model, inputs, over, guess):
    """The equilibrium continued from ``guess``, else solved from the model's own start."""
    if guess is not None:
        try:
            return solve_equilibrium(model, inputs, over, guess=guess)
        except SolverError:
            pass
    return solve_equilibrium(model, inputs, over)


__all__ = ["QUICK_ITERATIONS", "check_domain", "continued", "quick_newton"]
