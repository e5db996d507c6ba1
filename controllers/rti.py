"""The NMPC's real-time iteration: one Gauss-Newton SQP step per sample on the lifted
Radau IIA collocation form, condensed onto the input moves, as pure CasADi Functions
(:class:`RealTimeIteration`; the controller is :class:`~.nmpc.NonlinearMPC`).

:class:`Prediction` is the prediction model in scaled variables, with the model's
parameters, the two disturbances of :data:`~.ekf.OFFSETS` and the bounds' back-offs as
run-time inputs; :func:`radau_residual` the collocation equations of one interval.
"""

from __future__ import annotations

import copy
import ctypes
import dataclasses
import functools
from pathlib import Path

import casadi as cs
import numpy as np

from sarcomere.dynamics.errors import ParameterError
from sarcomere.dynamics.modeling.buffered import BufferedCall
from sarcomere.dynamics.modeling.model import Model
from sarcomere.dynamics.simulation import collocation

from .banded_lu import bordered_band
from .ekf import OFFSETS
from .qp import qp_solver
from .rti_banded import BandedCalls, BandedLift
from .rti_compiled import compiled_functions
from .rti_lift import DenseLift, FactoredLift

LINEAR_SOLVERS = ("auto", "lapacklu", "qr", "sparse_lu", "banded")
"""Linear solvers of the RTI's lifted Radau equations (:mod:`.rti_lift`): LAPACK's dense
LU or CasADi's own sparse QR (generates C, slowly) of every sensitivity in the
preparation (:class:`~.rti_lift.DenseLift`), or the sparse LU written out as SX
expressions with the Jacobians and kept
(:mod:`~sarcomere.dynamics.simulation.sparse_lu`, :class:`~.rti_lift.FactoredLift`:
generates C, the fastest compiled), or "banded": the dense lift's solves
by scipy's bordered banded LU (:mod:`.banded_lu`) between the preparation's two CasADi
Functions (the :attr:`~RealTimeIteration.law` Function keeps LAPACK's dense LU; refused
when the Jacobian has no band that pays); "auto": "sparse_lu" when ``compiled``, else
"banded" where the band pays, else "lapacklu" (BENCHMARKS.md, section 5)."""

GENERATED_SOLVERS = ("qr", "sparse_lu")
"""The linear solvers whose law generates C (LAPACK's have no code generation)."""

QP_FEASIBLE = 1e-6
"""Largest violation (rows scaled by ``1 + |A du|``, bounds in scaled input units) of a QP
answer the real-time iteration accepts; above it the sample falls back."""

SLACK_UNIT = 1e-3
"""The unit of the bound slacks inside the RTI's QP [SI of the signal; mN for a tension:
keeps the slack columns of the QP's matrices near the input moves' magnitude]."""


def radau_residual(f: cs.Function, nx: int, nu: int, degree: int) -> cs.Function:
    """The Radau IIA collocation equations of one interval as an SX Function.

    ``f(x, u) -> dx/dt``; returns ``(x0, V, u, h) -> r`` with ``V`` the states at the
    ``degree`` collocation points stacked (the last point is the interval's end) and
    ``r = h f(V_j, u) - sum_r C[r, j] [x0, V]_r`` (zero on the solution).
    """
    x, tau, u, h = cs.SX.sym("x", nx), cs.SX.sym("tau"), cs.SX.sym("u", nu), cs.SX.sym("h")
    f_tau = cs.Function("f_tau", [tau, x, cs.vertcat(u, h)], [h * f(x, u)])
    R = collocation.residual(f_tau, nx, degree)
    x0, V = cs.SX.sym("x0", nx), cs.SX.sym("V", nx * degree)
    r = R(x0, V, cs.vertcat(u, h))
    return cs.Function("radau", [x0, V, u, h], [r], ["x0", "V", "u", "h"], ["r"])


class Prediction:
    """The prediction model in scaled variables: ``x = xs * xi``, ``u = us * v``. The
    vector ``p`` is the model's parameters [SI, in ``model.param_names`` order], the two
    disturbances of :data:`~.ekf.OFFSETS` (a constant added to every input in the
    prediction [SI of the input] and one added to the tracked output [SI]; 0: none) and,
    with ``settings.backoff > 0``, one standard deviation per bounded signal
    (:attr:`backoffs`: the bound is raised by ``backoff`` times it); ``p`` is an argument
    of every Function, so all are run-time inputs, not constants.

    ``bounds``: the lower bounds ``(signal, bound, penalty)`` (:func:`~.receding.soft_bounds`:
    a penalty ``inf`` is a hard bound); the soft ones share one slack per node, so one
    penalty."""

    def __init__(self, model: Model, s, dt: float, xs: np.ndarray, bounds: list) -> None:
        m = model
        n_model = m.p.numel()
        self.bounded = [name for name, _, _ in bounds]
        self.low = np.array([low for _, low, _ in bounds])
        self.soft = np.array([np.isfinite(w) for _, _, w in bounds], dtype=bool)
        penalties = {w for _, _, w in bounds if np.isfinite(w)}
        if len(penalties) > 1:
            raise ParameterError(
                "nmpc.soft_min", sorted(penalties), "one penalty", "one slack per node"
            )
        self.penalty = penalties.pop() if penalties else 0.0
        self.backoffs = tuple(f"backoff.{n}" for n in self.bounded) if s.backoff else ()
        self.nx, self.nu = m.nx, len(m.input_names)
        self.np = n_model + len(OFFSETS) + len(self.backoffs)
        self.xs, self.us = xs, np.full(self.nu, s.u_max - s.u_min)
        xi, v, p = cs.SX.sym("xi", self.nx), cs.SX.sym("v", self.nu), cs.SX.sym("p", self.np)
        pm, d_in, d_out = p[:n_model], p[n_model], p[n_model + 1]
        x, u = xi * xs, v * self.us + d_in
        ode = m.function("ode")(x, cs.SX(0, 1), u, pm) / xs
        # the parameters ride along with the input: constant over an interval, like it
        self.f = cs.Function("f", [xi, cs.vertcat(v, p)], [ode])
        sig = m.signals_function([s.output, *self.bounded])(x, cs.SX(0, 1), u, pm)
        self.y = cs.Function("y", [xi, p], [sig[0] + d_out])
        T = sig[1:] if self.bounded else cs.SX(0, 1)
        T = T - s.backoff * p[n_model + 2 :] if self.backoffs else T
        self.T = cs.Function("T", [xi, p], [T])
        self.res = radau_residual(self.f, self.nx, self.nu + self.np, s.degree)
        self.dt, self.s = dt, s


class RealTimeIteration:
    """One Gauss-Newton SQP step per sample on the lifted collocation form, condensed, as
    pure CasADi Functions of a flat ``memory`` vector (no Python state in the law).

    The guess holds the node states, the inputs and the collocation states of every
    interval. Per interval the Radau equations ``R(V, x, v) = 0`` are linearised once at
    the guess (one Newton step, the "lifted" integrator):
    ``dV = -R_V^{-1} (R + R_x dx + R_v dv)`` from one factorisation (:attr:`lift`,
    :mod:`.rti_lift`: every sensitivity solved in the preparation, or the factors kept),
    so the interval's end is ``x_end + dx_end`` linear in ``(dx, dv)``. The node gaps, the
    tracking and move residuals (Gauss-Newton) and the linearised lower bounds of the
    bounded signals are condensed onto the corrections of the input moves ``dm`` (the QP's
    variables: the rate limits are then bounds), with one slack per node shared by the
    soft bounds' rows.

    Three Functions, composed into one :attr:`law` (with the banded lift of
    :mod:`.rti_banded` the solves run in numpy between the head, tail, feedback and update
    Functions, :attr:`calls`, and :attr:`prepare` is None):

    * :attr:`prepare` ``(memory, x, u_prev, p) -> data``: the lifting, the linearisation
      and the condensing. Everything condensed is affine in the measured state, the
      previous input and the reference, so none of them enters here, except when memory
      holds no guess (the first sample, or after a fallback): the guess is then the
      measured state and the previous input held.
    * :attr:`feedback` ``(data, memory, x, u_prev, ref) -> (u, violation, fallback,
      slack, step)``: the affine update of the QP's gradient and bounds (the measured
      state's distance from the guess carried through the intervals' ends (``N`` products
      or solves with one right-hand side) and the outputs' Jacobians, cheaper than the N
      matrix products that would condense it in the preparation), the QP and the command: the
      measurement-to-command latency.
    * :attr:`update` ``(data, memory, x, u_prev, step) -> memory_next``: the next guess
      (the corrected trajectory shifted by one sample) and the plan, after the command.

    Memory layout (:attr:`slices`): the guess ``Xb`` (nx x N+1), ``Ub`` (nu x N),
    ``Vb`` (nx degree x N), all scaled and column-major, a 0/1 flag "holds a guess", the
    last plan [SI] (nu x N) and a 0/1 flag "holds a plan".

    Fallback (:meth:`~.receding.RecedingHorizon.apply`'s logic, by ``if_else``): the QP's
    answer counts as failed when its violation exceeds :data:`QP_FEASIBLE` or the answer
    or the linearisation is not finite; the guess is then dropped (the next sample
    restarts from the measurement) and the command is the previous plan shifted by one
    sample (its last input repeated), else, with no plan yet, the previous input held.
    """

    def __init__(self, pb: Prediction) -> None:
        nx, nu, d, N = pb.nx, pb.nu, pb.s.degree, pb.s.horizon
        self.pb, self.N = pb, N
        sizes = {
            "Xb": nx * (N + 1),
            "Ub": nu * N,
            "Vb": nx * d * N,
            "has_guess": 1,
            "plan": nu * N,
            "has_plan": 1,
        }
        self.slices, start = {}, 0
        for name, n in sizes.items():
            self.slices[name] = slice(start, start + n)
            start += n
        self.n_memory = start
        self._lifts(pb)
        head = self._head_function()
        tail = self._tail_function(head)
        self.feedback = self._feedback_function()
        self.update = self._update_function()
        if isinstance(self.lift, BandedLift):  # the solves in numpy, between the Functions
            self.prepare = None
            parts = [head, tail, self.feedback, self.update]
            if pb.s.compiled:
                built = compiled_functions(parts, "nmpc_rti")
                parts = [built[f.name()] for f in parts]
            slots = {k: self._data_slice(k) for k in ("DXA", "DV")}
            banded = BandedCalls(pb.xs, self.lift, *parts, slots)
            self.calls = {"prepare": banded.prepare, "feedback": banded.feedback,
                          "update": banded.update}  # fmt: skip
            self.reset()
            return
        self.prepare = self._prepare_function(head, tail)
        parts = [self.prepare, self.feedback, self.update]
        if pb.s.compiled and isinstance(self.lift, FactoredLift):  # all in C
            built = compiled_functions(parts, "nmpc_rti")
            parts = [built[f.name()] for f in parts]
        elif pb.s.compiled:  # all in C but the lifted solves (LAPACK has no generated C)
            built = compiled_functions([head, tail, self.feedback, self.update], "nmpc_rti")
            parts = [self._prepare_function(built["nmpc_head"], built["nmpc_tail"])]
            parts += [built["nmpc_feedback"], built["nmpc_update"]]
        # the prepared data (some 27 000 numbers at n = 3, N = 20) stays in the preparation's
        # output array, which the feedback and the update read in place
        prepare = BufferedCall(parts[0], copy=False)
        feedback, update = BufferedCall(parts[1]), BufferedCall(parts[2])
        feedback.share(0, prepare.res[0])
        update.share(0, prepare.res[0])
        # the feedback's every output; the preparation's and the update's first
        self.calls = {"prepare": prepare, "feedback": feedback.outputs, "update": update}
        self.reset()

    @functools.cached_property
    def law(self) -> cs.Function:
        """``(memory, x, u_prev, ref, p) -> (memory_next, u, violation, fallback, slack)``:
        the preparation, the feedback and the update as one CasADi Function (with the
        banded lift, whose solves are numpy's, the dense lift's law: the same step)."""
        if self.prepare is None:
            twin = copy.copy(self.pb)
            twin.s = dataclasses.replace(self.pb.s, linear_solver="lapacklu", compiled=False)
            return RealTimeIteration(twin).law
        mem, x, u, ref = (cs.MX.sym(n, k) for n, k in self._io())
        p = cs.MX.sym("p", self.pb.np)
        data = self.prepare(mem, x, u, p)
        u_now, viol, fallback, slack, step = self.feedback(data, mem, x, u, ref)
        return cs.Function(
            "nmpc_law",
            [mem, x, u, ref, p],
            [self.update(data, mem, x, u, step), u_now, viol, fallback, slack],
            ["memory", "x", "u_prev", "ref", "p"],
            ["memory_next", "u", "violation", "fallback", "slack"],
        )

    def _data_slice(self, name: str) -> slice:
        """Where item ``name`` of the prepared data lies (column-major)."""
        start = 0
        for key, (r, c) in self.data_shapes.items():
            if key == name:
                return slice(start, start + r * c)
            start += r * c
        raise KeyError(name)

    def _io(self) -> list[tuple[str, int]]:
        return [("memory", self.n_memory), ("x", self.pb.nx), ("u_prev", self.pb.nu),
                ("ref", self.N)]  # fmt: skip

    def reset(self) -> None:
        """Forget the guess, the plan and the prepared data."""
        self.memory = np.zeros(self.n_memory)
        self.data: np.ndarray | None = None
        self.data_p: np.ndarray | None = None

    def sample(self, x: np.ndarray, u_prev: np.ndarray, ref: np.ndarray, p: np.ndarray):
        """One sample split as in real time: the preparation made after the previous one
        (redone now if memory holds no guess or ``p`` differs from it), the feedback and
        the update; :meth:`prepare_next` readies the next sample after the command is out.
        Equal to :attr:`law` (the same Functions); returns ``(u, violation, fallback,
        slack)`` as arrays."""
        c = self.calls
        if self.data is None or not np.array_equal(p, self.data_p):
            self.data = c["prepare"](self.memory, x, u_prev, p)
        u, viol, fallback, slack, step = c["feedback"](self.data, self.memory, x, u_prev, ref)
        self.memory = c["update"](self.data, self.memory, x, u_prev, step)
        self.data = None
        return u, viol, fallback, slack

    def prepare_next(self, x: np.ndarray, u: np.ndarray, p: np.ndarray) -> None:
        """Between samples: the next sample's preparation with the parameters ``p`` (once
        memory holds a guess; ``x`` and ``u`` are then not used)."""
        if self.memory[self.slices["has_guess"]][0]:
            self.data = self.calls["prepare"](self.memory, x, u, p)
            self.data_p = p.copy()

    def _lifts(self, pb: Prediction) -> None:
        """The per-interval linearisation and its solves (:mod:`.rti_lift`, mapped over
        the horizon) and the outputs' linearisation."""
        nx, N = pb.nx, pb.s.horizon
        linsol, self.band_reason = pb.s.linear_solver, ""
        if linsol == "auto":
            linsol = "sparse_lu" if pb.s.compiled else "banded"
        if linsol == "sparse_lu":  # the factors as expressions, with the Jacobians
            self.lift = FactoredLift(pb, N)
        else:
            if linsol.startswith("lapack") or linsol == "banded":
                _one_blas_thread()
            self.lift = DenseLift(pb, "lapacklu" if linsol == "banded" else linsol, N)
        if linsol == "banded":  # the factors kept in numpy, if the band pays
            sp = self.lift.lin.sparsity_out(0)
            P = np.array(cs.DM(sp, 1))[:, : sp.size1()] != 0
            band, self.band_reason = bordered_band(P, nx, pb.s.degree, self.lift.w)
            if band is not None:
                self.lift = BandedLift(pb, N, band)
            elif pb.s.linear_solver == "banded":
                raise ParameterError(
                    "nmpc.linear_solver", linsol, "'lapacklu' or 'auto'", self.band_reason
                )
        xi, ps = cs.SX.sym("xi", nx), cs.SX.sym("p", pb.np)
        yT = cs.vertcat(pb.y(xi, ps), pb.T(xi, ps))
        self.outs = cs.Function("outs", [xi, ps], [yT, cs.jacobian(yT, xi)]).map(N)

    def _guess(self, mem: cs.MX, xi0: cs.MX, vp: cs.MX) -> tuple[cs.MX, cs.MX, cs.MX]:
        """The guess in memory, or the measured state and previous input held."""
        nx, nu, d, N = self.pb.nx, self.pb.nu, self.pb.s.degree, self.N
        sl, has = self.slices, mem[self.slices["has_guess"]]
        Xb = cs.if_else(has, cs.reshape(mem[sl["Xb"]], nx, N + 1), cs.repmat(xi0, 1, N + 1))
        Ub = cs.if_else(has, cs.reshape(mem[sl["Ub"]], nu, N), cs.repmat(vp, 1, N))
        Vb = cs.if_else(has, cs.reshape(mem[sl["Vb"]], nx * d, N), cs.repmat(xi0, d, N))
        return Xb, Ub, Vb

    def _head_function(self) -> cs.Function:
        """(memory, x, u_prev, p) -> the guess, the Radau equations' residuals and
        Jacobians per interval, and the outputs' linearisation (all but the solves)."""
        pb, N = self.pb, self.N
        mem, x, u = (cs.MX.sym(n, k) for n, k in self._io()[:3])
        p = cs.MX.sym("p", pb.np)
        Xb, Ub, Vb = self._guess(mem, x / pb.xs, u / pb.us)
        P = cs.repmat(p, 1, N)
        lifted = self.lift.lin.call([Vb, Xb[:, :N], Ub, P])
        YT, CYT = self.outs(Xb[:, 1:], P)
        names = ["Xb", "Ub", "Vb", *self.lift.head_names, "YT", "CYT"]
        return cs.Function(
            "nmpc_head",
            [mem, x, u, p],
            [Xb, Ub, Vb, *lifted, YT, CYT],
            ["memory", "x", "u_prev", "p"],
            names,
        )

    def _prepare_function(self, head: cs.Function, tail: cs.Function) -> cs.Function:
        """(memory, x, u_prev, p) -> data: ``head``, the lifted solves, ``tail``."""
        mem, x, u = (cs.MX.sym(n, k) for n, k in self._io()[:3])
        p = cs.MX.sym("p", self.pb.np)
        inline = not head.is_a("External")  # CasADi's own: one graph, no calls between
        Xb, Ub, Vb, *lifted, YT, CYT = head.call([mem, x, u, p], inline, False)
        lifted = self.lift.between(lifted)
        (data,) = tail.call([Xb, Ub, Vb, *lifted, YT, CYT], inline, False)
        return cs.Function(
            "nmpc_prepare", [mem, x, u, p], [data], ["memory", "x", "u_prev", "p"], ["data"]
        )

    def _tail_function(self, head: cs.Function) -> cs.Function:
        """(Xb, Ub, Vb, *lifted, YT, CYT) -> data: the condensed QP, affine in the
        measurement; ``lifted`` the lift's data (:mod:`.rti_lift`)."""
        pb, N = self.pb, self.N
        s, nx, nu = pb.s, pb.nx, pb.nu
        nq = N * nu
        Xb, Ub, Vb = (cs.MX.sym(n, head.sparsity_out(n)) for n in ("Xb", "Ub", "Vb"))
        YT, CYT = (cs.MX.sym(n, head.sparsity_out(n)) for n in ("YT", "CYT"))
        lifted = self.lift.symbols()
        D = dict(zip(self.lift.names, lifted, strict=True))
        # node k's state correction: dX_k = c_k + Phi_k a0 + G_k du, a0 = x0 - Xb_0; the
        # part in a0 is left to the feedback (:meth:`_measured`: 20 products with a vector
        # there instead of 20 matrix products here)
        cc, GG = self.lift.condense(D, Xb, Vb, nq)
        # every node's output rows times its corrections at once: the outputs' Jacobians
        # as one block-diagonal matrix (their nonzeros in the same order)
        ny = 1 + len(pb.bounded)
        blocks = cs.diagcat(*[cs.DM.ones(ny, nx)] * N).sparsity()
        BD = cs.MX(blocks, cs.vec(cs.densify(CYT)))
        M = cs.mtimes(BD, cs.horzcat(cs.vertcat(*cc[1:]), cs.vertcat(*GG[1:])))
        YTv = cs.vec(cs.densify(YT))
        ry, rT = self._rows()
        ey0, Jy = YTv[ry] + M[ry, 0], M[ry, 1:]
        tb0, TJ = YTv[rT] + M[rT, 0], M[rT, 1:]
        # the QP's variables are the moves' corrections dm = Dk du (du = C dm, C = Dk^-1):
        # the rate limits are then bounds, which keeps the active sets regular
        Dk, C = _moves(N, nu), _cumulative(N, nu)
        Ubv = cs.vec(Ub)
        m0 = cs.mtimes(Dk, Ubv)  # the guess's moves, the first from 0
        wy = np.full(N, s.weight_y)
        wy[-1] += s.terminal_weight
        W = cs.DM(np.diag(wy))
        JyC = cs.mtimes(Jy, C)
        WJ = cs.mtimes(W, JyC)
        wu2 = s.weight_du * pb.us[0] ** 2
        data = {
            "Xb0": Xb[:, 0],
            "H": 2 * (cs.mtimes(JyC.T, WJ) + wu2 * cs.DM.eye(nq)),
            "AT": cs.mtimes(TJ, C),
            "g": 2 * (cs.mtimes(WJ.T, ey0) + wu2 * m0),
            "Gr": -2 * WJ.T,
            "m0": m0,
            "tb0": tb0,
            "CYT": cs.densify(CYT),
            "Ub": Ubv,
            "Xb": Xb,
            "Vb": Vb,
            **D,
        }
        self.data_shapes = {k: v.shape for k, v in data.items()}
        flat = cs.densify(cs.vertcat(*(cs.vec(v) for v in data.values())))
        ok = _finite(flat)  # a linearisation that is not finite is a failed sample
        return cs.Function(
            "nmpc_tail",
            [Xb, Ub, Vb, *lifted, YT, CYT],
            [cs.vertcat(flat, ok)],
            ["Xb", "Ub", "Vb", *self.lift.names, "YT", "CYT"],
            ["data"],
        )

    def _unpack(self, data: cs.MX) -> dict[str, cs.MX]:
        out, start = {}, 0
        for name, (r, c) in self.data_shapes.items():
            out[name] = cs.reshape(data[start : start + r * c], r, c)
            start += r * c
        out["ok"] = data[start]
        return out

    def _data_symbol(self) -> cs.MX:
        return cs.MX.sym("data", sum(r * c for r, c in self.data_shapes.values()) + 1)

    def _held(self, mem: cs.MX, u_prev: cs.MX) -> cs.MX:
        """The plan of a failed sample (SI, nu x N): the last plan one sample on, else the
        previous input held."""
        nu, N, sl = self.pb.nu, self.N, self.slices
        last = cs.reshape(mem[sl["plan"]], nu, N)
        if N == 1:
            return cs.repmat(u_prev, 1, N)
        return cs.if_else(mem[sl["has_plan"]], _ahead(last), cs.repmat(u_prev, 1, N))

    def _rows(self) -> tuple[list[int], list[int]]:
        """The tracked output's and the bounded signals' rows among every node's outputs."""
        ny, N = 1 + len(self.pb.bounded), self.N
        return list(range(0, N * ny, ny)), [k * ny + i for k in range(N) for i in range(1, ny)]

    def _measured(self, D: dict[str, cs.MX], a0: cs.MX) -> tuple[cs.MX, cs.MX]:
        """The nodes' tracked outputs and bounded signals moved by the measured state's distance
        ``a0`` from the guess (scaled): ``a0`` through the intervals' end sensitivities
        (``L``), then the outputs' Jacobians (``CYT``)."""
        nx, N = self.pb.nx, self.N
        dx, out = a0, []
        for k in range(N):
            dx = self.lift.carry(D, k, dx)
            out.append(cs.mtimes(D["CYT"][:, k * nx : (k + 1) * nx], dx))
        ry, rT = self._rows()
        ya = cs.vertcat(*out)
        return ya[ry], ya[rT]

    def _feedback_function(self) -> cs.Function:
        """(data, memory, x, u_prev, ref) -> (u, violation, fallback, slack, step)."""
        pb, N = self.pb, self.N
        s, nu = pb.s, pb.nu
        nq, nT = N * nu, len(pb.bounded)
        data = self._data_symbol()
        mem, x, u_prev, ref = (cs.MX.sym(n, k) for n, k in self._io())
        D = self._unpack(data)
        a0, vp = x / pb.xs - D["Xb0"], u_prev / pb.us
        ey_a, et_a = self._measured(D, a0)
        E1vp = cs.vertcat(vp, cs.MX(nq - nu, 1))
        rate = E1vp - D["m0"]  # minus the guess's moves from the previous input
        wu2 = s.weight_du * pb.us[0] ** 2
        g = D["g"] + cs.mtimes(D["Gr"], ref - ey_a) - 2 * wu2 * E1vp
        dv = s.rate_max * pb.dt / pb.us[0]
        C = _cumulative(N, nu)
        # rows: the input bounds (C dm), then the bounded signals; variable bounds: the rates
        T_low = cs.repmat(cs.DM(pb.low.reshape(-1, 1)), N, 1) - D["tb0"] - et_a
        lba = cs.vertcat(s.u_min / pb.us[0] - D["Ub"], T_low)
        uba = cs.vertcat(s.u_max / pb.us[0] - D["Ub"], cs.DM.inf(nT * N))
        lbx, ubx = rate - dv, rate + dv
        if pb.soft.any():  # variables [dm; slack / SLACK_UNIT], one slack per node
            nS, w = N, pb.penalty
            H = cs.diagcat(D["H"], 2 * w * SLACK_UNIT**2 * cs.DM.eye(nS))
            g = cs.vertcat(g, cs.DM.ones(nS) * w * SLACK_UNIT)
            E = cs.DM(np.kron(np.eye(N), pb.soft[:, None].astype(float))) * SLACK_UNIT
            A = cs.vertcat(cs.horzcat(C, cs.DM(nq, nS)), cs.horzcat(D["AT"], E))
            lbx, ubx = cs.vertcat(lbx, cs.DM.zeros(nS)), cs.vertcat(ubx, cs.DM.inf(nS))
        else:
            nS, H, A = 0, D["H"], cs.vertcat(C, D["AT"])
        self.qp = qp_solver(
            s.qp_solver,
            cs.Sparsity.dense(nq + nS, nq + nS),
            cs.Sparsity.dense(nq + nT * N, nq + nS),
        )
        z = self.qp(h=H, g=g, a=A, lba=lba, uba=uba, lbx=lbx, ubx=ubx)["x"]
        dm = z[:nq]
        slack = cs.mmax(cs.vertcat(z[nq:] * SLACK_UNIT, cs.DM.zeros(1)))  # [N]
        # how far the QP's answer is from feasible (the solver's flag is not reachable
        # from inside a Function): constraint rows scaled by their size, and the bounds
        Az = cs.mtimes(A, z)
        scale = 1 + cs.fabs(Az)
        viol = cs.mmax(
            cs.vertcat((lba - Az) / scale, (Az - uba) / scale, lbx - z, z - ubx, cs.DM.zeros(1))
        )
        U = D["Ub"] + cs.mtimes(C, dm)
        ok = (viol <= QP_FEASIBLE) * _finite(z) * D["ok"]
        first = cs.if_else(ok, U[:nu] * pb.us, self._held(mem, u_prev)[:, 0])
        u = cs.fmin(cs.fmax(first, s.u_min), s.u_max)
        return cs.Function(
            "nmpc_feedback",
            [data, mem, x, u_prev, ref],
            [u, viol, 1 - ok, slack, cs.vertcat(dm, ok)],
            ["data", "memory", "x", "u_prev", "ref"],
            ["u", "violation", "fallback", "slack", "step"],
        )

    def _update_function(self) -> cs.Function:
        """(data, memory, x, u_prev, step) -> memory_next: the corrected trajectory
        shifted by one sample (the next guess) and the plan."""
        pb, N = self.pb, self.N
        nx, nu = pb.nx, pb.nu
        nq = N * nu
        data = self._data_symbol()
        mem, x, u_prev = (cs.MX.sym(n, k) for n, k in self._io()[:3])
        step = cs.MX.sym("step", nq + 1)
        D = self._unpack(data)
        dm, ok = step[:nq], step[nq]
        du = cs.reshape(cs.mtimes(_cumulative(N, nu), dm), nu, N)
        Xb, Vb = D["Xb"], D["Vb"]
        dX, dV = [x / pb.xs - D["Xb0"]], []
        for k in range(N):
            dV.append(self.lift.stages(D, k, dX[k], du[:, k]))
            dX.append(Vb[-nx:, k] + dV[k][-nx:] - Xb[:, k + 1])
        X, V = Xb + cs.horzcat(*dX), Vb + cs.horzcat(*dV)
        U = cs.reshape(D["Ub"], nu, N) + du
        Xn, Un, Vn = _ahead(X), _ahead(U), _ahead(V)
        keep = ok * _finite(Xn) * _finite(Vn)
        guess = cs.vertcat(cs.vec(Xn), cs.vec(Un), cs.vec(Vn))
        guess = cs.if_else(keep, guess, cs.MX(self.slices["has_guess"].start, 1))
        plan = cs.if_else(ok, U * pb.us, self._held(mem, u_prev))
        return cs.Function(
            "nmpc_update",
            [data, mem, x, u_prev, step],
            [cs.vertcat(guess, keep, cs.vec(plan), 1)],
            ["data", "memory", "x", "u_prev", "step"],
            ["memory_next"],
        )


def _one_blas_thread() -> None:
    """Run the OpenBLAS bundled with CasADi (its LAPACK linear solvers' BLAS, not numpy's)
    on one thread, for the whole process: its 54 x 54 LU (dgetrf) went multi-threaded and
    ran 5x slower (2.8 against 0.54 ms for the 20 intervals) whenever the other core was
    busy; matrices this small gain nothing from threads. (``OPENBLAS_NUM_THREADS=1`` does
    the same from outside.)"""
    path = Path(cs.__file__).parent / "libcasadi-tp-openblas.so.0"
    if path.is_file():
        ctypes.CDLL(str(path)).openblas_set_num_threads(1)


def _moves(N: int, nu: int) -> cs.DM:
    """The moves ``u_k - u_{k-1}`` of the stacked inputs (the first from zero)."""
    return cs.DM(np.kron(np.eye(N) - np.eye(N, k=-1), np.eye(nu)))


def _cumulative(N: int, nu: int) -> cs.DM:
    """The inverse of :func:`_moves`: the inputs as sums of their moves."""
    return cs.DM(np.kron(np.tril(np.ones((N, N))), np.eye(nu)))


def _ahead(M: cs.MX) -> cs.MX:
    """The columns moved one ahead, the last repeated."""
    return cs.horzcat(M[:, 1:], M[:, -1])


def _finite(M: cs.MX) -> cs.MX:
    """1 if every entry of ``M`` is finite (neither inf nor NaN), else 0."""
    return cs.mmin(cs.vec(cs.fabs(M) < np.inf))
