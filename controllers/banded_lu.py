"""A bordered banded LU of the Radau collocation Jacobians with scipy's LAPACK, for the
uncompiled real-time iteration (:mod:`.rti`, ``linear_solver`` "banded").

The dense lift (:class:`~.rti_lift.DenseLift`) solves ``L_k = -R_V^{-1} [R, R_x, R_v]``
per interval. A chain's ODE Jacobian couples each state with its neighbours only, apart
from a few states coupled with all (the regulator's pressure drives every chamber): with
those states' unknowns moved last (the border) and the others in reverse Cuthill-McKee
order, ``R_V`` (rows and columns permuted, ``P R_V P^T``) is ``[[A, B], [C, E]]`` with
``A`` banded. :class:`BorderedBand` finds that structure once from ``R_V``'s sparsity
(:func:`bordered_band`: the border grown greedily, state by state, while the estimated
flops fall; ``None`` with the reason when the band does not pay) and solves
all intervals per call: ``A``'s LU with partial pivoting inside the band
(``dgbtrf``), ``Y = A^{-1} [b_1, B]`` (``dgbtrs``), then the border by the Schur
complement ``S = E - C A^{-1} B``: ``x_2 = S^{-1} (b_2 - C A^{-1} b_1)``,
``x_1 = A^{-1} b_1 - A^{-1} B x_2``. At n = 10 (159 unknowns, the band 20 below and 20
above the diagonal of 156, border 3) that is about a fifth of the dense LU's flops.

A singular ``A`` (``dgbtrf`` info > 0) gives NaN, which the RTI treats as a failed
sample, as it does a singular dense LU.
"""

from __future__ import annotations

import casadi as cs
import numpy as np
import scipy.sparse as ssp
from scipy.linalg import lapack
from scipy.sparse.csgraph import reverse_cuthill_mckee

BAND_SHARE = 0.5
"""The band is used when its estimated flops are below this share of the dense LU's."""


def _flops(kl: int, ku: int, m: int, nb: int, w: int) -> float:
    """Multiply-adds of the bordered band's LU and solves with ``w`` right-hand sides: the
    band's, the border's products and the Schur complement's dense LU and solves."""
    band = m * kl * (kl + ku) + m * (2 * kl + ku) * (w + nb)
    return band + nb * m * (w + 2 * nb) + nb**3 / 3 + nb * nb * w


def _band(P: np.ndarray, unknowns: list[int]) -> tuple[list[int], int, int]:
    """``unknowns`` in reverse Cuthill-McKee order of ``P``'s symmetric pattern, and the
    band's widths below and above the diagonal in that order."""
    S = P[np.ix_(unknowns, unknowns)]
    o = reverse_cuthill_mckee(ssp.csr_matrix(S | S.T), symmetric_mode=True)
    r, c = np.nonzero(S[np.ix_(o, o)])
    return [unknowns[i] for i in o], int(max(0, (r - c).max())), int(max(0, (c - r).max()))


def bordered_band(P: np.ndarray, nx: int, d: int, w: int) -> tuple[dict | None, str]:
    """The bordered band of the collocation Jacobian's pattern ``P`` (``nx d`` square,
    stage-major unknowns: a state's ``d`` values are ``i, nx + i, ..``) for ``w``
    right-hand sides: ``(structure, "")``, or ``(None, reason)`` when the band's estimated
    flops are not below :data:`BAND_SHARE` of the dense LU's. The border is grown state by
    state (the one whose move lowers the estimate most) while the estimate falls."""
    n = nx * d

    def bordered(border: list[int]) -> dict:
        rest = [j * nx + i for i in range(nx) if i not in border for j in range(d)]
        order, kl, ku = _band(P, rest)
        cost = _flops(kl, ku, len(rest), d * len(border), w)
        outer = [j * nx + i for i in border for j in range(d)]
        return {"perm": order + outer, "m": len(rest), "kl": kl, "ku": ku, "cost": cost,
                "border": border}  # fmt: skip

    best = bordered([])
    while len(best["border"]) < nx - 1:  # the state whose move to the border pays most
        left = [i for i in range(nx) if i not in best["border"]]
        trial = min((bordered([*best["border"], i]) for i in left), key=lambda t: t["cost"])
        if trial["cost"] >= best["cost"]:
            break
        best = trial
    dense = n**3 / 3 + n * n * w
    if best["cost"] >= BAND_SHARE * dense:
        return None, (
            f"the collocation Jacobian's band ({best['kl']} below and {best['ku']} above "
            f"the diagonal of {best['m']} unknowns, border {n - best['m']}) costs "
            f"{best['cost'] / dense:.0%} of the dense LU's flops"
        )
    return best, ""


class BorderedBand:
    """``-R_V^{-1} RB`` for the ``N`` intervals of the mapped Jacobians (``RV``:
    ``n x N n``, ``RB``: ``n x N w``, CasADi's column-major nonzeros) by the bordered
    banded LU of ``structure`` (:func:`bordered_band`); :meth:`solve` returns the dense
    ``n x N w`` result's column-major values, the dense lift's ``L``."""

    def __init__(self, structure: dict, sp_rv: cs.Sparsity, sp_rb: cs.Sparsity, N: int):
        perm, m, kl, ku = (structure[k] for k in ("perm", "m", "kl", "ku"))
        n, w = sp_rv.size1(), sp_rb.size2() // N
        self.N, self.n, self.w, self.m, self.kl, self.ku = N, n, w, m, kl, ku
        self.nb, self.ld = n - m, 2 * kl + ku + 1
        self.pos = np.empty(n, dtype=int)
        self.pos[perm] = np.arange(n)
        # where each nonzero of RV goes: A's band storage (per interval m x ld, the
        # transpose of LAPACK's column-major ldab x m), the right-hand sides' block
        # (w + nb columns x m rows: B joins b_1), C, E
        r, c = (np.array(v) for v in sp_rv.get_triplet())
        k, r, c = c // n, self.pos[r], self.pos[c % n]
        nb, ld, wb = self.nb, self.ld, w + self.nb
        parts = {
            "A": ((r < m) & (c < m), k * m * ld + c * ld + kl + ku + r - c),
            "Y": ((r < m) & (c >= m), k * wb * m + (w + c - m) * m + r),
            "C": ((r >= m) & (c < m), k * nb * m + (r - m) * m + c),
            "E": ((r >= m) & (c >= m), k * nb * nb + (r - m) * nb + c - m),
        }
        self.rv = {key: (np.flatnonzero(sel), idx[sel]) for key, (sel, idx) in parts.items()}
        r, c = (np.array(v) for v in sp_rb.get_triplet())
        k, r, c = c // w, self.pos[r], c % w
        self.rb = {
            "Y": (np.flatnonzero(r < m), (k * wb * m + c * m + r)[r < m]),
            "b2": (np.flatnonzero(r >= m), (k * nb * w + (r - m) * w + c)[r >= m]),
        }

    def _fill(self, shape, parts: list[tuple[np.ndarray, tuple]]) -> np.ndarray:
        out = np.zeros(shape)
        flat = out.reshape(-1)
        for values, (src, dst) in parts:
            flat[dst] = values[src]
        return out

    def solve(self, rv: np.ndarray, rb: np.ndarray) -> np.ndarray:
        N, m, w, nb, kl, ku = self.N, self.m, self.w, self.nb, self.kl, self.ku
        A = self._fill((N, m, self.ld), [(rv, self.rv["A"])])
        Y = self._fill((N, w + nb, m), [(rv, self.rv["Y"]), (rb, self.rb["Y"])])
        for k in range(N):  # A[k].T, Y[k].T: LAPACK's column-major arrays, in place
            lu, piv, info = lapack.dgbtrf(A[k].T, kl, ku, overwrite_ab=1)
            if info != 0:
                Y[k] = np.nan
                continue
            Y[k] = lapack.dgbtrs(lu, kl, ku, Y[k].T, piv, overwrite_b=1)[0].T
        # the transposed solutions (a right-hand side per row) throughout: contiguous blocks
        if nb:
            Yb, Yc = Y[:, :w, :], Y[:, w:, :]  # (A^{-1} b_1)^T, (A^{-1} B)^T
            C = self._fill((N, nb, m), [(rv, self.rv["C"])])
            E = self._fill((N, nb, nb), [(rv, self.rv["E"])])
            b2 = self._fill((N, nb, w), [(rb, self.rb["b2"])])
            CT = C.transpose(0, 2, 1)
            S = E - (Yc @ CT).transpose(0, 2, 1)  # E - C A^{-1} B
            x2 = np.linalg.solve(S, b2 - (Yb @ CT).transpose(0, 2, 1)).transpose(0, 2, 1)
            Y = np.concatenate([x2 @ Yc - Yb, -x2], axis=2)
        else:
            Y = -Y
        # back to the unknowns' order: the dense n x N w matrix's column-major values
        return np.take(Y, self.pos, axis=2).reshape(-1)
