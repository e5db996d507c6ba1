"""The QP pieces of the MPCs: the exact zero-order-hold discretisation, the QP solvers
through ``casadi.conic`` (both MPCs; the rest they share is in :mod:`.receding`), and the
LMPC's condensed velocity-form QP (:class:`VelocityQP`, condensed in numpy at each
linearisation) with the law that solves it every sample (:func:`velocity_law`, one CasADi
Function: what :class:`~.lmpc.LinearMPC` runs and the controller FMU generates).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import casadi as cs
import numpy as np
import scipy.linalg

from sarcomere.dynamics.errors import ParameterError

QP_SOLVERS = {
    "qrqp": {
        "print_iter": False,
        "print_header": False,
        "print_info": False,
        "error_on_fail": False,
        "max_iter": 200,
    },
    "daqp": {"error_on_fail": False},
    "qpoases": {"printLevel": "none", "error_on_fail": False},
}
"""``casadi.conic`` plugins the MPCs accept, with the options they are built with. ``daqp``
(default; DAQP, a dual active-set solver for dense QPs) generates code that includes
``daqp/api.h`` and links DAQP, whose headers and static library CasADi's wheel ships
(:func:`~.rti_compiled.daqp_build`: the library is linked into the binary, nothing else to
install). ``qrqp`` (CasADi's own active-set solver) generates self-contained C, but
factorises the whole KKT system sparsely: on the control-length LMPC QP (24 unknowns, 100
rows with four soft tension bounds) 8-13 ms interpreted and about 20 ms compiled, against
0.04 ms for the compiled DAQP law (without soft bounds qrqp takes 0.05 ms too); on the
degenerate active sets of the NMPC started at an input bound it cycles (a fallback).
qpOASES has no code generation."""


def zoh(A: np.ndarray, B: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """Exact zero-order-hold discretisation: ``expm([[A, B], [0, 0]] dt)``."""
    nx, nu = B.shape
    M = np.zeros((nx + nu, nx + nu))
    M[:nx, :nx], M[:nx, nx:] = A, B
    E = scipy.linalg.expm(M * dt)
    return E[:nx, :nx], E[:nx, nx:]


def qp_solver(name: str, H: cs.Sparsity, A: cs.Sparsity) -> cs.Function:
    """A ``casadi.conic`` QP solver built once for the sparsities ``H`` and ``A``."""
    if name not in QP_SOLVERS:
        raise ParameterError("qp_solver", name, f"one of {sorted(QP_SOLVERS)}")
    return cs.conic("qp", name, {"h": H, "a": A}, dict(QP_SOLVERS[name]))


@dataclass
class VelocityQP:
    """The condensed QP of one linearisation (see the module docstring).

    Parameters
    ----------
    Ad, Bd : numpy.ndarray
        Discrete-time state and input matrices (nx x nx, nx x nu).
    C : numpy.ndarray
        Tracked outputs (ny x nx).
    Cs : numpy.ndarray
        Softly bounded signals (ns x nx), may have zero rows.
    horizon : int
    weight_y, weight_du : float
    weight_slack : numpy.ndarray
        The penalty of each soft bound's slack (ns) [per unit of the signal].
    u_scale : numpy.ndarray
        Scale of each input [SI]: the QP's unknowns are ``du / u_scale``.
    """

    Ad: np.ndarray
    Bd: np.ndarray
    C: np.ndarray
    Cs: np.ndarray
    horizon: int
    weight_y: float
    weight_du: float
    weight_slack: np.ndarray
    u_scale: np.ndarray
    H: np.ndarray = field(init=False)

    def __post_init__(self) -> None:
        nx, nu = self.Bd.shape
        ny, ns, N = self.C.shape[0], self.Cs.shape[0], self.horizon
        Phi = np.block([[self.Ad, np.zeros((nx, ny))], [self.C @ self.Ad, np.eye(ny)]])
        Gam = np.vstack([self.Bd, self.C @ self.Bd]) * self.u_scale[None, :]
        n = nx + ny
        Sx = np.zeros((N * n, n))
        Su = np.zeros((N * n, N * nu))
        P = np.eye(n)
        for k in range(N):
            P = Phi @ P
            Sx[k * n : (k + 1) * n] = P
        for j in range(N):
            blk = Gam
            for k in range(j, N):
                Su[k * n : (k + 1) * n, j * nu : (j + 1) * nu] = blk
                blk = Phi @ blk
        # the tracking errors e_1..e_N: the last ny rows of every block of n
        Se_x = Sx.reshape(N, n, n)[:, nx:].reshape(N * ny, n)
        Se_u = Su.reshape(N, n, N * nu)[:, nx:].reshape(N * ny, N * nu)
        self.nu, self.ns = nu, ns
        nv = N * nu + ns
        H = np.zeros((nv, nv))
        H[: N * nu, : N * nu] = 2 * (
            self.weight_y * Se_u.T @ Se_u + self.weight_du * np.diag(np.tile(self.u_scale**2, N))
        )
        H[N * nu :, N * nu :] = 2 * np.diag(np.broadcast_to(self.weight_slack, ns))
        self.H = H
        self._G = 2 * self.weight_y * Se_u.T @ Se_x  # gradient = G xi0
        self._Gr = 2 * self.weight_y * Se_u.T  # minus this times the reference ahead
        # inputs: u_k = u_prev + sum_{j<=k} du_j
        T = np.kron(np.tril(np.ones((N, N))), np.diag(self.u_scale))
        # soft signals at k = 1..N: s_0 + Cs (x_k - x_0), x_k - x_0 = sum_{i<=k} dx_i
        # (cumulative sums of the dx rows: no (N nx) x (N n) summation matrix)
        cum_x = np.cumsum(Sx.reshape(N, n, n)[:, :nx], axis=0)
        cum_u = np.cumsum(Su.reshape(N, n, N * nu)[:, :nx], axis=0)
        self._Ssx = np.einsum("sx,kxj->ksj", self.Cs, cum_x).reshape(N * ns, n)
        Ssu = np.einsum("sx,kxj->ksj", self.Cs, cum_u).reshape(N * ns, N * nu)
        A = np.zeros((N * nu + N * ns, nv))
        A[: N * nu, : N * nu] = T
        A[N * nu :, : N * nu] = Ssu
        A[N * nu :, N * nu :] = np.kron(np.ones((N, 1)), np.eye(ns))
        self.A = A

    def data(self) -> np.ndarray:
        """The condensed QP as one flat vector (the ``p`` part :func:`law_function` reads):
        ``H, G, Gr, A, Ssx`` column-major, then ``u_scale`` and ``weight_slack``."""
        ws = np.broadcast_to(self.weight_slack, self.ns)
        parts = (self.H, self._G, self._Gr, self.A, self._Ssx, self.u_scale, ws)
        return np.concatenate([np.ravel(np.asarray(a, float), order="F") for a in parts])


LAW_TOL = 1e-6
"""Largest scaled constraint violation of the QP's answer still accepted [-] (the solver's
own flag is not reachable from inside a Function)."""


def velocity_law(nx: int, nu: int, ns: int, horizon: int, solver: str = "daqp") -> cs.Function:
    """One sample of the LMPC at a fixed linearisation as one CasADi Function::

        lmpc(memory, x, u_prev, ref, p) -> (memory_next, u, ok)

    ``memory = [x_prev (nx); started (1); plan (horizon nu, column-major nu x horizon)]``:
    the states at the last sample, whether there was one, and the last plan of inputs [SI];
    ``x = [states (nx); tracked output (1); soft signals (ns)]`` [SI] as measured now;
    ``u_prev`` the input held since the last sample [SI]; ``ref`` the reference now
    (clipped) and at nodes ``1..horizon`` [SI]; ``p = [VelocityQP.data(); u_lo; u_hi;
    du_max; soft_min]`` (:meth:`LinearMPC.law_parameters`). The QP (``solver``, one of
    :data:`~.qp.QP_SOLVERS`) is solved for the moves; ``u`` is the first input of the new plan
    clipped into the bounds, or, when the answer is not feasible to :data:`LAW_TOL`
    (``ok = 0``), of the last plan shifted by one sample. Re-linearisation is outside: it
    changes ``p``.
    """
    N, n = horizon, nx + 1
    nq, nv, na = N * nu, N * nu + ns, N * (nu + ns)
    mem = cs.MX.sym("memory", nx + 1 + nq)
    x, u_prev = cs.MX.sym("x", nx + 1 + ns), cs.MX.sym("u_prev", nu)
    ref = cs.MX.sym("ref", N + 1)
    sizes = [nv * nv, nq * n, nq * N, na * nv, N * ns * n, nu, ns, nu, nu, nu, ns]
    p = cs.MX.sym("p", sum(sizes))
    H, G, Gr, A, Ssx, us, ws, lo, hi, dmax, smin = cs.vertsplit(p, np.cumsum([0, *sizes]).tolist())
    H, G, Gr = cs.reshape(H, nv, nv), cs.reshape(G, nq, n), cs.reshape(Gr, nq, N)
    A, Ssx = cs.reshape(A, na, nv), cs.reshape(Ssx, N * ns, n)
    x_prev, started, plan = mem[:nx], mem[nx], cs.reshape(mem[nx + 1 :], nu, N)
    dx = cs.if_else(started > 0, x[:nx] - x_prev, cs.MX.zeros(nx))
    xi0 = cs.vertcat(dx, x[nx] - ref[0])
    gap = smin - x[nx + 1 :]
    g = cs.vertcat(cs.mtimes(G, xi0) - cs.mtimes(Gr, ref[1:] - ref[0]), ws)
    lba = cs.vertcat(cs.repmat(lo - u_prev, N, 1), cs.repmat(gap, N, 1) - cs.mtimes(Ssx, xi0))
    uba = cs.vertcat(cs.repmat(hi - u_prev, N, 1), cs.DM.inf(N * ns))
    lbx = cs.vertcat(cs.repmat(-dmax / us, N, 1), cs.DM.zeros(ns))
    ubx = cs.vertcat(cs.repmat(dmax / us, N, 1), cs.DM.inf(ns))
    if solver not in QP_SOLVERS:
        raise ParameterError("lmpc.qp_solver", solver, f"one of {sorted(QP_SOLVERS)}")
    qp = qp_solver(solver, H.sparsity(), A.sparsity())
    v = qp(h=H, g=g, a=A, lba=lba, uba=uba, lbx=lbx, ubx=ubx)["x"]
    Av = cs.mtimes(A, v)
    scale = 1 + cs.fabs(Av)
    viol = cs.mmax(cs.vertcat((lba - Av) / scale, (Av - uba) / scale, lbx - v, v - ubx, 0))
    finite = cs.sum1(cs.fabs(v) < cs.inf) == nv  # false for a NaN
    ok = cs.logic_and(viol <= LAW_TOL, finite)
    moves = cs.reshape(v[:nq], nu, N) * cs.repmat(us, 1, N)
    solved = cs.repmat(u_prev, 1, N) + cs.cumsum(moves, 1)
    shifted = cs.horzcat(plan[:, 1:], plan[:, -1])
    new = cs.if_else(ok, solved, shifted)
    u = cs.fmin(cs.fmax(new[:, 0], lo), hi)
    return cs.Function(
        "lmpc",
        [mem, x, u_prev, ref, p],
        [cs.vertcat(x[:nx], 1, cs.vec(new)), u, ok],
        ["memory", "x", "u_prev", "ref", "p"],
        ["memory_next", "u", "ok"],
    )
