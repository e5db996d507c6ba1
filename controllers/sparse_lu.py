"""A sparse LU solve of the Radau collocation Jacobian written out as CasADi SX expressions.

The RTI's lifted solve ``R_V^{-1} [R, R_x, R_v]`` per interval (:mod:`.nmpc`) has a
54 x 54 matrix at n = 3, degree 3, with 387 of its 2916 entries structurally nonzero:
``R_V = h blockdiag(J_1 .. J_d) - D kron I`` (``J_j`` the ODE's Jacobian at collocation point
``j``, ``D`` the Radau differentiation matrix). Ordered state by state (a state's ``d``
collocation values together) the matrix is ``J``'s pattern of ``d x d`` blocks, and
Gaussian elimination in a minimum-degree order of that pattern fills little.
:func:`solve` eliminates in that order on the structural nonzeros only and returns the
solution as SX expressions: the same Function then holds the Jacobians and the solve, it
generates to C (CasADi's LAPACK solvers do not), and compiled it runs about 3x faster than
the Jacobians plus LAPACK's dense LU.

No pivoting: the pivots are the diagonal ``d x d`` blocks' (``h J_ii - D``, dominated by
``D``'s well-conditioned entries for the stiff states' negative ``J_ii``). A zero pivot
gives a non-finite solution, which the RTI treats as a failed sample.
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


def _rows(M: cs.SX, order: list[int] | None = None) -> list[dict[int, cs.SX]]:
    """The structural nonzeros of ``M`` row by row (columns renumbered by ``order``)."""
    sp, pos = M.sparsity(), None if order is None else {c: i for i, c in enumerate(order)}
    rows: list[dict[int, cs.SX]] = [{} for _ in range(M.shape[0])]
    for c in range(M.shape[1]):
        for k in range(sp.colind()[c], sp.colind()[c + 1]):
            rows[sp.row()[k]][c if pos is None else pos[c]] = M.nz[k]
    return rows


def solve(A: cs.SX, B: cs.SX, order: list[int]) -> cs.SX:
    """``A^{-1} B`` by Gaussian elimination without pivoting, rows and columns of ``A`` in
    ``order``, on structural nonzeros only (dense result)."""
    n = A.shape[0]
    a, b = _rows(A, order), _rows(B)
    U, rhs = [a[o] for o in order], [b[o] for o in order]
    for k in range(n):  # forward elimination, the right-hand sides along
        inv = 1 / U[k][k]
        for i in range(k + 1, n):
            if k not in U[i]:
                continue
            m = U[i].pop(k) * inv
            for c, v in U[k].items():
                if c > k:
                    U[i][c] = U[i].get(c, 0) - m * v
            for c, v in rhs[k].items():
                rhs[i][c] = rhs[i].get(c, 0) - m * v
    X: list[dict[int, cs.SX]] = [{} for _ in range(n)]
    for k in reversed(range(n)):  # back substitution
        row = dict(rhs[k])
        for c, v in U[k].items():
            if c > k:
                for j, x in X[c].items():
                    row[j] = row.get(j, 0) - v * x
        inv = 1 / U[k][k]
        X[k] = {j: x * inv for j, x in row.items()}
    out = cs.SX.zeros(n, B.shape[1])
    for k, row in enumerate(X):
        for j, x in row.items():
            out[order[k], j] = x
    return out
