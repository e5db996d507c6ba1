"""A sparse LU of the Radau collocation Jacobian written out as CasADi SX expressions.

Two users solve with the Jacobian ``R_V`` of a Radau IIA step's collocation equations
in generated C: the NMPC's lifted solves ``R_V^{-1} B`` per interval
(:mod:`sarcomere.controllers.rti_lift`) and the fit's steps, their Newton and their
sensitivities (:mod:`sarcomere.dynamics.identification.shooting`). ``R_V`` is a
54 x 54 matrix at n = 3, degree 3, with 387 of its 2916 entries structurally nonzero
(159 x 159 with 1269 at n = 10):
``R_V = h blockdiag(J_1 .. J_d) - D kron I`` (``J_j`` the ODE's Jacobian at collocation point
``j``, ``D`` the Radau differentiation matrix). Ordered state by state (a state's ``d``
collocation values together) the matrix is ``J``'s pattern of ``d x d`` blocks, and
Gaussian elimination in a minimum-degree order of that pattern fills little.
:class:`Factors` eliminates in that order on the structural nonzeros only and returns the
factors' values as SX expressions (the same Function then holds the Jacobians and the
factorisation; it generates to C, CasADi's LAPACK solvers do not), and the solve with one
right-hand side as a small SX Function of those values, mapped over as many right-hand
sides as a use needs: the factorisation is made once per interval and kept.

No pivoting: the pivots are the diagonal ``d x d`` blocks' (``h J_ii - D``, dominated by
``D``'s well-conditioned entries for the stiff states' negative ``J_ii``). A zero pivot
gives a non-finite solution, which the RTI treats as a failed sample and the fit's step
as a failed Newton (it falls back to CasADi's pivoting sparse QR).
"""

from __future__ import annotations

import casadi as cs
import numpy as np


def block_order(pattern: np.ndarray, nx: int, d: int) -> list[int]:
    """Elimination order of a ``(nx d) x (nx d)`` collocation Jacobian with stage-major
    unknowns (``V = [v_1; ..; v_d]``): states in the minimum-degree order of the states'
    pattern (any stage coupling counted), each state's ``d`` stage values together."""
    blocks = pattern.reshape(d, nx, d, nx).any(axis=(0, 2))
    adj = [set(np.flatnonzero(blocks[i] | blocks[:, i])) - {i} for i in range(nx)]
    left, states = set(range(nx)), []
    while left:  # greedy minimum degree, ties to the lowest index
        k = min(left, key=lambda i: (len(adj[i] & left), i))
        for a in adj[k] & left:
            adj[a] |= (adj[k] & left) - {a}
        states.append(k)
        left.remove(k)
    return [j * nx + i for i in states for j in range(d)]


def collocation_factors(RV: cs.SX, nx: int, d: int) -> Factors:
    """The :class:`Factors` of a collocation Jacobian ``RV`` (``nx`` states, ``d`` stages,
    stage-major) in the :func:`block_order` of its structural pattern."""
    return Factors(RV, block_order(np.array(cs.DM(RV.sparsity(), 1)) != 0, nx, d))


def _rows(M: cs.SX, order: list[int] | None = None) -> list[dict[int, cs.SX]]:
    """The structural nonzeros of ``M`` row by row (columns renumbered by ``order``)."""
    sp, pos = M.sparsity(), None if order is None else {c: i for i, c in enumerate(order)}
    rows: list[dict[int, cs.SX]] = [{} for _ in range(M.shape[0])]
    for c in range(M.shape[1]):
        for k in range(sp.colind()[c], sp.colind()[c + 1]):
            rows[sp.row()[k]][c if pos is None else pos[c]] = M.nz[k]
    return rows


class Factors:
    """The sparse LU of ``A`` (rows and columns in ``order``, no pivoting, structural
    nonzeros only) as a vector of SX expressions, :attr:`values`, and the elimination's
    pattern, to solve with any right-hand side later: :meth:`solve_function`.

    ``values`` holds, step by step, the multipliers of the rows eliminated, the upper
    factor's row beyond the pivot and the pivot's inverse; their positions are recorded
    in :attr:`lower` and :attr:`upper` (plain integers: no expression kept)."""

    def __init__(self, A: cs.SX, order: list[int]) -> None:
        n, a = A.shape[0], _rows(A, order)
        U, values = [a[o] for o in order], []
        self.order, self.lower, self.upper = order, [], []
        for k in range(n):  # forward elimination
            inv, steps = 1 / U[k][k], []
            for i in range(k + 1, n):
                if k not in U[i]:
                    continue
                m = U[i].pop(k) * inv
                for c, v in U[k].items():
                    if c > k:
                        U[i][c] = U[i].get(c, 0) - m * v
                steps.append((i, len(values)))
                values.append(m)
            self.lower.append(steps)
            row = []
            for c, v in U[k].items():
                if c > k:
                    row.append((c, len(values)))
                    values.append(v)
            self.upper.append((row, len(values)))
            values.append(inv)
        self.values = cs.vertcat(*values)

    def solve_function(self, name: str = "lu_solve") -> cs.Function:
        """``(values, b) -> A^{-1} b`` for one column ``b`` as an SX Function (map it for
        several)."""
        n = len(self.order)
        v, b = cs.SX.sym("values", self.values.numel()), cs.SX.sym("b", n)
        y = [b[o] for o in self.order]
        for k, steps in enumerate(self.lower):  # L y = P b
            for i, j in steps:
                y[i] = y[i] - v[j] * y[k]
        x: list = [None] * n
        for k in reversed(range(n)):  # U x = y
            row, inv = self.upper[k]
            acc = y[k]
            for c, j in row:
                acc = acc - v[j] * x[c]
            x[k] = acc * v[inv]
        out = cs.SX.zeros(n)
        for k, xk in enumerate(x):
            out[self.order[k]] = xk
        return cs.Function(name, [v, b], [out], ["values", "b"], ["x"])
