"""Constrained Gauss-Newton for ``min 1/2 |r(v)|^2`` subject to ``g(v) = 0``, with bounds on
the parameters' search variables ``phi`` (the first entries of ``v``).

The other unknowns ``y`` (shooting nodes, static equilibria) are as many as the
constraints and determined by them: ``G_y = dg/dy`` is square (sparse; a record's nodes
and its continuity make it block bidiagonal). Each iteration linearises once and
condenses the Gauss-Newton model onto ``phi`` (the lifted multiple-shooting step of Bock;
Albersmeyer and Diehl): with the linearised constraints solved for ``dy = a + E dphi``
(``a = -G_y^-1 g``, ``E = -G_y^-1 G_phi``, one sparse LU), the step ``dphi`` solves the
small bounded linear least-squares problem::

    min |r + J_y a + (J_phi + J_y E) dphi|^2 + mu |diag(d) dphi|^2,
    lo <= phi + dphi <= hi,  |dphi| <= max_step

(``scipy.optimize.lsq_linear``; ``d`` the column norms, Marquardt's scaling). The nodes
move with the parameters (lifting), so a poor start does not have to be simulated from
end to end. The caller's ``evaluate`` may restore some unknowns exactly (the problem
re-solves its equilibria: a Newton step on a stiff equilibrium far from it overshoots).

Globalisation (Levenberg-Marquardt with a constraint cap): the constraints are measured
by the node change that would restore them, ``theta = max |G_y^-1 g|`` with the
iteration's ``G_y`` (Deuflhard's natural level: raw equilibrium rows, scaled by stiff
forces, would otherwise dominate any merit). A step is taken when it leaves ``theta``
at most :data:`THETA_MAX` (or no larger than before) and either the cost falls by at
least :data:`ACCEPT` of the decrease the model predicts or ``theta`` at least halves;
``mu`` then falls, else it rises. It stops when ``theta <= gtol`` and the
predicted decrease is below :class:`Options`' thresholds (or the step below ``xtol``);
otherwise it reports why it stopped. An evaluation that raises SolverError (a step whose
Newton fails) is a rejected step.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import scipy.sparse.linalg as spla
from scipy.optimize import lsq_linear

from ..errors import SolverError


@dataclass(frozen=True)
class Options:
    """Stopping rules: ``max_iter`` iterations; converged when ``max |G_y^-1 g| <= gtol``
    (scaled states) and the predicted cost decrease is below ``atol``, ``rtol (1 + cost)``
    or ``floor cost``, or ``max |dphi| <= xtol``; also when a step is rejected while its
    predicted decrease is below ``floor cost + 1e-14`` (or ``floor (1 + cost)`` once the
    damping is at its largest). The cost (half the weighted sum of squares) cannot resolve
    more: its evaluation noise from the inner Newton and equilibrium tolerances was
    measured at 5e-3 on fit-synthetic's 2949 (1.7e-6 of it); and the Gauss-Newton decrease
    is the step's size in the Fisher metric, ``dphi^T F dphi / 2``: 1e-5 of a chi-squared
    of order the data count is far below a 95 % threshold of 1.92. A zero-residual fit
    (cost near 0) goes on to ``rtol``/``xtol``. ``mu0``: the first damping (relative to
    the column norms); ``max_step``: the largest change of a search variable per
    iteration (1 in log space: a factor e).
    """

    max_iter: int = 100
    rtol: float = 1e-15
    atol: float = 0.0
    floor: float = 1e-5
    gtol: float = 1e-6
    xtol: float = 1e-12
    mu0: float = 1.0
    max_step: float = 1.0


@dataclass
class Outcome:
    """Where it stopped: the unknowns, the status ("converged" or why not), the
    iterations, and the linearisation at ``v`` (None where the start could not be
    evaluated)."""

    v: np.ndarray
    status: str
    iterations: int
    linearization: object | None


def gauss_newton(
    evaluate: Callable[[np.ndarray, bool], tuple[np.ndarray, object]],
    v0: np.ndarray,
    lo: np.ndarray,
    hi: np.ndarray,
    options: Options,
    report: Callable[[str], None] | None = None,
) -> Outcome:
    """Minimise from ``v0``. ``evaluate(v, jacobian)`` returns the unknowns it evaluated at
    (it may restore some: the problem's equilibria) and an object with ``rw``, ``g`` and
    (when ``jacobian``) the sparse ``Jr``, ``Jg``; ``lo <= phi <= hi`` (equal
    bounds hold a parameter). ``report``: called with a line per iteration."""
    n = len(lo)
    v = np.asarray(v0, dtype=float)
    try:
        v, lin = evaluate(v, True)
    except SolverError as exc:
        return Outcome(v, f"evaluation failed at the start ({exc})", 0, None)
    mu, grow = options.mu0, 2.0
    for it in range(options.max_iter):
        cost = 0.5 * float(lin.rw @ lin.rw)
        step = _step(lin, v, lo, hi, mu, options.max_step)
        if step is None:
            return Outcome(v, SINGULAR, it, lin)
        dv, pred, level = step
        viol = level(lin.g)
        if np.max(np.abs(viol), initial=0.0) <= options.gtol and _small(
            dv[:n], pred, cost, options
        ):
            if mu <= MU_CONFIRM:
                return Outcome(v, "converged", it, lin)
            mu = MU_CONFIRM  # confirm with a lightly damped step
            continue
        theta = float(np.max(np.abs(viol), initial=0.0))
        try:
            v_t, trial = evaluate(v + dv, True)
            cost_t = 0.5 * float(trial.rw @ trial.rw)
            theta_t = float(np.max(np.abs(level(trial.g)), initial=0.0))
        except SolverError:
            v_t, trial, cost_t, theta_t = None, None, np.inf, np.inf
        rho = (cost - cost_t) / pred if pred > 0 else -np.inf
        feasible = theta_t <= max(THETA_MAX, theta)
        if feasible and not rho > ACCEPT and theta_t <= 0.5 * theta:
            rho = ACCEPT * 2  # a restoring step: the constraints at least halved
        if not feasible:
            rho = -np.inf
        if report:
            report(
                f"iteration {it}: chi2 {2 * cost:.6g}, max |G_y^-1 g| {theta:.2g} -> "
                f"{theta_t:.2g}, rho {rho:.3g}, mu {mu:.3g}, "
                f"max |dphi| {np.max(np.abs(dv[:n]), initial=0):.3g}, decrease {cost - cost_t:.3g} "
                f"(predicted {pred:.3g})"
            )
        if rho > ACCEPT:
            v, lin = v_t, trial
            mu *= 0.2 if rho > 0.5 else 0.5 if rho > 0.25 else 2.0
            mu = max(mu, MU_MIN)
            grow = 2.0
        else:
            quiet = np.max(np.abs(viol), initial=0.0) <= options.gtol
            if quiet and pred <= options.floor * cost + 1e-14:
                return Outcome(v, "converged", it, lin)  # at the resolution of the cost
            if mu >= MU_MAX:
                if quiet and pred <= options.floor * (1 + cost):
                    return Outcome(v, "converged", it, lin)
                return Outcome(v, "no descent: rejected steps up to the largest damping", it, lin)
            mu = max(mu * grow, options.mu0)
            grow *= 2
    return Outcome(v, f"no convergence in {options.max_iter} iterations", options.max_iter, lin)


THETA_MAX = 0.5
"""The largest constraint violation a step may leave, as node change ``max |G_y^-1 g|``
(scaled states: half a state's scale), unless it was larger before."""

SINGULAR = (
    "no Gauss-Newton step: a singular constraint Jacobian (a node or equilibrium the "
    "constraints do not fix) or a non-finite linearisation"
)

ACCEPT = 1e-4
"""A step is taken when the cost falls by at least this fraction of the decrease the
linear model predicts (Levenberg-Marquardt's gain ratio); the damping then falls fivefold
above a ratio of 0.5, twofold above 0.25, else doubles; a rejected step raises it to at
least ``mu0``, by a factor that doubles with each rejection in a row (measured on
fit-synthetic: 9 iterations, against 15 when a rejection only quadruples it)."""

MU_MIN = 1e-6
"""The smallest damping: a parameter combination the data do not determine (a flat
direction) would otherwise take an arbitrary, large step."""

MU_CONFIRM = 1e-2
"""A small step found with more damping than this is checked again with this damping."""

MU_MAX = 1e10
"""The largest damping before giving up (the step is then far below any useful size)."""


def _small(dphi: np.ndarray, pred: float, cost: float, options: Options) -> bool:
    if pred <= max(options.atol, options.rtol * (1 + cost), options.floor * cost):
        return True
    return np.max(np.abs(dphi), initial=0) <= options.xtol


def _step(lin, v: np.ndarray, lo: np.ndarray, hi: np.ndarray, mu: float, max_step: float):
    """The condensed Gauss-Newton step ``dv``, the predicted cost decrease of the full
    step, and the constraints' measure ``g -> G_y^-1 g`` (the node change that would
    restore them: a natural level, in scaled state units whatever the rows' scaling);
    None where ``G_y`` is singular."""
    n = len(lo)
    Jr, Jg = lin.Jr, lin.Jg
    A_phi, A_y = Jr[:, :n].toarray(), Jr[:, n:]
    dy_a = np.zeros(Jg.shape[1] - n)
    E = np.zeros((Jg.shape[1] - n, n))
    lu = None
    if Jg.shape[0]:
        if Jg.shape[0] != Jg.shape[1] - n:
            raise ValueError(f"{Jg.shape[0]} constraints for {Jg.shape[1] - n} unknowns")
        try:
            lu = spla.splu(Jg[:, n:].tocsc())
        except RuntimeError:
            return None
        dy_a = -lu.solve(lin.g)
        E = -lu.solve(Jg[:, :n].toarray())
        if not (np.all(np.isfinite(dy_a)) and np.all(np.isfinite(E))):
            return None
    r0 = lin.rw + A_y @ dy_a
    J = A_phi + A_y @ E
    if not (np.all(np.isfinite(r0)) and np.all(np.isfinite(J))):
        return None
    free = lo < hi
    dphi = np.zeros(n)
    if free.any():
        Jf = J[:, free]
        d = np.sqrt(np.maximum(np.sum(Jf**2, axis=0), 1e-300))
        M = np.vstack([Jf, np.sqrt(mu) * np.diag(d)]) if mu else Jf
        b = -np.concatenate([r0, np.zeros(int(free.sum()))]) if mu else -r0
        phi = v[:n][free]
        low = np.maximum(lo[free] - phi, -max_step)
        high = np.minimum(hi[free] - phi, max_step)
        width = np.maximum(high - low, 0.0)
        low, high = np.minimum(low, 0.0), np.maximum(high, 0.0)
        high = np.where(width > 0, high, low + 1e-300)
        try:
            dphi[free] = lsq_linear(M, b, bounds=(low, high), method="bvls", tol=1e-14).x
        except np.linalg.LinAlgError:
            return None
    dy = dy_a + E @ dphi
    lin_r = r0 + J @ dphi
    pred = 0.5 * float(lin.rw @ lin.rw) - 0.5 * float(lin_r @ lin_r)

    def level(g: np.ndarray) -> np.ndarray:
        return lu.solve(g) if lu is not None else g

    return np.concatenate([dphi, dy]), pred, level


__all__ = ["Options", "Outcome", "gauss_newton"]
