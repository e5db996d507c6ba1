"""Constrained Gauss-Newton (Levenberg-Marquardt-damped SQP) for ``min 1/2 |r(v)|^2``
subject to ``g(v) = 0`` and bounds on some unknowns.

Each iteration evaluates ``r``, ``g`` and their exact sparse Jacobians once and solves the
KKT system of the Gauss-Newton model

    [J_r^T J_r + mu D   J_g^T] [dv]   [-J_r^T r]
    [J_g                0    ] [ l] = [-g      ]

(``D`` the diagonal of ``J_r^T J_r``, Marquardt's scaling; ``mu = 0`` while full steps
succeed). A step that leaves a bound fixes that unknown at the bound and is solved again.
The step is accepted by backtracking on the exact-penalty merit ``1/2 |r|^2 + nu |g|_1``
(``nu`` above the largest multiplier); a failed line search raises ``mu`` tenfold. It
stops when the constraints hold (``max |g| <= gtol``) and the predicted decrease of the
cost is below ``rtol`` of it; otherwise it reports why it stopped, never a silent result.
An evaluation that raises (a Radau step whose Newton fails) counts as an infinite merit.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

GTOL = 1e-9
"""Largest constraint violation accepted (scaled units of the constraints)."""

RTOL = 1e-12
"""Converged when the predicted cost decrease is below this fraction of ``1 + cost``."""


@dataclass
class Outcome:
    """Where Gauss-Newton stopped: the unknowns, the status ("converged" or why not), the
    iterations and the final cost and constraint violation."""

    v: np.ndarray
    status: str
    iterations: int
    cost: float
    violation: float

    @property
    def success(self) -> bool:
        return self.status == "converged"


def _csc(J) -> sp.csc_matrix:
    return sp.csc_matrix(J) if not sp.issparse(J) else J.tocsc()


def gauss_newton(
    full: Callable[[np.ndarray], tuple],
    values: Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]],
    v0: np.ndarray,
    lo: np.ndarray,
    hi: np.ndarray,
    max_iter: int = 100,
    gtol: float = GTOL,
    rtol: float = RTOL,
) -> Outcome:
    """Minimise from ``v0``. ``full(v) -> (r, J_r, g, J_g)`` (Jacobians scipy sparse or
    dense), ``values(v) -> (r, g)``; ``lo <= v <= hi`` (equal bounds fix an unknown)."""
    v = np.clip(np.asarray(v0, dtype=float), lo, hi)
    fixed = lo == hi
    try:
        r, Jr, g, Jg = full(v)
    except RuntimeError as exc:
        return Outcome(v, f"evaluation failed at the start ({_why(exc)})", 0, np.inf, np.inf)
    mu, nu = 0.0, 1.0
    cost = 0.5 * float(r @ r)
    for it in range(max_iter):
        Jr, Jg = _csc(Jr), _csc(Jg)
        viol = float(np.max(np.abs(g), initial=0.0))
        active = fixed.copy()
        for _ in range(len(v) + 1):
            dv, lam, pred = _step(r, Jr, g, Jg, active, mu)
            if dv is None:
                return Outcome(v, "singular KKT system (a parameter the data do not move?)",
                               it, 2 * cost, viol)
            trial = v + dv
            out = (trial < lo - 1e-15) | (trial > hi + 1e-15)
            if not out.any():
                break
            active |= out
            v = np.where(out & (trial < lo), lo, np.where(out, hi, v))
        if viol <= gtol and pred <= rtol * (1 + cost):
            return Outcome(v, "converged", it, 2 * cost, viol)
        nu = max(nu, 1.1 * float(np.max(np.abs(lam), initial=0.0)))
        merit = cost + nu * float(np.sum(np.abs(g)))
        decrease = pred + nu * float(np.sum(np.abs(g)))
        alpha, accepted = 1.0, False
        while alpha >= 1e-4:
            trial = np.clip(v + alpha * dv, lo, hi)
            try:
                rt, gt = values(trial)
            except RuntimeError:
                alpha *= 0.5
                continue
            mt = 0.5 * float(rt @ rt) + nu * float(np.sum(np.abs(gt)))
            if np.isfinite(mt) and mt <= merit - 1e-4 * alpha * decrease:
                accepted = True
                break
            alpha *= 0.5
        if not accepted:
            if mu >= 1e6:
                return Outcome(v, "no descent (line search failed at the largest damping)",
                               it, 2 * cost, viol)
            mu = max(1e-4, 10 * mu)
            continue
        mu = mu / 10 if alpha == 1.0 else mu
        mu = 0.0 if mu < 1e-6 else mu
        v = trial
        try:
            r, Jr, g, Jg = full(v)
        except RuntimeError as exc:
            return Outcome(v, f"evaluation failed ({_why(exc)})", it, np.inf, np.inf)
        cost = 0.5 * float(r @ r)
    viol = float(np.max(np.abs(g), initial=0.0))
    return Outcome(v, f"no convergence in {max_iter} iterations", max_iter, 2 * cost, viol)


def _step(r, Jr, g, Jg, active, mu):
    """The Gauss-Newton-SQP step with ``active`` unknowns held, the multipliers and the
    predicted cost decrease; (None, None, None) if the KKT matrix is singular."""
    free = np.flatnonzero(~active)
    A, B = Jr[:, free], Jg[:, free]
    H = (A.T @ A).tocsc()
    if mu:
        d = H.diagonal()
        H = H + sp.diags(mu * np.maximum(d, 1e-12 * max(d.max(initial=0.0), 1.0)))
    n, m = len(free), B.shape[0]
    K = sp.bmat([[H, B.T], [B, None]], format="csc")
    rhs = np.concatenate([-(A.T @ r), -g])
    with np.errstate(all="ignore"):
        try:
            sol = spla.spsolve(K, rhs)
        except RuntimeError:
            return None, None, None
    if not np.all(np.isfinite(sol)):
        return None, None, None
    dv = np.zeros(Jr.shape[1])
    dv[free] = sol[:n]
    lin = r + A @ sol[:n]
    pred = 0.5 * float(r @ r) - 0.5 * float(lin @ lin)
    return dv, sol[n : n + m], max(pred, 0.0)


def _why(exc: BaseException) -> str:
    lines = [ln for ln in str(exc).splitlines() if ln.strip()]
    return lines[-1][:160] if lines else type(exc).__name__
