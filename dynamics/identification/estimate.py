"""One fit from one start, with noise levels estimated by maximum likelihood where the fit
file says "estimate".

With the noise of signal ``s`` unknown, the likelihood's maximum over ``sigma_s`` is at
``sigma_s^2 = mean(residual_s^2)``; the fit alternates a weighted least-squares solve and
that update (from ``sigma_s`` = 1 % of the data's spread) until every estimated ``sigma_s``
changes by less than :data:`SIGMA_RTOL`.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from .problem import Problem, Solution

SIGMA_RTOL = 1e-4
"""Relative change of the estimated noise levels at which their update stops."""

MAX_ROUNDS = 20
"""Most least-squares solves of one fit while the noise levels are estimated."""


@dataclass
class Fitted:
    """A solve and the noise levels (SI, per signal) used in its weights."""

    solution: Solution
    sigma: dict[str, float]


def initial_sigma(problem: Problem) -> dict[str, float]:
    """1 % of each estimated signal's spread in the data (its ML value replaces it)."""
    rows = np.array(problem.rows.signal)
    out = {}
    for s in problem.estimated_noise:
        d = problem.rows.data[rows == s]
        spread = float(np.ptp(d)) if d.size else 0.0
        out[s] = 0.01 * spread if spread > 0 else max(abs(float(np.mean(d))), 1.0) * 1e-3
    return out


def fit_from(
    problem: Problem, theta0: np.ndarray, sigma: Mapping[str, float] | None = None
) -> Fitted:
    """Fit from parameter values ``theta0`` (SI). Raises SolverError where the start's
    initial guess cannot be built (a simulation or an equilibrium fails); a failed solve
    is returned with its status."""
    v0 = problem.initial_guess(theta0)
    sig = dict(sigma) if sigma else initial_sigma(problem)
    rows = np.array(problem.rows.signal)
    sol = problem.solve(v0, problem.weights(sig))
    for _ in range(MAX_ROUNDS - 1):
        if not problem.estimated_noise or not sol.success:
            break
        new = {s: float(np.sqrt(np.mean(sol.residuals[rows == s] ** 2))) for s in sig}
        new = {s: max(v, 1e-300) for s, v in new.items()}
        done = all(abs(new[s] / sig[s] - 1) < SIGMA_RTOL for s in sig)
        sig = new
        if done:
            break
        sol = problem.solve(sol.v, problem.weights(sig))
    return Fitted(sol, sig)


__all__ = ["Fitted", "fit_from"]
