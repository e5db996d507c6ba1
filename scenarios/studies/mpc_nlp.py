"""The converged NMPC the real-time iteration is compared with in the speed study
(:mod:`.mpc_speed`, ``sarcomere bench mpc``; BENCHMARKS.md, section 5): the same Radau
IIA collocation, cost and bounds as :class:`~sarcomere.controllers.nmpc.NonlinearMPC`,
solved to convergence every sample by IPOPT or fatrop.

The NLP (:class:`CollocationNLP`) is built once as an ``nlpsol`` with the measured state,
the previous input, the reference per node and the prediction's parameters as parameters,
warm-started from the previous solution shifted by one sample (primal and, for IPOPT,
dual). The stage state is ``s_k = [x_k; u_{k-1}]`` (the previous input is carried, so the
rate limit is a constraint of one stage, as fatrop's structure needs); the stage controls
are ``u_k`` and the collocation states; each stage's gap to the next comes first, which
fatrop's ``structure_detection = "auto"`` reads. :class:`ConvergedNMPC` is the controller:
the NMPC with this NLP in place of the RTI (a failed solve falls back to the previous plan
shifted by one sample, counted in ``stats.fallbacks``).
"""

from __future__ import annotations

from collections.abc import Mapping

import casadi as cs
import numpy as np

from sarcomere.controllers.nmpc import NMPCSettings, NonlinearMPC
from sarcomere.controllers.registry import count, positive
from sarcomere.controllers.rti import Prediction
from sarcomere.dynamics.errors import ParameterError
from sarcomere.dynamics.modeling.model import Model

SOLVERS = ("ipopt", "fatrop")
"""The NLP solvers."""

MAX_ITER = 1000
"""Largest NLP iteration limit per sample: the warm-started solves here take 3-15
iterations; a sample that needs more than 1000 is a failed solve (a fallback), not a slow
one."""


class CollocationNLP:
    """The collocation NLP, stage by stage (see the module docstring), as an nlpsol."""

    def __init__(self, pb: Prediction, solver: str, tol: float, max_iter: int) -> None:
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
        ns = 1 if pb.soft.any() else 0  # one slack per node (the soft rows')

        def tension(X, sigma):
            """The node's lower bounds, the soft rows eased by its slack ``sigma`` (cost
            added)."""
            if not ns:
                con(pb.T(X, p), pb.low, inf, False)
                return 0
            con(pb.T(X, p) + cs.DM(pb.soft.astype(float)) * sigma, pb.low, inf, False)
            return pb.penalty * (sigma + sigma**2)

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
                J += pb.penalty * cs.sum1(sig)  # node 0 is measured: no bound, slack 0
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
                    "tol": tol,
                    "max_iter": max_iter,
                    "warm_start_init_point": "yes",
                    "mu_init": 1e-3,
                },
                "print_time": False,
            }
        else:
            opts = {
                "structure_detection": "auto",
                "equality": eq,
                "fatrop": {"print_level": 0, "tol": tol, "max_iter": max_iter},
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
        self.slack = 0.0  # the last solution's largest slack [SI]

    def reset(self) -> None:
        """Forget the warm start."""
        self.warm = {}

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
                "x0": shift(wopt, b, pb.s.horizon),
                "lam_x0": shift(np.array(sol["lam_x"]).ravel(), b, pb.s.horizon),
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


def shift(w: np.ndarray, stage: int, n: int) -> np.ndarray:
    """``n`` stages of ``stage`` entries and a terminal part, moved one stage ahead (the
    last stage repeated)."""
    stages = w[: n * stage].reshape(n, stage)
    return np.concatenate([stages[1:].ravel(), stages[-1], w[n * stage :]])


class ConvergedNMPC(NonlinearMPC):
    """The NMPC solved to convergence every sample by ``solver`` ("ipopt" or "fatrop"),
    to ``tol``, in at most ``max_iter`` iterations (see the module docstring); otherwise
    :class:`~sarcomere.controllers.nmpc.NonlinearMPC` (settings, filter, integral action).
    It has no law Function to export."""

    def __init__(
        self,
        model: Model,
        u_op: np.ndarray,
        dt: float,
        settings: NMPCSettings | None = None,
        params: Mapping[str, float] | None = None,
        solver: str = "ipopt",
        tol: float = 1e-6,
        max_iter: int = 100,
    ) -> None:
        if solver not in SOLVERS:
            raise ParameterError("nmpc.solver", solver, f"one of {SOLVERS}")
        positive("nmpc", "tol", tol)
        count("nmpc.max_iter", max_iter, 1, MAX_ITER, "a limit per sample, not a budget")
        self.solver, self.nlp_options = solver, (solver, float(tol), max_iter)
        super().__init__(model, u_op, dt, settings, params)

    def build_engine(self, pb: Prediction) -> CollocationNLP:
        return CollocationNLP(pb, *self.nlp_options)

    def law_function(self) -> cs.Function:
        raise ParameterError("nmpc.solver", self.nlp_options[0], "'rti' for a law Function")

    def optimise(self, x: np.ndarray, ref: np.ndarray, y: Mapping[str, float]) -> dict:
        """One converged solve, after this sample's estimate; the first input of its plan,
        or of the last plan shifted by one sample when it failed (a fallback)."""
        self.observe(x, self._u.copy(), y)
        plan, ok = self.engine.solve(x, self._u, ref, self._p)
        self.slack = self.engine.slack
        if ok:
            self._plan = plan
        else:
            self.stats.fallbacks += 1
            if self._plan is not None and len(self._plan) > 1:
                self._plan = np.vstack([self._plan[1:], self._plan[-1:]])
            else:
                self._plan = np.tile(self._u, (self.settings.horizon, 1))
        self._u = np.clip(self._plan[0], self._u_lo, self._u_hi)
        return dict(zip(self.inputs, self._u.tolist(), strict=True))
