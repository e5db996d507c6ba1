"""A bordered banded LU of the Radau collocation Jacobians with scipy's LAPACK, for the
uncompiled real-time iteration (:mod:`.rti`, ``linear_solver`` "banded").

The lifted intervals of :mod:`.rti_banded` solve ``-R_V^{-1} b`` per interval. A
chain's ODE Jacobian couples each state with its neighbours only, apart from a few
states coupled with all (the regulator's pressure drives every chamber): with
those states' unknowns moved last (the border) and the others in reverse Cuthill-McKee
order, ``R_V`` (rows and columns permuted, ``P R_V P^T``) is ``[[A, B], [C, E]]`` with
``A`` banded. :func:`bordered_band` finds that structure once from ``R_V``'s sparsity
(the border grown greedily, state by state, while the estimated flops fall; ``None``
with the reason when the band does not pay); :class:`BorderedBand` factorises every
interval per preparation, ``A``'s LU with partial pivoting inside the band (``dgbtrf``),
``A^{-1} B`` and the Schur complement ``S = E - C A^{-1} B``, and solves any right-hand
side later: ``y = A^{-1} b_1`` (``dgbtrs``), ``x_2 = S^{-1} (b_2 - C y)``,
``x_1 = y - A^{-1} B x_2``. At n = 10 (159 unknowns: the band 18 below and 18 above the
diagonal of 153, border 6, the regulator's and one more state's) a solve is about a
third of the dense LU's flops, its factorisation a tenth.

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
    """The bordered banded LU of the ``N`` intervals' ``R_V`` (their mapped nonzeros,
    ``n x N n`` of sparsity ``sp_rv``, CasADi's column-major order) by ``structure``
    (:func:`bordered_band`): :meth:`factor` once per preparation, then :meth:`solve`
    ``-R_V^{-1} b`` for interval ``k`` as often as a use needs."""

    def __init__(self, structure: dict, sp_rv: cs.Sparsity, N: int) -> None:
        perm, m, kl, ku = (structure[k] for k in ("perm", "m", "kl", "ku"))
        n = sp_rv.size1()
        self.N, self.n, self.m, self.kl, self.ku = N, n, m, kl, ku
        self.nb, self.ld = n - m, 2 * kl + ku + 1
        self.perm = np.asarray(perm)
        # where each nonzero goes: A's band storage (per interval m x ld, the transpose
        # of LAPACK's column-major ldab x m), B (transposed: nb x m), C (nb x m), E
        r, c = (np.array(v) for v in sp_rv.get_triplet())
        self.pos = pos = np.empty(n, dtype=int)
        pos[perm] = np.arange(n)
        k, r, c = c // n, pos[r], pos[c % n]
        nb, ld = self.nb, self.ld
        parts = {
            "A": ((r < m) & (c < m), k * m * ld + c * ld + kl + ku + r - c),
            "B": ((r < m) & (c >= m), k * nb * m + (c - m) * m + r),
            "C": ((r >= m) & (c < m), k * nb * m + (r - m) * m + c),
            "E": ((r >= m) & (c >= m), k * nb * nb + (r - m) * nb + c - m),
        }
        self.at = {key: (np.flatnonzero(sel), idx[sel]) for key, (sel, idx) in parts.items()}

    def _fill(self, rv: np.ndarray, key: str, shape: tuple) -> np.ndarray:
        out = np.zeros(shape)
        src, dst = self.at[key]
        out.reshape(-1)[dst] = rv[src]
        return out

    def factor(self, rv: np.ndarray) -> None:
        """``A``'s LU per interval (``dgbtrf``), ``A^{-1} B`` and the inverse of the Schur
        complement ``S = E - C A^{-1} B``; a singular interval's solves give NaN."""
        N, m, nb, kl, ku = self.N, self.m, self.nb, self.kl, self.ku
        self.A = self._fill(rv, "A", (N, m, self.ld))
        self.ok = np.ones(N, dtype=bool)
        self.piv: list[np.ndarray] = []
        for k in range(N):  # A[k].T: LAPACK's column-major array, factorised in place
            piv, info = lapack.dgbtrf(self.A[k].T, kl, ku, overwrite_ab=1)[1:]
            self.piv.append(piv)
            self.ok[k] = info == 0
        if nb:
            self.C = self._fill(rv, "C", (N, nb, m))
            AB = self._fill(rv, "B", (N, nb, m))  # becomes (A^{-1} B)^T
            for k in range(N):
                AB[k] = self._band_solve(k, AB[k].T).T
            S = self._fill(rv, "E", (N, nb, nb)) - self.C @ AB.transpose(0, 2, 1)
            self.AB, self.Sinv = AB.transpose(0, 2, 1), np.linalg.inv(S)

    def _band_solve(self, k: int, b: np.ndarray) -> np.ndarray:
        if not self.ok[k]:
            return np.full(b.shape, np.nan)
        return lapack.dgbtrs(self.A[k].T, self.kl, self.ku, b, self.piv[k])[0]

    def solve(self, k: int, b: np.ndarray, rows: slice = slice(None)) -> np.ndarray:
        """Rows ``rows`` of ``-R_V^{-1} b`` for interval ``k`` (``b``: ``n`` x columns,
        the unknowns' order)."""
        bp = b[self.perm]
        y = self._band_solve(k, np.asfortranarray(bp[: self.m]))
        if self.nb:
            x2 = self.Sinv[k] @ (bp[self.m :] - self.C[k] @ y)
            y = np.concatenate([y - self.AB[k] @ x2, x2])
        return -y[self.pos[rows]]
