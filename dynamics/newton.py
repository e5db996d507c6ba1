"""Damped Newton's method on a square system ``r(x) = 0``, and the continuation around
it: the one home of the Newton iteration of the equilibrium (:mod:`.equilibrium`, which
adds domain checks and settling on top), the calibration (:mod:`.calibration`) and the
MPC target calculation (``controllers/target.py``).

Each iteration solves ``J dx = -r`` (``scipy.sparse`` or dense ``J``) and backtracks:
the step ``alpha dx`` is halved until the merit ``|w r|`` (``w``: row weights from the
Jacobian at the iterate, default 1) falls by the Armijo factor ``1 - 1e-4 alpha``; a
trial point whose residual or Jacobian is not finite counts as worse. It stops when the
weighted residual's max-norm is at most ``tol``, or when every step component is within
``step_tol``. It never returns silently wrong: a failure raises :class:`NewtonFailure`
(why, residual, steps taken), unless the caller accepts a stall below ``stall_tol``.
"""

from __future__ import annotations

import warnings
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

MIN_DAMPING = 1e-4
"""Smallest step fraction of the line search before it gives up (no descent)."""


class NewtonFailure(Exception):
    """Newton did not converge: ``why``, the weighted residual's max-norm at the last
    iterate and the steps taken."""

    def __init__(self, why: str, residual: float, iterations: int) -> None:
        super().__init__(why)
        self.why, self.residual, self.iterations = why, residual, iterations


@dataclass(frozen=True)
class NewtonResult:
    """The solution, the weighted residual's max-norm where it was last evaluated (before
    the final step when ``step_tol`` stopped the iteration), the Newton steps taken, and
    whether it stalled (accepted below ``stall_tol``)."""

    x: np.ndarray
    residual: float
    iterations: int
    stalled: bool = False


def damped_newton(
    fun: Callable[[np.ndarray], tuple[np.ndarray, object]],
    x0: np.ndarray,
    *,
    tol: float,
    max_iter: int,
    residual: Callable[[np.ndarray], np.ndarray] | None = None,
    weights: Callable[[object], np.ndarray] | None = None,
    merit_norm: float | None = np.inf,
    step_tol: np.ndarray | None = None,
    stall_tol: float | None = None,
) -> NewtonResult:
    """Solve ``r(x) = 0`` from ``x0`` in at most ``max_iter`` steps.

    Parameters
    ----------
    fun
        ``x -> (r, J)``: the residual and its Jacobian (dense array or scipy sparse).
    tol
        Converged when ``max |w r| <= tol``.
    residual
        ``x -> r`` for the line search's trial points; by default ``fun`` (its Jacobian
        is then kept for the accepted point).
    weights
        ``J -> w``, the row weights at an iterate (the line search compares trial points
        with the same weights); default none.
    merit_norm
        The norm of ``w r`` the line search decreases (``numpy.linalg.norm``'s ``ord``;
        None: the 2-norm).
    step_tol
        Also converged (after taking it) when every ``|dx_i| <= step_tol_i``.
    stall_tol
        Where Newton can make no more progress (singular Jacobian, no descent, or
        ``max_iter`` reached), accept the iterate if ``max |w r| <= stall_tol``.

    Raises
    ------
    NewtonFailure
        With why, the residual and the steps taken.
    """
    x = np.array(x0, dtype=float)
    r, J = fun(x)
    for it in range(max_iter + 1):
        w = None if weights is None else weights(J)
        rw = r if w is None else r * w
        norm = float(np.linalg.norm(rw, np.inf)) if rw.size else 0.0
        if not np.isfinite(norm):
            raise NewtonFailure("residual is not finite", norm, it)
        if norm <= tol:
            return NewtonResult(x, norm, it)
        stall = NewtonFailure(f"no convergence in {max_iter} iterations", norm, it)
        if it < max_iter:
            dx, why = _newton_step(J, r)
            if why:
                stall = NewtonFailure(why, norm, it)
            elif step_tol is not None and np.all(np.abs(dx) <= step_tol):
                return NewtonResult(x + dx, norm, it + 1)
            else:
                merit = (float(np.linalg.norm(rw, merit_norm)), merit_norm)
                found = _line_search(fun, residual, x, dx, w, merit)
                if found is not None:
                    x, r, J = found
                    continue
                stall = NewtonFailure("line search failed (no descent)", norm, it)
        if stall_tol is not None and norm <= stall_tol:
            return NewtonResult(x, norm, it, stalled=True)
        raise stall
    raise AssertionError("unreachable")  # pragma: no cover


class ContinuationFailure(Exception):
    """A continuation stopped: the fraction of the way reached and the last failure."""

    def __init__(self, fraction: float, failure: NewtonFailure) -> None:
        super().__init__(failure.why)
        self.fraction, self.failure = fraction, failure


def continuation(advance: Callable[[object, float], object], start: object, min_step: float):
    """Follow a path from fraction 0 to 1: ``advance(solution, fraction)`` solves at
    ``fraction`` from the last solution (raising :class:`NewtonFailure` where it cannot).
    The first step tries the whole way; a failed step is halved, an accepted one doubles
    the next. Returns the solution at 1; raises :class:`ContinuationFailure` once the step
    falls below ``min_step``."""
    solution, frac, step = start, 0.0, 1.0
    while frac < 1.0:
        nxt = min(1.0, frac + step)
        try:
            solution = advance(solution, nxt)
        except NewtonFailure as failure:
            step /= 2
            if step < min_step:
                raise ContinuationFailure(frac, failure) from None
            continue
        frac, step = nxt, min(1.0, 2 * step)
    return solution


def row_weights(J, scale: np.ndarray) -> np.ndarray:
    """``1 / max_j |J_ij| scale_j`` for a sparse or dense Jacobian: each residual row
    compared in its own units, with ``scale`` the size of each unknown (``fmax`` skips
    NaN; a row with structural zeros counts a 0). The numbers of the symbolic
    ``equilibrium._row_scales``."""
    J = sp.csc_matrix(J)
    n_rows, n_cols = J.shape
    columns = np.repeat(np.arange(n_cols), np.diff(J.indptr))
    top = np.full(n_rows, np.nan)
    np.fmax.at(top, J.indices, np.abs(J.data) * scale[columns])
    counts = np.bincount(J.indices, minlength=n_rows)
    rows = np.where(counts < n_cols, np.fmax(top, 0.0), top)
    return 1.0 / np.fmax(rows, 1e-300)


def _newton_step(J, r: np.ndarray) -> tuple[np.ndarray, str]:
    """``dx = -J^-1 r``, or why there is none."""
    try:
        # a singular J is reported below (a non-finite step): not scipy's warning as well
        with np.errstate(over="ignore", invalid="ignore"), warnings.catch_warnings():
            warnings.simplefilter("ignore", spla.MatrixRankWarning)
            dx = spla.spsolve(J, -r) if sp.issparse(J) else np.linalg.solve(J, -np.ravel(r))
    except (np.linalg.LinAlgError, RuntimeError) as exc:
        return np.empty(0), f"singular Jacobian ({exc})"
    if not np.all(np.isfinite(dx)):
        return dx, "singular Jacobian (Newton step not finite)"
    return dx, ""


def _line_search(fun, residual, x, dx, w, merit):
    """The first ``x + alpha dx`` (alpha = 1, 1/2, ...) whose merit (``merit``: value and
    norm at ``x``) falls by the Armijo factor, with its residual and Jacobian; or None."""
    value, order = merit
    alpha = 1.0
    with np.errstate(over="ignore", invalid="ignore"):
        while alpha > MIN_DAMPING:
            trial = x + alpha * dx
            rt, Jt = (residual(trial), None) if residual is not None else fun(trial)
            mt = np.linalg.norm(rt if w is None else rt * w, order)
            if np.isfinite(mt) and mt < (1 - 1e-4 * alpha) * value and _finite(Jt):
                return (trial, *fun(trial)) if Jt is None else (trial, rt, Jt)
            alpha *= 0.5
    return None


def _finite(J) -> bool:
    """Whether a Jacobian (None: not evaluated) has only finite entries."""
    if J is None:
        return True
    return bool(np.all(np.isfinite(J.data if sp.issparse(J) else J)))
