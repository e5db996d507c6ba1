"""The lifted Radau IIA intervals of the NMPC's real-time iteration (:mod:`.rti`): their
linearisation at the guess, and the three uses of its solves, in two forms.

Per interval ``k`` the collocation equations ``R(V, x, v) = 0`` linearised at the guess
give the stage corrections ``dV_k = -R_V^{-1} (R + R_x dx_k + R_v dv_k)``. The RTI needs
them three ways: the condensing (:meth:`condense`: every node's state correction
``dX_k = c_k + G_k du``, its part in the measured state left out), the feedback
(:meth:`carry`: the measured state's distance from the guess carried through an
interval's end, ``A_k dx``) and the update (:meth:`stages`: ``dV_k`` itself).

* :class:`DenseLift` (LAPACK's dense LU or CasADi's sparse QR, ``linear_solver``
  "lapacklu" or "qr"): ``L_k = -R_V^{-1} [R, R_x, R_v]`` solved in the preparation with
  ``1 + nx + nu`` right-hand sides per interval and kept; its end rows give ``A_k``,
  ``B_k``.
* :class:`FactoredLift` (``"sparse_lu"``): the sparse LU of ``R_V``
  (:class:`~sarcomere.dynamics.simulation.sparse_lu.Factors`, generated with the
  Jacobians) is kept instead, and each use solves with what
  it needs: the condensing carries the input moves' directions forward (``1 + (k + 1) nu``
  right-hand sides at interval ``k``: ``N + N (N + 1) nu / 2`` in all, against
  ``N (1 + nx + nu)``, which grows with the chain), the feedback one per interval, the
  update one per interval. Same step, other order of operations: the commands agree to
  round-off.
"""

from __future__ import annotations

import casadi as cs

from sarcomere.dynamics.simulation import sparse_lu


class DenseLift:
    """``L_k = -R_V^{-1} [R, R_x, R_v]`` per interval, solved by ``linsol`` (CasADi's
    "lapacklu" or "qr") in the preparation; the data keeps ``L`` (``nx d`` x ``N (1 + nx +
    nu)``)."""

    def __init__(self, pb, linsol: str, N: int) -> None:
        nx, nu, d = pb.nx, pb.nu, pb.s.degree
        self.nx, self.nu, self.N, self.w = nx, nu, N, 1 + nx + nu
        V, xi, v = cs.SX.sym("V", nx * d), cs.SX.sym("xi", nx), cs.SX.sym("v", nu)
        ps = cs.SX.sym("p", pb.np)
        R = pb.res(xi, V, cs.vertcat(v, ps), pb.dt)
        RV, RB = cs.jacobian(R, V), cs.horzcat(R, cs.jacobian(R, cs.vertcat(xi, v)))
        # common subexpressions of both Jacobians merged: 5114 instead of 6077 at n = 3
        self.lin = cs.Function("radau_lin", [V, xi, v, ps], cs.cse([RV, RB])).map(N)
        A, B = cs.MX.sym("RV", RV.sparsity()), cs.MX.sym("RB", RB.sparsity())
        self.solve = cs.Function("lift_solve", [A, B], [-cs.solve(A, B, linsol)]).map(N)
        self.head_names = ["RV", "RB"]
        self.names = ["L"]

    def between(self, lifted: list[cs.MX]) -> list[cs.MX]:
        """The preparation's step between the Jacobians and the condensing: the solves."""
        return [self.solve(*lifted)]

    def symbols(self) -> list[cs.MX]:
        return [cs.MX.sym("L", self.lin.size1_out(0), self.N * self.w)]

    def condense(self, D: dict, Xb: cs.MX, Vb: cs.MX, nq: int) -> tuple[list, list]:
        """Every node's ``c_k`` (nx) and ``G_k`` (nx x nq), node 0 included (zeros)."""
        nx, nu, w, L = self.nx, self.nu, self.w, D["L"]
        c, G = cs.MX(nx, 1), cs.MX(nx, nq)
        cc, GG = [c], [G]
        for k in range(self.N):
            Lk = L[-nx:, k * w : (k + 1) * w]  # the interval's end
            Ak, Bk = Lk[:, 1 : 1 + nx], Lk[:, 1 + nx :]
            c = Vb[-nx:, k] + Lk[:, 0] + cs.mtimes(Ak, c) - Xb[:, k + 1]
            G = cs.mtimes(Ak, G) + cs.horzcat(cs.MX(nx, k * nu), Bk, cs.MX(nx, nq - (k + 1) * nu))
            cc.append(c), GG.append(G)
        return cc, GG

    def carry(self, D: dict, k: int, dx: cs.MX) -> cs.MX:
        """``A_k dx``: a state correction at node ``k`` carried to node ``k + 1``."""
        w = self.w
        return cs.mtimes(D["L"][-self.nx :, k * w + 1 : k * w + 1 + self.nx], dx)

    def stages(self, D: dict, k: int, dx: cs.MX, du: cs.MX) -> cs.MX:
        """``dV_k`` for the node correction ``dx`` and the input correction ``du``."""
        Lk = D["L"][:, k * self.w : (k + 1) * self.w]
        return Lk[:, 0] + cs.mtimes(Lk[:, 1:], cs.vertcat(dx, du))


class FactoredLift:
    """The sparse LU of ``R_V`` per interval kept (with ``R``, ``R_x``, ``R_v``): the data
    holds ``F`` (the factors' values), ``R`` and the nonzeros of ``R_x`` and ``R_v``, all
    ``N`` columns; the solves are one small SX Function (:attr:`solve`) mapped over the
    right-hand sides each use has."""

    def __init__(self, pb, N: int) -> None:
        nx, nu, d = pb.nx, pb.nu, pb.s.degree
        self.nx, self.nu, self.N = nx, nu, N
        V, xi, v = cs.SX.sym("V", nx * d), cs.SX.sym("xi", nx), cs.SX.sym("v", nu)
        ps = cs.SX.sym("p", pb.np)
        R = pb.res(xi, V, cs.vertcat(v, ps), pb.dt)
        RV, RX, RU = cs.jacobian(R, V), cs.jacobian(R, xi), cs.jacobian(R, v)
        lu = sparse_lu.collocation_factors(RV, nx, d)
        self.spx, self.spu = RX.sparsity(), RU.sparsity()
        outs = cs.cse([lu.values, R, cs.vertcat(*RX.nonzeros()), cs.vertcat(*RU.nonzeros())])
        self.lin = cs.Function("radau_factor", [V, xi, v, ps], outs).map(N)
        self.solve = lu.solve_function("radau_solve")
        self._maps: dict[int, cs.Function] = {}
        self.head_names = self.names = ["F", "R", "RX", "RU"]

    def between(self, lifted: list[cs.MX]) -> list[cs.MX]:
        return lifted

    def symbols(self) -> list[cs.MX]:
        return [cs.MX.sym(n, self.lin.size1_out(i), self.N) for i, n in enumerate(self.names)]

    def _solve(self, F: cs.MX, B: cs.MX) -> cs.MX:
        """``-R_V^{-1} B`` for the ``B.shape[1]`` columns of ``B``."""
        m = B.shape[1]
        if m not in self._maps:
            self._maps[m] = self.solve if m == 1 else self.solve.map(m)
        return -self._maps[m](F, B)

    def _rx(self, D: dict, k: int) -> cs.MX:
        return cs.MX(self.spx, D["RX"][:, k])

    def condense(self, D: dict, Xb: cs.MX, Vb: cs.MX, nq: int) -> tuple[list, list]:
        """Every node's ``c_k`` (nx) and ``G_k`` (nx x nq), node 0 included (zeros): the
        constant and the moves' directions carried forward, ``1 + (k + 1) nu`` solves at
        interval ``k``."""
        nx, nu = self.nx, self.nu
        c, G = cs.MX(nx, 1), cs.MX(nx, nq)
        cc, GG = [c], [G]
        for k in range(self.N):
            RX = self._rx(D, k)
            B = cs.horzcat(
                D["R"][:, k] + cs.mtimes(RX, c),
                cs.mtimes(RX, G[:, : k * nu]),
                cs.densify(cs.MX(self.spu, D["RU"][:, k])),
            )
            Y = self._solve(D["F"][:, k], B)[-nx:, :]  # the interval's end
            c = Vb[-nx:, k] + Y[:, 0] - Xb[:, k + 1]
            G = cs.horzcat(Y[:, 1:], cs.MX(nx, nq - (k + 1) * nu))
            cc.append(c), GG.append(G)
        return cc, GG

    def carry(self, D: dict, k: int, dx: cs.MX) -> cs.MX:
        return self._solve(D["F"][:, k], cs.mtimes(self._rx(D, k), dx))[-self.nx :]

    def stages(self, D: dict, k: int, dx: cs.MX, du: cs.MX) -> cs.MX:
        RU = cs.MX(self.spu, D["RU"][:, k])
        B = D["R"][:, k] + cs.mtimes(self._rx(D, k), dx) + cs.mtimes(RU, du)
        return self._solve(D["F"][:, k], B)
