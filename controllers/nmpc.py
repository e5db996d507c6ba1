"""Nonlinear MPC on the model's own equations: Radau IIA collocation, IPOPT or fatrop, and a
real-time-iteration variant.

The prediction model should be built for optimisers
(``hanging_load(..., flow_law="smooth", saturate=False)``): the smooth flow law keeps every
derivative continuous, and the input's range is a bound of the problem, not a clamp.

Discretisation: one Radau IIA collocation element of ``degree`` points (default 3, order 5,
L-stable) per sample interval, states scaled by their magnitude over the operating range.
The stage state is ``s_k = [x_k; u_{k-1}]`` (the previous input is carried, so the rate limit
is a constraint of one stage, as fatrop's structure needs); the stage controls are ``u_k``
and the collocation states. Cost ``sum_k weight_y (y_k - r_k)^2 + weight_du (u_k - u_{k-1})^2``
with ``r_k`` the reference at node ``k`` (``t + k dt``): the values handed over by
:meth:`~.receding.RecedingHorizon.set_preview` when the reference is known ahead, else
``r(t)`` at every node;
plus ``terminal_weight (y_N - r_N)^2``; constraints: the input within ``[u_min, u_max]``,
its rate within ``rate_max``, and every thread tension ``>= tension_min`` at every node
from ``k = 1`` on: soft by default (one slack per node, exact L1 plus quadratic penalty:
the hard solution wherever that is feasible), hard with ``soft_constraints = False``.

Solvers (``NMPCSettings.solver``):

* ``"ipopt"``, ``"fatrop"``: the collocation NLP built once as an ``nlpsol`` with the
  measured state, the previous input and the reference as parameters, warm-started from the
  previous solution shifted by one sample (primal and, for IPOPT, dual);
* ``"rti"``: real-time iteration (one Gauss-Newton SQP step per sample) on the multiple-
  shooting form: each interval is integrated by the same Radau IIA equations solved by
  Newton, its sensitivities come from the implicit function theorem, the QP is condensed onto
  the input moves and solved by ``casadi.conic`` (DAQP by default), all in pure CasADi
  Functions (preparation, feedback, update; :meth:`NonlinearMPC.law_function` composes
  them into one law), optionally generated to C and compiled (``compiled``).

Parameters of the prediction (the load, the geometry, the regulator) are run-time inputs of
the solver's Function, not constants: :meth:`NonlinearMPC.set_parameters` changes them
between samples, and on an EKF (:class:`~.estimated.OnEstimate`) the estimated load is fed
every sample, so the prediction carries the load the plant has (offset-free by the
disturbance model). On the states themselves (no EKF) the NMPC runs its own Kalman filter
of one disturbance (``disturbance``: "load", "input" or "output"; the LMPC's filter,
:class:`~.disturbance.StateDisturbanceFilter`) and feeds its estimate the same way; the
law Function is the same, only its ``p`` changes.

Integral action (``integral_gain``, default 5 1/s; :func:`make_nmpc` makes it 0 when an
EKF or the own filter feeds an estimate): the reference the optimiser sees is moved by
the integrated tracking error, so a load the prediction does not know (the +50 g
disturbance) leaves no steady offset, slowly.

A failed solve (infeasible QP, NLP not converged) falls back to the previous plan shifted
by one sample and is counted in ``stats.fallbacks``.
"""

from __future__ import annotations

import ctypes
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

import casadi as cs
import numpy as np

from sarcomere.dynamics.equilibrium import Equilibrium
from sarcomere.dynamics.errors import ParameterError
from sarcomere.dynamics.modeling.model import Model
from sarcomere.dynamics.simulation import collocation

from . import sparse_lu
from .base import Controller
from .disturbance import DISTURBANCES, StateDisturbanceFilter, check_disturbance
from .ekf import DEFAULT_STD, OFFSETS, estimated_parameters
from .qp import qp_solver
from .receding import (
    TENSION,
    BufferedCall,
    RecedingHorizon,
    check_horizon,
    ekf_disturbance,
    mpc_settings,
    with_estimator,
)
from .registry import count, positive, register_controller
from .rti_compiled import compiled_functions

SOLVERS = ("ipopt", "fatrop", "rti")
"""NMPC solution methods."""

LINEAR_SOLVERS = ("auto", "lapacklu", "lapackqr", "qr", "sparse_lu")
"""Linear solvers of the RTI's lifted Radau equations: LAPACK's dense LU (the fastest in
CasADi's virtual machine) or QR, CasADi's own sparse QR (generates C, slowly), or the
sparse LU written out as SX expressions with the Jacobians (:mod:`.sparse_lu`: generates
C, the fastest compiled); "auto": "sparse_lu" when ``compiled``, else "lapacklu"."""

GENERATED_SOLVERS = ("qr", "sparse_lu")
"""The linear solvers whose law generates C (LAPACK's have no code generation)."""

QP_FEASIBLE = 1e-6
"""Largest violation (rows scaled by ``1 + |A du|``, bounds in scaled input units) of a QP
answer the real-time iteration accepts; above it the sample falls back."""

SLACK_UNIT = 1e-3
"""The unit [N] of the tension slacks inside the RTI's QP (mN: keeps the slack columns of
the QP's matrices near the input moves' magnitude)."""

MAX_ITER = 1000
"""Largest NLP iteration limit per sample (ipopt, fatrop): the warm-started solves here
take 3-15 iterations; a sample that needs more than 1000 is a failed solve (a fallback),
not a slow one."""


@dataclass(frozen=True)
class NMPCSettings:
    """Settings of :class:`NonlinearMPC` (SI).

    Attributes
    ----------
    horizon : int
        Prediction horizon [samples].
    weight_y : float
        Weight of the squared tracking error [1/m^2].
    weight_du : float
        Weight of the squared input move per sample [1/Pa^2].
    u_min, u_max : float
        Regulator command bounds [Pa gauge] (default 0 to 0.1 MPa).
    rate_max : float
        Largest input rate [Pa/s].
    tension_min : float
        Smallest allowed thread tension [N] (hard constraint).
    solver : str
        "ipopt", "fatrop" or "rti".
    degree : int
        Radau IIA collocation points per interval (1..5).
    tol : float
        NLP tolerance (ipopt, fatrop).
    max_iter : int
        NLP iteration limit (ipopt, fatrop).
    qp_solver : str
        QP solver of the real-time iteration: "daqp" (default: its generated C compiles
        against the static DAQP library and headers the casadi wheel ships, so the law
        exports with libc as its only dependency), "qrqp" (self-contained C, but it cycles
        on the degenerate active sets of a start at an input bound: a fallback, hundreds
        of iterations), "qpoases" or "hpipm" (not code-generable here).
    output : str
        The tracked signal.
    integral_gain : float
        Integral action [1/s]: the reference given to the optimiser is moved by
        ``integral_gain * integral of (r - y) dt`` (not while the input is at a bound or
        moves at the rate limit: anti-windup), so
        a load or model error the prediction does not know leaves no steady offset; 0
        turns it off (:func:`make_nmpc` defaults to 0 where an EKF or the own filter,
        ``disturbance``, feeds an estimate: the prediction then knows the load).
    terminal_weight : float
        Extra weight of the squared tracking error at the last node [1/m^2], added to
        ``weight_y`` there (default 0: the 0.2 s horizon outlasts the regulator lag and
        the chain's settling, so the last node needs no extra pull; raise it for short
        horizons).
    compiled : bool
        Run the RTI as generated C, compiled with gcc and cached on disk
        (:mod:`.rti_compiled`): the linearisation, the condensing, the feedback and the
        update, with the lifted linear solves as the sparse LU of :mod:`.sparse_lu`
        (``linear_solver`` "auto"). Default false (BENCHMARKS.md, section 5: measured
        compile time against the time saved).
    linear_solver : str
        Linear solver of the lifted Radau equations: "lapacklu", "lapackqr", "qr"
        (CasADi's sparse QR), "sparse_lu" (:mod:`.sparse_lu`, SX expressions fused with
        the Jacobians; with "qr" the ones that generate C: use it for a law to export) or
        "auto" (default: "sparse_lu" when compiled, else LAPACK LU, the faster in
        CasADi's virtual machine).
    soft_constraints : bool
        Soften the thread-tension bounds (default true): every bound row of every node
        gets a slack ``s >= 0`` [N] costing ``tension_l1 s + tension_l2 s^2``; false keeps
        them hard (an infeasible QP is then a fallback).
    tension_l1 : float
        Exact (L1) penalty of a tension slack [1/N]. Above the bounds' multipliers (up to
        about 2e3 1/N in the venting test at 0.2 N, ``tests/controllers/test_nmpc.py``),
        so the soft solution is the hard one whenever the hard one is feasible.
    tension_l2 : float
        Quadratic penalty of a tension slack [1/N^2] (keeps the slack's QP block
        positive definite).
    disturbance : str
        The disturbance model of the NMPC's own Kalman filter on the states it reads
        (:class:`~.disturbance.StateDisturbanceFilter`): "load" (the load mass), "input",
        "output" or "none" (default here: the bare law, what the controller FMU exports;
        :func:`make_nmpc` defaults to "load" where the model has a load, else "input",
        when no EKF runs). Its estimate is fed to the prediction's run-time parameters
        every sample.
    input_std, output_std : float or None
        The filter's noise: of the input [Pa] (default 2 kPa, the EKF's and the LMPC's)
        and of the tracked output as read [SI] (None: :data:`~.ekf.DEFAULT_STD` of its
        unit).
    """

    horizon: int = 20
    weight_y: float = 1.0e6
    weight_du: float = 1.0e-9
    u_min: float = 0.0
    u_max: float = 1.0e5
    rate_max: float = 2.0e6
    tension_min: float = 0.0
    solver: str = "rti"
    degree: int = 3
    tol: float = 1.0e-6
    max_iter: int = 100
    qp_solver: str = "daqp"
    output: str = "myofibril.length"
    integral_gain: float = 5.0
    terminal_weight: float = 0.0
    compiled: bool = False
    linear_solver: str = "auto"
    soft_constraints: bool = True
    tension_l1: float = 1.0e6
    tension_l2: float = 1.0e6
    disturbance: str = "none"
    input_std: float = 2.0e3
    output_std: float | None = None

    def __post_init__(self) -> None:
        if self.disturbance not in DISTURBANCES:
            raise ParameterError("nmpc.disturbance", self.disturbance, f"one of {DISTURBANCES}")
        positive("nmpc", "input_std", self.input_std, allow_zero=True)
        if self.output_std is not None:
            positive("nmpc", "output_std", self.output_std)
        check_horizon("nmpc.horizon", self.horizon)
        positive("nmpc", "integral_gain", self.integral_gain, allow_zero=True)
        positive("nmpc", "weight_y", self.weight_y)
        positive("nmpc", "weight_du", self.weight_du, allow_zero=True)
        positive("nmpc", "rate_max", self.rate_max)
        positive("nmpc", "tol", self.tol)
        positive("nmpc", "terminal_weight", self.terminal_weight, allow_zero=True)
        positive("nmpc", "tension_l1", self.tension_l1)
        positive("nmpc", "tension_l2", self.tension_l2, allow_zero=True)
        for name in ("soft_constraints", "compiled"):
            if not isinstance(getattr(self, name), bool):
                raise ParameterError(f"nmpc.{name}", getattr(self, name), "true or false")
        if self.linear_solver not in LINEAR_SOLVERS:
            raise ParameterError(
                "nmpc.linear_solver", self.linear_solver, f"one of {LINEAR_SOLVERS}"
            )
        if self.compiled and self.solver != "rti":
            raise ParameterError(
                "nmpc.compiled", True, "false with solver ipopt or fatrop", "only the RTI compiles"
            )
        count("nmpc.max_iter", self.max_iter, 1, MAX_ITER, "a limit per sample, not a budget")
        if not self.u_min < self.u_max:
            raise ParameterError("nmpc.u_max", self.u_max, f"> u_min = {self.u_min:g} Pa")
        if self.solver not in SOLVERS:
            raise ParameterError("nmpc.solver", self.solver, f"one of {SOLVERS}")
        count("nmpc.degree", self.degree, 1, 5, "Radau IIA of order 1 to 9")


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


class _Problem:
    """The prediction model in scaled variables: ``x = xs * xi``, ``u = us * v``. The
    vector ``p`` is the model's parameters [SI, in ``model.param_names`` order] followed by
    the two disturbances of :data:`~.ekf.OFFSETS` (:attr:`NonlinearMPC.offsets`): a
    constant added to every input in the prediction [SI of the input] and one added to the
    tracked output [SI] (0: none); ``p`` is an argument of every Function, so all are
    run-time inputs, not constants."""

    def __init__(self, model: Model, s: NMPCSettings, dt: float, xs: np.ndarray) -> None:
        m = model
        n_model = m.p.numel()
        self.nx, self.nu, self.np = m.nx, len(m.input_names), n_model + len(OFFSETS)
        self.xs, self.us = xs, np.full(self.nu, s.u_max - s.u_min)
        xi, v, p = cs.SX.sym("xi", self.nx), cs.SX.sym("v", self.nu), cs.SX.sym("p", self.np)
        pm, d_in, d_out = p[:n_model], p[n_model], p[n_model + 1]
        x, u = xi * xs, v * self.us + d_in
        ode = m.function("ode")(x, cs.SX(0, 1), u, pm) / xs
        # the parameters ride along with the input: constant over an interval, like it
        self.f = cs.Function("f", [xi, cs.vertcat(v, p)], [ode])
        self.tensions = [n for n in m.signal_names if TENSION.fullmatch(n)]
        sig = m.signals_function([s.output, *self.tensions])(x, cs.SX(0, 1), u, pm)
        self.y = cs.Function("y", [xi, p], [sig[0] + d_out])
        self.T = cs.Function("T", [xi, p], [sig[1:]])
        self.res = radau_residual(self.f, self.nx, self.nu + self.np, s.degree)
        self.dt, self.s = dt, s


class _CollocationNLP:
    """The collocation NLP, stage by stage (see the module docstring), as an nlpsol."""

    def __init__(self, pb: _Problem, solver: str) -> None:
        s, nx, nu, d, N = pb.s, pb.nx, pb.nu, pb.s.degree, pb.s.horizon
        # measured x [SI], previous u [SI], reference per node [SI], model parameters [SI]
        P = cs.SX.sym("P", nx + nu + N + pb.np)
        xi0, vprev, ref = P[:nx] / pb.xs, P[nx : nx + nu] / pb.us, P[nx + nu : nx + nu + N]
        p = P[nx + nu + N :]
        w, lbw, ubw, g, lbg, ubg, eq = [], [], [], [], [], [], []
        J = 0

        def con(expr, lo, hi, is_eq):
            g.append(expr)
            n = expr.numel()
            lbg.extend(np.broadcast_to(lo, n).tolist())
            ubg.extend(np.broadcast_to(hi, n).tolist())
            eq.extend([is_eq] * n)

        inf, dv = np.inf, s.rate_max * pb.dt / pb.us
        vlo, vhi = s.u_min / pb.us, s.u_max / pb.us
        # stage k: variables [s_k, u_k, V_k, sigma_k]; constraints: the gap to s_{k+1} first, then
        # the stage's own (the order fatrop's structure detection reads)
        S = cs.SX.sym("S0", nx + nu)
        w.append(S), lbw.extend([-inf] * (nx + nu)), ubw.extend([inf] * (nx + nu))
        ns = 1 if s.soft_constraints else 0  # one tension slack [N] per node

        def tension(X, sigma):
            """The node's tension bounds, softened by its slack ``sigma`` (cost added)."""
            if not ns:
                con(pb.T(X, p), s.tension_min, inf, False)
                return 0
            con(pb.T(X, p) + sigma, s.tension_min, inf, False)
            return s.tension_l1 * sigma + s.tension_l2 * sigma**2

        wy = [s.weight_y] * (N - 1) + [s.weight_y + s.terminal_weight]
        for k in range(N):
            V, Xc = cs.SX.sym(f"U{k}", nu), cs.SX.sym(f"Xc{k}", nx * d)
            sig = cs.SX.sym(f"sigma{k}", ns)
            w += [V, Xc, sig]
            lbw.extend([*vlo, *[-inf] * (nx * d), *[0.0] * ns])
            ubw.extend([*vhi, *[inf] * (nx * d), *[inf] * ns])
            X, Vp = S[:nx], S[nx:]
            S_next = cs.SX.sym(f"S{k + 1}", nx + nu)
            w.append(S_next), lbw.extend([-inf] * (nx + nu)), ubw.extend([inf] * (nx + nu))
            con(S_next - cs.vertcat(Xc[-nx:], V), 0, 0, True)
            if k == 0:
                con(S - cs.vertcat(xi0, vprev), 0, 0, True)
                J += s.tension_l1 * cs.sum1(sig)  # node 0 is measured: no bound, slack 0
            else:
                J += tension(X, sig)
            con(pb.res(X, Xc, cs.vertcat(V, p), pb.dt), 0, 0, True)
            con(V - Vp, -dv, dv, False)
            J += s.weight_du * cs.sumsqr((V - Vp) * pb.us)
            J += wy[k] * (pb.y(S_next[:nx], p) - ref[k]) ** 2
            S = S_next
        sig = cs.SX.sym("sigmaN", ns)
        w.append(sig), lbw.extend([0.0] * ns), ubw.extend([inf] * ns)
        J += tension(S[:nx], sig)
        self.stage, self.ns = nx + nu + nu + nx * d + ns, ns
        nlp = {"x": cs.vertcat(*w), "p": P, "f": J, "g": cs.vertcat(*g)}
        if solver == "ipopt":
            opts = {
                "ipopt": {
                    "print_level": 0,
                    "sb": "yes",
                    "tol": s.tol,
                    "max_iter": s.max_iter,
                    "warm_start_init_point": "yes",
                    "mu_init": 1e-3,
                },
                "print_time": False,
            }
        else:
            opts = {
                "structure_detection": "auto",
                "equality": eq,
                "fatrop": {"print_level": 0, "tol": s.tol, "max_iter": s.max_iter},
                "print_time": False,
            }
        opts["error_on_fail"] = False
        self.solver = cs.nlpsol("nmpc", solver, nlp, opts)
        self.bounds = {
            "lbx": np.array(lbw),
            "ubx": np.array(ubw),
            "lbg": np.array(lbg),
            "ubg": np.array(ubg),
        }
        self.pb, self.warm = pb, {}
        self.slack = 0.0  # the last solution's largest tension slack [N]

    def initial(self, xi: np.ndarray, v: np.ndarray) -> np.ndarray:
        """A guess holding the state ``xi`` and input ``v`` over the horizon."""
        d, zero = self.pb.s.degree, np.zeros(self.ns)
        stage = np.concatenate([xi, v, v, np.tile(xi, d), zero])
        return np.concatenate([np.tile(stage, self.pb.s.horizon), xi, v, zero])

    def solve(
        self, x: np.ndarray, u_prev: np.ndarray, ref: np.ndarray, p: np.ndarray
    ) -> tuple[np.ndarray, bool]:
        """The input plan [SI] (horizon x nu) and whether the solver converged, for the
        reference at nodes 1..horizon and the model parameters ``p`` [SI]."""
        pb = self.pb
        if "x0" not in self.warm:
            self.warm = {"x0": self.initial(x / pb.xs, u_prev / pb.us)}
        P = np.concatenate([x, u_prev, ref, p])
        sol = self.solver(p=P, **self.warm, **self.bounds)
        ok = bool(self.solver.stats()["success"])
        wopt = np.array(sol["x"]).ravel()
        ok = ok and bool(np.all(np.isfinite(wopt)))
        if ok:  # warm start of the next sample: shifted by one stage
            b = self.stage
            self.warm = {
                "x0": _shift(wopt, b, pb.s.horizon),
                "lam_x0": _shift(np.array(sol["lam_x"]).ravel(), b, pb.s.horizon),
                "lam_g0": np.array(sol["lam_g"]).ravel(),
            }
        else:
            self.warm = {}
        nx, nu, N = pb.nx, pb.nu, pb.s.horizon
        if self.ns:  # the slacks: each stage's last variable, and the very last
            self.slack = float(
                max(wopt[self.stage - 1 : N * self.stage : self.stage].max(), wopt[-1])
            )
        idx = nx + nu + np.arange(N)[:, None] * self.stage + np.arange(nu)[None, :]
        return wopt[idx] * pb.us, ok


def _shift(w: np.ndarray, stage: int, n: int) -> np.ndarray:
    """``n`` stages of ``stage`` entries and a terminal part, moved one stage ahead (the
    last stage repeated)."""
    stages = w[: n * stage].reshape(n, stage)
    return np.concatenate([stages[1:].ravel(), stages[-1], w[n * stage :]])


class _RealTimeIteration:
    """One Gauss-Newton SQP step per sample on the lifted collocation form, condensed, as
    pure CasADi Functions of a flat ``memory`` vector (no Python state in the law).

    The guess holds the node states, the inputs and the collocation states of every
    interval. Per interval the Radau equations ``R(V, x, v) = 0`` are linearised once at
    the guess (one Newton step, the "lifted" integrator): ``dV = dV0 + S [dx; dv]`` with
    ``dV0 = -R_V^{-1} R`` and ``S = -R_V^{-1} [R_x, R_v]`` from one factorisation, so
    the interval's end is ``x_end + dx_end`` linear in ``(dx, dv)``. The node gaps, the
    tracking and move residuals (Gauss-Newton) and the linearised tension constraints are
    condensed onto the corrections of the input moves ``dm`` (the QP's variables: the
    rate limits are then bounds), with one tension slack per node when the bounds are
    soft.

    Three Functions, composed into one :attr:`law`:

    * :attr:`prepare` ``(memory, x, u_prev, p) -> data``: the lifting, the linearisation
      and the condensing. Everything condensed is affine in the measured state, the
      previous input and the reference, so none of them enters here, except when memory
      holds no guess (the first sample, or after a fallback): the guess is then the
      measured state and the previous input held.
    * :attr:`feedback` ``(data, memory, x, u_prev, ref) -> (u, violation, fallback,
      slack, step)``: the affine update of the QP's gradient and bounds (the measured
      state's distance from the guess carried through the intervals' end sensitivities
      and the outputs' Jacobians: 2N matrix-vector products, cheaper than the N matrix
      products that would condense it in the preparation), the QP and the command: the
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

    def __init__(self, pb: _Problem) -> None:
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
        self.prepare = self._prepare_function(head, tail)
        self.feedback = self._feedback_function()
        self.update = self._update_function()
        mem, x, u, ref = (cs.MX.sym(n, k) for n, k in self._io())
        p = cs.MX.sym("p", pb.np)
        data = self.prepare(mem, x, u, p)
        u_now, viol, fallback, slack, step = self.feedback(data, mem, x, u, ref)
        self.law = cs.Function(
            "nmpc_law",
            [mem, x, u, ref, p],
            [self.update(data, mem, x, u, step), u_now, viol, fallback, slack],
            ["memory", "x", "u_prev", "ref", "p"],
            ["memory_next", "u", "violation", "fallback", "slack"],
        )
        parts = [self.prepare, self.feedback, self.update]
        if pb.s.compiled and self.solve is None:  # all in C
            built = compiled_functions(parts, "nmpc_rti")
            parts = [built[f.name()] for f in parts]
        elif pb.s.compiled:  # all in C but the lifted solves (LAPACK has no generated C)
            built = compiled_functions([head, tail, self.feedback, self.update], "nmpc_rti")
            parts = [self._prepare_function(built["nmpc_head"], built["nmpc_tail"])]
            parts += [built["nmpc_feedback"], built["nmpc_update"]]
        # the prepared data (some 27 000 numbers at n = 3, N = 20) stays in the preparation's
        # output array, which the feedback and the update read in place
        prepare, feedback, update = (
            BufferedCall(parts[0], copy=False),
            *map(BufferedCall, parts[1:]),
        )
        feedback.share(0, prepare.res[0])
        update.share(0, prepare.res[0])
        self.calls = {"prepare": prepare, "feedback": feedback, "update": update}
        self.reset()

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
            self.data = c["prepare"](self.memory, x, u_prev, p)[0]
        u, viol, fallback, slack, step = c["feedback"](self.data, self.memory, x, u_prev, ref)
        self.memory = c["update"](self.data, self.memory, x, u_prev, step)[0]
        self.data = None
        return u, viol, fallback, slack

    def prepare_next(self, x: np.ndarray, u: np.ndarray, p: np.ndarray) -> None:
        """Between samples: the next sample's preparation with the parameters ``p`` (once
        memory holds a guess; ``x`` and ``u`` are then not used)."""
        if self.memory[self.slices["has_guess"]][0]:
            self.data = self.calls["prepare"](self.memory, x, u, p)[0]
            self.data_p = p.copy()

    def _lifts(self, pb: _Problem) -> None:
        """The per-interval linearisation, its linear solves (both mapped over the horizon)
        and the outputs' linearisation."""
        nx, nu, d, N = pb.nx, pb.nu, pb.s.degree, pb.s.horizon
        V, xi, v = cs.SX.sym("V", nx * d), cs.SX.sym("xi", nx), cs.SX.sym("v", nu)
        ps = cs.SX.sym("p", pb.np)
        R = pb.res(xi, V, cs.vertcat(v, ps), pb.dt)
        RV, RB = cs.jacobian(R, V), cs.horzcat(R, cs.jacobian(R, cs.vertcat(xi, v)))
        linsol = pb.s.linear_solver
        if linsol == "auto":
            linsol = "sparse_lu" if pb.s.compiled else "lapacklu"
        if linsol == "sparse_lu":  # the solve as expressions, with the Jacobians: no call
            order = sparse_lu.block_order(np.array(cs.DM(RV.sparsity(), 1)) != 0, nx, d)
            L = -sparse_lu.solve(RV, RB, order)
            self.lin = cs.Function("radau_lift", [V, xi, v, ps], cs.cse([L])).map(N)
            self.solve = None
        else:
            # common subexpressions of both Jacobians merged: 5114 instead of 6077
            self.lin = cs.Function("radau_lin", [V, xi, v, ps], cs.cse([RV, RB])).map(N)
            if linsol.startswith("lapack"):
                _one_blas_thread()
            A, B = cs.MX.sym("RV", RV.sparsity()), cs.MX.sym("RB", RB.sparsity())
            self.solve = cs.Function("lift_solve", [A, B], [-cs.solve(A, B, linsol)]).map(N)
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
        lifted = self.lin.call([Vb, Xb[:, :N], Ub, P])  # [RV, RB], or [L] (fused)
        YT, CYT = self.outs(Xb[:, 1:], P)
        names = ["Xb", "Ub", "Vb", *(["RV", "RB"] if self.solve else ["L"]), "YT", "CYT"]
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
        L = self.solve(*lifted) if self.solve else lifted[0]
        (data,) = tail.call([Xb, Ub, Vb, L, YT, CYT], inline, False)
        return cs.Function(
            "nmpc_prepare", [mem, x, u, p], [data], ["memory", "x", "u_prev", "p"], ["data"]
        )

    def _tail_function(self, head: cs.Function) -> cs.Function:
        """(Xb, Ub, Vb, L, YT, CYT) -> data: the condensed QP, affine in the measurement;
        ``L = [dV0, S]`` per interval (the lifted solves)."""
        pb, N = self.pb, self.N
        s, nx, nu = pb.s, pb.nx, pb.nu
        nq, w = N * nu, 1 + nx + nu
        Xb, Ub, Vb = (cs.MX.sym(n, head.sparsity_out(n)) for n in ("Xb", "Ub", "Vb"))
        YT, CYT = (cs.MX.sym(n, head.sparsity_out(n)) for n in ("YT", "CYT"))
        L = cs.MX.sym("L", nx * pb.s.degree, N * w)
        # node k's state correction: dX_k = c_k + Phi_k a0 + G_k du, a0 = x0 - Xb_0; the
        # part in a0 is left to the feedback (:meth:`_measured`: 20 products with a vector
        # there instead of 20 matrix products here)
        c, G = cs.MX(nx, 1), cs.MX(nx, nq)
        cc, GG = [c], [G]
        for k in range(N):
            Lk = L[-nx:, k * w : (k + 1) * w]  # the interval's end
            Ak, Bk = Lk[:, 1 : 1 + nx], Lk[:, 1 + nx :]
            c = Vb[-nx:, k] + Lk[:, 0] + cs.mtimes(Ak, c) - Xb[:, k + 1]
            G = cs.mtimes(Ak, G) + _at(Bk, k, N, nu)
            cc.append(c), GG.append(G)
        # every node's output rows times its corrections at once: the outputs' Jacobians
        # as one block-diagonal matrix (their nonzeros in the same order)
        ny = 1 + len(pb.tensions)
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
            "L": L,
        }
        self.data_shapes = {k: v.shape for k, v in data.items()}
        flat = cs.densify(cs.vertcat(*(cs.vec(v) for v in data.values())))
        ok = _finite(flat)  # a linearisation that is not finite is a failed sample
        return cs.Function(
            "nmpc_tail",
            [Xb, Ub, Vb, L, YT, CYT],
            [cs.vertcat(flat, ok)],
            ["Xb", "Ub", "Vb", "L", "YT", "CYT"],
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
        """The tracked output's and the tensions' rows among every node's outputs."""
        ny, N = 1 + len(self.pb.tensions), self.N
        return list(range(0, N * ny, ny)), [k * ny + i for k in range(N) for i in range(1, ny)]

    def _measured(self, D: dict[str, cs.MX], a0: cs.MX) -> tuple[cs.MX, cs.MX]:
        """The nodes' tracked outputs and tensions moved by the measured state's distance
        ``a0`` from the guess (scaled): ``a0`` through the intervals' end sensitivities
        (``L``), then the outputs' Jacobians (``CYT``)."""
        nx, w, N = self.pb.nx, 1 + self.pb.nx + self.pb.nu, self.N
        dx, out = a0, []
        for k in range(N):
            dx = cs.mtimes(D["L"][-nx:, k * w + 1 : k * w + 1 + nx], dx)
            out.append(cs.mtimes(D["CYT"][:, k * nx : (k + 1) * nx], dx))
        ry, rT = self._rows()
        ya = cs.vertcat(*out)
        return ya[ry], ya[rT]

    def _feedback_function(self) -> cs.Function:
        """(data, memory, x, u_prev, ref) -> (u, violation, fallback, slack, step)."""
        pb, N = self.pb, self.N
        s, nu = pb.s, pb.nu
        nq, nT = N * nu, len(pb.tensions)
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
        # rows: the input bounds (C dm), then the tensions; variable bounds: the rates
        T_low = s.tension_min - D["tb0"] - et_a
        lba = cs.vertcat(s.u_min / pb.us[0] - D["Ub"], T_low)
        uba = cs.vertcat(s.u_max / pb.us[0] - D["Ub"], cs.DM.inf(nT * N))
        lbx, ubx = rate - dv, rate + dv
        if s.soft_constraints:  # variables [dm; slack / SLACK_UNIT], one slack per node
            nS = N
            H = cs.diagcat(D["H"], 2 * s.tension_l2 * SLACK_UNIT**2 * cs.DM.eye(nS))
            g = cs.vertcat(g, cs.DM.ones(nS) * s.tension_l1 * SLACK_UNIT)
            E = cs.DM(np.kron(np.eye(N), np.ones((nT, 1)))) * SLACK_UNIT
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
        nq, w = N * nu, 1 + nx + nu
        data = self._data_symbol()
        mem, x, u_prev = (cs.MX.sym(n, k) for n, k in self._io()[:3])
        step = cs.MX.sym("step", nq + 1)
        D = self._unpack(data)
        dm, ok = step[:nq], step[nq]
        du = cs.reshape(cs.mtimes(_cumulative(N, nu), dm), nu, N)
        Xb, Vb, L = D["Xb"], D["Vb"], D["L"]
        dX, dV = [x / pb.xs - D["Xb0"]], []
        for k in range(N):
            Lk = L[:, k * w : (k + 1) * w]
            dV.append(Lk[:, 0] + cs.mtimes(Lk[:, 1:], cs.vertcat(dX[k], du[:, k])))
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


def _at(M: cs.MX, k: int, N: int, nu: int) -> cs.MX:
    """``M`` placed at input block ``k`` of ``N`` blocks of ``nu`` columns, zeros elsewhere."""
    r = M.shape[0]
    return cs.horzcat(cs.MX(r, k * nu), M, cs.MX(r, (N - k - 1) * nu))


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


class NonlinearMPC(RecedingHorizon):
    """Nonlinear MPC of the tracked output by the regulator command (module docstring).

    Reads every state of the prediction model and the tracked output by name (state
    feedback: the plant's signals of the same names, or an estimator's).

    Parameters
    ----------
    model : Model
        The prediction model (smooth flow law, ``saturate=False``).
    u_op : numpy.ndarray
        The input held before the first sample [SI].
    dt : float
        Sample time [s].
    settings : NMPCSettings, optional
    params : mapping of str to float, optional
        Parameter overrides of ``model`` by name (SI), e.g. the plant's load.

    Examples
    --------
    >>> from sarcomere.dynamics import hanging_load, solve_equilibrium
    >>> m = hanging_load(1, load_kg=0.02, flow_law="smooth", saturate=False)
    >>> eq = solve_equilibrium(m, {"regulator.p_cmd": 5e4})
    >>> mpc = NonlinearMPC(m, eq.u, 0.01)
    >>> y = {n: eq[n] for n in mpc.outputs}
    >>> u = mpc.checked(0.0, y, {"myofibril.length": eq["myofibril.length"]})
    >>> round(u["regulator.p_cmd"])
    50000
    """

    slug = "nmpc"
    offsets = OFFSETS  # the input and output disturbances, after the model parameters

    def __init__(
        self,
        model: Model,
        u_op: np.ndarray,
        dt: float,
        settings: NMPCSettings | None = None,
        params: Mapping[str, float] | None = None,
    ) -> None:
        s = settings or NMPCSettings()
        if model.nz:
            raise ParameterError("nmpc.model", model.name, "an ODE model (no algebraic unknowns)")
        super().__init__(model, dt, s, [*model.state_names, s.output], params)
        # state scales: the largest magnitude at the ends of the input range; states that
        # are zero there (velocities) get 1 cm/s
        big = np.abs(np.vstack([e.x for e in self.clip.ends])).max(axis=0)
        pb = _Problem(model, s, self.dt, np.where(big > 1e-12, big, 1e-2))
        self.problem = pb
        self.engine = _RealTimeIteration(pb) if s.solver == "rti" else _CollocationNLP(pb, s.solver)
        self.disturbance = check_disturbance("nmpc", s.disturbance, model.param_names)
        self.filter = self._disturbance_filter(pb.xs)
        self.reset(u_op)

    def _disturbance_filter(self, xs: np.ndarray) -> StateDisturbanceFilter | None:
        """The Kalman filter of :attr:`NMPCSettings.disturbance` (None for "none"), its
        estimate kept in the range of the load, +-the input range or +-the reachable
        output span."""
        s, m, kind = self.settings, self.model, self.disturbance
        if kind == "none":
            return None
        if kind == "load":
            var = m.variables["load.m"]
            bounds = (var.low, var.high)
        else:
            span = s.u_max - s.u_min if kind == "input" else self.clip.high - self.clip.low
            bounds = (-span, span)
        y_std = s.output_std or DEFAULT_STD.get(m.unit(s.output), 1e-6)
        return StateDisturbanceFilter(m, s.output, kind, self.dt, xs, s.input_std, y_std, bounds)

    @property
    def disturbance_estimate(self) -> float:
        """The own filter's estimate now [SI]: the load mass [kg], the input offset [Pa],
        the output offset [SI]; 0 for "none"."""
        return 0.0 if self.filter is None else float(self._p[self.filter.index])

    def reset(self, u0: Mapping[str, float] | np.ndarray) -> None:
        super().reset(u0)
        self._offset = 0.0
        self.violation = 0.0  # the last RTI QP answer's (scaled rows, see QP_FEASIBLE)
        self.slack = 0.0  # the last RTI plan's largest tension slack [N]
        if self.filter is not None:
            self.filter.reset()
        if isinstance(self.engine, _RealTimeIteration):
            self.engine.reset()
        else:
            self.engine.warm = {}

    def law_function(self) -> cs.Function:
        """The RTI's whole per-sample law as one pure CasADi Function (solver "rti")::

            nmpc_law(memory, x, u_prev, ref, p)
                -> (memory_next, u, violation, fallback, slack)

        ``memory`` (zeros at the start) carries the guess and the plan between samples
        (:class:`_RealTimeIteration`), ``x`` the state [SI, ``model.state_names``],
        ``u_prev`` the input held [SI], ``ref`` the reference at nodes 1..horizon [SI, as
        the optimiser sees it: clipped, shifted by the integral action], ``p`` the
        prediction's parameters [SI, ``model.param_names``]; ``u`` the command [SI],
        ``violation`` the QP answer's, ``fallback`` 1 when the sample fell back, ``slack``
        the plan's largest tension slack [N]. This
        controller calls exactly these Functions each sample (split: ``engine.sample``).
        For C generation build the controller with ``linear_solver="qr"``: LAPACK (the
        default "lapacklu") has no code generation. The
        QP solver DAQP's generated C includes ``daqp/api.h`` and links statically
        against ``libdaqpstat.a``, both in the casadi wheel (``casadi/include``,
        :func:`.rti_compiled.daqp_build`).

        Raises
        ------
        ParameterError
            For the NLP solvers (ipopt, fatrop), which are not one Function.
        """
        if not isinstance(self.engine, _RealTimeIteration):
            raise ParameterError("nmpc.solver", self.settings.solver, "'rti' for a law Function")
        return self.engine.law

    @property
    def memory(self) -> np.ndarray:
        """The RTI's memory vector now (a copy; see :meth:`law_function`)."""
        return self.engine.memory.copy()

    def _rti(self, x: np.ndarray, ref: np.ndarray) -> dict:
        """One sample of the RTI law with the present parameters; the command by name."""
        eng = self.engine
        u, viol, fallback, slack = eng.sample(x, self._u, ref, self._p)
        mem = eng.memory
        self.stats.fallbacks += int(fallback[0])
        self.violation, self.slack = float(viol[0]), float(slack[0])
        self._plan = mem[eng.slices["plan"]].reshape(-1, len(self._u))
        self._u = u
        return dict(zip(self.inputs, self._u.tolist(), strict=True))

    def _estimate(self, x: np.ndarray, u_held: np.ndarray, y: Mapping[str, float]) -> None:
        """The own filter's disturbance estimate from this sample into the parameters."""
        if self.filter is not None:
            out = float(y[self.settings.output])
            self._p[self.filter.index] = self.filter.update(x, u_held, out, self._p)

    def update(self, t: float, y: Mapping[str, float], r: Mapping[str, float]) -> dict:
        x = np.array([y[n] for n in self.model.state_names], dtype=float)
        ref = self.clip(r)
        # the reference per node: the preview if given for this sample, else r(t) held;
        # integral action shifts it by the integrated error, kept inside the reachable range
        nodes = self.nodes(ref)
        shifted = np.clip(nodes + self._offset, self.clip.low, self.clip.high)
        u_prev = self._u.copy()
        if isinstance(self.engine, _RealTimeIteration):
            # real time: the command from the preparation made between samples with the
            # last estimate (the filter's prior for this sample: its disturbance is a random
            # walk); this sample's estimate, made after the command, goes into the next
            u = self._rti(x, shifted)
            self._estimate(x, u_prev, y)
            self.engine.prepare_next(x, self._u, self._p)
        else:
            self._estimate(x, u_prev, y)
            plan, ok = self.engine.solve(x, self._u, shifted, self._p)
            self.slack = self.engine.slack
            u = self.apply(plan if ok else None)
        # anti-windup: no integration while the command is held by a bound or moves at
        # the rate limit (the optimiser could not follow a larger shift either)
        at_rate = np.abs(self._u - u_prev) >= self.settings.rate_max * self.dt * (1 - 1e-6)
        at_bound = (self._u <= self._u_lo) | (self._u >= self._u_hi)
        if not np.any(at_rate | at_bound):
            error = ref - float(y[self.settings.output])
            self._offset += self.settings.integral_gain * self.dt * error
        return u


DEFAULT_FIDELITY = "full"
"""Prediction fidelity of :func:`make_nmpc`, chosen by measurement (BENCHMARKS.md, section
5; ``sarcomere bench mpc``): on the full exact-law plant (n = 3, 20 g, RTI) full and
quasi_static track equally (0.815 mm RMS before the load step) and hold a raised tension
bound to 2e-5 N, and full was the faster of the two; symmetric is about 4x faster and
tracks 6 % worse, but has one representative thread, so it cannot bound the lowest
thread's tension."""


def make_nmpc(model: Model, op: Equilibrium, dt: float, settings: dict) -> Controller:
    """Registry factory of ``nmpc`` for the paper's set-ups.

    The prediction model is the plant's set-up rebuilt for optimisers at the fidelity
    ``fidelity`` (own key, default :data:`DEFAULT_FIDELITY`), with the smooth flow law and
    no clamp: by the scene's ``build_model`` where given, else by the set-up the plant
    records (:attr:`Model.setup`, set by :func:`~sarcomere.dynamics.assemblies.hanging_load`
    and :func:`~sarcomere.dynamics.assemblies.isometric`); its parameters take the plant's
    values by name (``op.p``: load, fixture position, regulator, geometry, the scene's
    overrides).
    Common keys: ``output``, ``input``, ``u_min``, ``u_max``, ``tension_min`` (the hard
    tension bound, default 0). Own keys: the other :class:`NMPCSettings` fields,
    ``fidelity``, ``estimator`` ("none" or "ekf"), ``ekf`` and ``disturbance`` ("load",
    "input", "output" or "none"). Without an estimator the NMPC's own Kalman filter on
    the states it reads estimates the disturbance (:attr:`NMPCSettings.disturbance`,
    default "load" where the prediction has a load, else "input", as the LMPC's); on an
    EKF the EKF does (:func:`~.receding.ekf_disturbance`, default its own: the load where
    the plant has one) and the NMPC's filter is off. The output's noise (``noise_std``)
    sets ``output_std`` unless given. Whichever estimates a parameter of the prediction
    or an offset, the estimate is fed to the prediction every sample and
    ``integral_gain`` defaults to 0 (set it to keep the integral reference shift as
    well; ``disturbance = "none"`` without an EKF keeps the integral's default 5 1/s).
    """
    extra = {"fidelity": DEFAULT_FIDELITY, "disturbance": None}
    own, est, ekf_settings = mpc_settings("nmpc", model, settings, NMPCSettings, extra)
    kind = own.pop("disturbance")
    if est == "ekf":  # the EKF estimates the disturbance: no second estimate
        ekf_settings = ekf_disturbance("nmpc", model, kind, ekf_settings)
    noise = (settings.get("noise_std") or {}).get(settings["output"])
    if own["output_std"] is None and noise:
        own["output_std"] = float(noise)
    given = dict(zip(model.param_names, np.asarray(op.p, float), strict=True))
    fidelity = own.pop("fidelity")
    smooth = {"fidelity": fidelity, "flow_law": "smooth", "saturate": False}
    if settings.get("build_model") is not None:  # a scene: its own set-up, rebuilt
        pred = settings["build_model"](**smooth)
    elif model.setup is not None:  # an assembly's model: the set-up it records
        pred = model.setup.build(**smooth)
    else:
        raise ParameterError(
            "nmpc.model",
            model.name,
            "a model built by an assembly (hanging_load, isometric), or a build_model setting",
            "a System flattened by hand records no set-up to rebuild for prediction",
        )
    params = {n: given[n] for n in pred.param_names if n in given}
    if est == "ekf":
        own["disturbance"] = "none"
        fed = any(
            n in (*pred.param_names, *OFFSETS) for n in estimated_parameters(model, ekf_settings)
        )
    else:  # the NMPC's own filter on the states it reads
        default = "load" if "load.m" in pred.param_names else "input"
        own["disturbance"] = check_disturbance("nmpc", kind or default, pred.param_names)
        fed = own["disturbance"] != "none"
    if fed and "integral_gain" not in settings:  # the estimate removes the offset
        own["integral_gain"] = 0.0
    s = NMPCSettings(
        **own,
        output=settings["output"],
        u_min=float(settings["u_min"]),
        u_max=float(settings["u_max"]),
        tension_min=float(settings.get("tension_min") or 0.0),
    )
    ctl = NonlinearMPC(pred, op.u, dt, s, params)
    return with_estimator("nmpc", ctl, model, op, dt, settings, est, ekf_settings)


register_controller("nmpc", make_nmpc)
