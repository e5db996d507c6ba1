"""Which experiment next: candidate experiments ranked by the information they would add
at the current estimate (D-optimality).

A candidate is a :class:`~.problem.Problem` over the same estimated parameters whose
experiments have not been run (its data values are placeholders: only the noise of its
measured signals matters). Simulated at the estimate, its weighted sensitivities
``S_c`` add ``S_c^T S_c`` to the Fisher information ``F`` of the fitted experiments; the
D-optimality gain is ``ln det(F + S_c^T S_c) - ln det F`` (the 95 % confidence ellipsoid
of the search variables shrinks by ``exp(-gain / 2)`` in volume), with ``F`` regularised
by :data:`RIDGE` of its largest diagonal entry where it is singular (a structurally
non-identifiable set: the gain then also counts directions the data did not reach). The
parameter a candidate pins down best is the one whose variance it reduces most,
relatively.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from ..errors import SolverError
from .problem import Problem, Solution
from .uncertainty import sensitivities

RIDGE = 1e-10
"""Regularisation of a singular Fisher information, relative to its largest diagonal."""


def _logdet(F: np.ndarray, ridge: float) -> float:
    return float(np.linalg.slogdet(F + ridge * np.eye(len(F)))[1])


def rank(
    fitted: Problem,
    sol: Solution,
    candidates: Sequence[tuple[str, Problem]],
    sigma: dict[str, float] | None = None,
) -> list[dict]:
    """``candidates`` (name, problem) sorted by D-optimality gain, each with ``gain``,
    ``volume_factor``, ``pins`` (the parameter whose variance falls most) and the variance
    reduction per parameter; a candidate whose simulation fails is listed with ``why``."""
    S = sensitivities(fitted, sol)
    F = S.T @ S
    ridge = RIDGE * max(float(np.max(np.diag(F), initial=0.0)), 1e-300)
    base = _logdet(F, ridge)
    var0 = np.diag(np.linalg.inv(F + ridge * np.eye(len(F))))
    names = [e.name for e in fitted.params]
    out = []
    for name, cand in candidates:
        try:
            v = cand.initial_guess(sol.theta)
        except SolverError as exc:
            out.append({"candidate": name, "gain": None, "why": str(exc)})
            continue
        Sc = sensitivities(cand, cand.evaluate(v, cand.weights(sigma)))
        Fn = F + Sc.T @ Sc
        gain = _logdet(Fn, ridge) - base
        var1 = np.diag(np.linalg.inv(Fn + ridge * np.eye(len(Fn))))
        reduction = 1.0 - var1 / var0
        k = int(np.argmax(reduction))
        out.append(
            {
                "candidate": name,
                "gain": gain,
                "volume_factor": float(np.exp(-gain / 2)),
                "pins": names[k],
                "variance_reduction": dict(zip(names, reduction.tolist(), strict=True)),
            }
        )
    return sorted(out, key=lambda r: -np.inf if r["gain"] is None else -r["gain"])


__all__ = ["rank"]
