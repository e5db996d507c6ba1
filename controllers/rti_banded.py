"""The RTI's lifted intervals solved by the bordered banded LU in numpy
(:mod:`.banded_lu`; ``linear_solver`` "banded", uncompiled): :class:`BandedLift`, and
:class:`BandedCalls`, the three calls of a sample with the solves between CasADi's.

Same step as :class:`~.rti_lift.FactoredLift` (the factorisation kept, each use solving
only what it needs: the condensing ``1 + (k + 1) nu`` right-hand sides at interval
``k``, the feedback and the update one per interval), but the solves are scipy's LAPACK
calls, so they run in Python between the Functions: the preparation's condensed ``c_k``,
``G_k`` (``CC``, ``GG``), the measured state's deviation carried to every node (``DXA``,
written into the prepared data just before the feedback) and the stage corrections
(``DV``, just before the update) are data the Functions read. The law as one CasADi
Function (:attr:`~.rti.RealTimeIteration.law`) is the dense lift's: same step, its
commands equal to round-off.
"""

from __future__ import annotations

import casadi as cs
import numpy as np

from sarcomere.dynamics.modeling.buffered import BufferedCall

from .banded_lu import BorderedBand


class BandedLift:
    """The lifted intervals' Jacobians (``RV``, ``R`` and the nonzeros of ``R_x``,
    ``R_v``: :attr:`lin`, mapped) and the data the Functions read (:attr:`names`)."""

    def __init__(self, pb, N: int, structure: dict) -> None:
        nx, nu, d = pb.nx, pb.nu, pb.s.degree
        self.nx, self.nu, self.N, self.n = nx, nu, N, nx * d
        V, xi, v = cs.SX.sym("V", nx * d), cs.SX.sym("xi", nx), cs.SX.sym("v", nu)
        ps = cs.SX.sym("p", pb.np)
        R = pb.res(xi, V, cs.vertcat(v, ps), pb.dt)
        RV, RX, RU = cs.jacobian(R, V), cs.jacobian(R, xi), cs.jacobian(R, v)
        outs = cs.cse([RV, R, cs.vertcat(*RX.nonzeros()), cs.vertcat(*RU.nonzeros())])
        self.lin = cs.Function("radau_jacobians", [V, xi, v, ps], outs).map(N)
        self.band = BorderedBand(structure, self.lin.sparsity_out(0), N)
        # where the nonzeros of R_x and R_v go in their dense (n x nx, n x nu) arrays
        self.at = [np.ravel_multi_index(M.sparsity().get_triplet(), M.shape) for M in (RX, RU)]
        self.head_names = ["RV", "R", "RX", "RU"]
        self.names = ["CC", "GG", "DXA", "DV"]

    def symbols(self) -> list[cs.MX]:
        nx, N, nq = self.nx, self.N, self.N * self.nu
        sizes = {"CC": (nx, N), "GG": (nx, N * nq), "DXA": (nx, N), "DV": (self.n, N)}
        return [cs.MX.sym(k, *sizes[k]) for k in self.names]

    def condense(self, D: dict, Xb: cs.MX, Vb: cs.MX, nq: int) -> tuple[list, list]:
        """Every node's ``c_k`` and ``G_k``, node 0 included (zeros), as condensed in
        :meth:`BandedCalls.prepare`."""
        cc = [cs.MX(self.nx, 1)] + [D["CC"][:, k] for k in range(self.N)]
        GG = [cs.MX(self.nx, nq)] + [D["GG"][:, k * nq : (k + 1) * nq] for k in range(self.N)]
        return cc, GG

    def carry(self, D: dict, k: int, dx: cs.MX) -> cs.MX:
        """The measured state's deviation at node ``k + 1`` (:meth:`BandedCalls.feedback`
        carried it)."""
        return D["DXA"][:, k]

    def stages(self, D: dict, k: int, dx: cs.MX, du: cs.MX) -> cs.MX:
        """``dV_k`` (:meth:`BandedCalls.update` solved it)."""
        return D["DV"][:, k]


class BandedCalls:
    """The sample's three calls (the signatures of :attr:`~.rti.RealTimeIteration.calls`)
    around the CasADi Functions ``head``, ``tail``, ``feedback`` and ``update`` built
    with a :class:`BandedLift`; ``slots`` the data's ``DXA`` and ``DV`` slices."""

    def __init__(self, xs, lift: BandedLift, head, tail, feedback, update, slots) -> None:
        self.xs, self.lift, self.slots = xs, lift, slots
        self.head, self.tail = BufferedCall(head, copy=False), BufferedCall(tail, copy=False)
        self.fb, self.up = BufferedCall(feedback), BufferedCall(update)
        for i, j in ((0, 0), (1, 1), (2, 2), (7, 7), (8, 8)):  # read in place
            self.tail.share(i, self.head.res[j])
        self.fb.share(0, self.tail.res[0])
        self.up.share(0, self.tail.res[0])
        self.res = self.tail.res

    def prepare(self, mem, x, u, p) -> np.ndarray:
        """The Jacobians, the factorisation, the condensing ``c_k``, ``G_k`` (the moves'
        directions carried forward), then the tail's QP data."""
        lift, N, nx, nu = self.lift, self.lift.N, self.lift.nx, self.lift.nu
        Xb, Ub, Vb, RV, R, RX, RU, YT, CYT = self.head.outputs(mem, x, u, p)
        lift.band.factor(RV)
        self.Xb, self.Vb = Xb.reshape(N + 1, nx).T, Vb.reshape(N, -1).T
        self.R = R.reshape(N, -1).T
        self.RX, self.RU = (
            _dense(nz.reshape(N, -1), at, (N, lift.n, m))
            for nz, at, m in ((RX, lift.at[0], nx), (RU, lift.at[1], nu))
        )
        nq, end = N * nu, slice(lift.n - nx, None)  # the interval's end: the last stage
        CC, GG = np.zeros((nx, N)), np.zeros((nx, N * nq))
        c, G = np.zeros(nx), np.zeros((nx, 0))
        for k in range(N):
            B = np.hstack([(self.R[:, k] + self.RX[k] @ c)[:, None], self.RX[k] @ G, self.RU[k]])
            Y = lift.band.solve(k, B, end)
            c = self.Vb[-nx:, k] + Y[:, 0] - self.Xb[:, k + 1]
            G = Y[:, 1:]
            CC[:, k], GG[:, k * nq : k * nq + G.shape[1]] = c, G
        empty = np.zeros(nx * N + lift.n * N)
        return self.tail(Xb, Ub, Vb, CC, GG, empty[: nx * N], empty[nx * N :], YT, CYT)

    def _a0(self, x: np.ndarray) -> np.ndarray:
        """The measured state's distance from the guess (scaled)."""
        return x / self.xs - self.Xb[:, 0]

    def feedback(self, data, mem, x, u_prev, ref) -> list[np.ndarray]:
        """The measured state's deviation carried through the intervals (one solve per
        interval) into the data, then the feedback Function."""
        lift, dx = self.lift, self._a0(x)
        DXA, end = np.empty((lift.nx, lift.N)), slice(lift.n - lift.nx, None)
        for k in range(lift.N):
            dx = lift.band.solve(k, (self.RX[k] @ dx)[:, None], end)[:, 0]
            DXA[:, k] = dx
        data[self.slots["DXA"]] = DXA.reshape(-1, order="F")
        return self.fb.outputs(data, mem, x, u_prev, ref)

    def update(self, data, mem, x, u_prev, step) -> np.ndarray:
        """The stage corrections of the step (one solve per interval) into the data, then
        the update Function."""
        lift, N, nx, nu = self.lift, self.lift.N, self.lift.nx, self.lift.nu
        du = np.cumsum(np.reshape(step[: N * nu], (N, nu)), axis=0)  # the inputs' corrections
        dx, DV = self._a0(x), np.empty((lift.n, N))
        for k in range(N):
            b = self.R[:, k] + self.RX[k] @ dx + self.RU[k] @ du[k]
            DV[:, k] = lift.band.solve(k, b[:, None])[:, 0]
            dx = self.Vb[-nx:, k] + DV[-nx:, k] - self.Xb[:, k + 1]
        data[self.slots["DV"]] = DV.reshape(-1, order="F")
        return self.up(data, mem, x, u_prev, step)


def _dense(nz: np.ndarray, at: np.ndarray, shape: tuple) -> np.ndarray:
    """Matrices (``shape``: count x rows x columns) from their nonzeros (a row each) at
    the flat positions ``at``."""
    out = np.zeros((shape[0], shape[1] * shape[2]))
    out[:, at] = nz
    return out.reshape(shape)
