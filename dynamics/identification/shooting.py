"""Multiple shooting of a time series: fixed-step Radau IIA collocation with forward
sensitivities, generated to C.

The record is cut into shooting intervals of ``interval`` samples. The scaled state
``xi = x / x_nominal`` at each interval's start is an unknown of the fit (a node); inside
an interval the states at the samples follow from it by one Radau IIA step per sample (3
nodes, order 5: the equations of :func:`..simulation.collocation.residual`; or
``substeps`` equal steps), the inputs linear between samples (the
:class:`~sarcomere.dynamics.signals.Table` convention).

Each step's collocation equations ``R(V, xi_k, q_k, p) = 0`` are solved for the stage
values ``V`` by Newton (CasADi's ``fast_newton``: sparse QR, code-generable) from
``V = xi_k`` at every node. The sensitivities of the step's end state follow at the
converged stages by the implicit function theorem (exact, no finite differences):
``S_{k+1} = -[R_V^-1 (R_xi S_k + [0, R_p D])]_end`` with ``S = d xi / d(node, theta_e)``
(``theta_e``: the estimated values the experiment uses, entering ``p`` as ``p_sel = D
theta_e``). The steps of an interval are one ``mapaccum``, the intervals one ``map``: a
record's states (and sensitivities) are one compiled call. The C is generated once per
(model, estimated entries, interval length, outputs) and kept in the disk cache of
:mod:`..simulation.compiled`. A step whose Newton does not bring the scaled residual
below :data:`RESIDUAL_TOL` is a SolverError naming its time.
"""

from __future__ import annotations

from dataclasses import dataclass

import casadi as cs
import numpy as np

from ..errors import SolverError
from ..modeling.model import Model
from ..simulation import collocation, compiled

POINTS = 3
"""Radau IIA nodes per step (order 5)."""

NEWTON = {"abstol": 1e-10, "abstolStep": 1e-10, "max_iter": 30, "error_on_fail": False}
"""The step's Newton (scaled unknowns: states divided by their nominal values); a failure
is detected from the residual it leaves (:data:`RESIDUAL_TOL`), not by CasADi."""

RESIDUAL_TOL = 1e-8
"""Largest scaled collocation residual of an accepted step."""


def scales(model: Model, states=()) -> np.ndarray:
    """State scales ``x = scales * xi``: the larger of the model's nominal values and the
    magnitudes in ``states`` (e.g. equilibria of the record: a set pressure whose nominal
    is 1 Pa reaches 1e5 Pa), rounded up to a power of two (exact scaling)."""
    mag = np.max(np.abs(np.vstack([model.nominal("x"), *states])), axis=0)
    return 2.0 ** np.ceil(np.log2(np.maximum(mag, 1e-12)))


@dataclass(frozen=True)
class Engine:
    """The compiled Functions of one (model, estimated entries ``idx``, ``ne`` estimated
    values, interval length ``L``, outputs), called on numpy arrays
    (:class:`~..simulation.compiled.NumpyFunction`):

    * ``values(xi0, Q, p, scale) -> (Xi, res)``: one interval's scaled states after each
      step (nx x L) and each step's residual (1 x L); ``Q`` (2 nu + 1) x L: ``u0, u1, h``.
    * ``sens(xi0, Q, p, D, scale) -> (Xi, S, res)``: also ``S`` = nx x ((nx + ne) L), the
      sensitivities after each step to the node and to ``theta_e``.
    * ``outputs(X, U, p) -> (y, Y_x, Y_p)``: the measured signals at ``L`` samples and
      their Jacobians to ``x`` (unscaled) and to ``p_sel``, side by side.
    * ``equilibrium(xi, u, p, scale) -> (f, F_xi, F_p)``: the scaled ODE at the first
      sample and its Jacobians to ``xi`` and ``p_sel``.
    """

    values: compiled.NumpyFunction
    sens: compiled.NumpyFunction
    outputs: compiled.NumpyFunction
    equilibrium: compiled.NumpyFunction
    length: int


def engine(
    model: Model, idx: tuple[int, ...], ne: int, length: int, outputs: tuple, substeps: int = 1
) -> Engine:
    """The :class:`Engine` (generated, compiled and loaded once; memoised on the model);
    ``substeps`` Radau IIA steps per sample."""
    key = ("identification.engine", idx, ne, length, outputs, substeps)
    return model.cached(key, lambda: _build(model, idx, ne, length, outputs, substeps))


def _build(
    model: Model, idx: tuple[int, ...], ne: int, length: int, outputs: tuple, substeps: int
) -> Engine:
    nx, nu, n_p, k = model.nx, model.u.numel(), model.p.numel(), len(idx)
    scale = cs.SX.sym("scale", nx)
    ode = cs.Function("ode", [model.x, model.u, model.p], [model.ode])
    tau, xi, q = cs.SX.sym("tau"), cs.SX.sym("xi", nx), cs.SX.sym("q", 2 * nu + 1)
    p = cs.SX.sym("p", n_p)
    u0, u1, h = q[:nu], q[nu : 2 * nu], q[2 * nu]
    f = cs.Function(
        "f",
        [tau, xi, cs.vertcat(q, p, scale)],
        [h * ode(scale * xi, u0 + tau * (u1 - u0), p) / scale],
    )
    V = cs.SX.sym("V", nx * POINTS)
    r = collocation.residual(f, nx, POINTS)(xi, V, cs.vertcat(q, p, scale))
    psel = cs.vertcat(*[p[i] for i in idx]) if idx else cs.SX(0, 1)
    R = cs.Function("R", [V, xi, q, p, scale], [r])
    RJ = cs.Function(
        "RJ", [V, xi, q, p, scale], [cs.jacobian(r, V), cs.jacobian(r, xi), cs.jacobian(r, psel)]
    )
    newton = cs.rootfinder("radau_step", "fast_newton", R, NEWTON)

    xm, qm, pm = cs.MX.sym("xi", nx), cs.MX.sym("q", q.numel()), cs.MX.sym("p", n_p)
    Sm, Dm, cm = cs.MX.sym("S", nx, nx + ne), cs.MX.sym("D", k, ne), cs.MX.sym("scale", nx)

    def advance(x, S):
        """The sample's step (``substeps`` equal parts, inputs interpolated); ``S`` carried
        along when given."""
        res = cs.MX(0)
        for j in range(substeps):
            a, b = j / substeps, (j + 1) / substeps
            qj = cs.vertcat(
                qm[:nu] + a * (qm[nu : 2 * nu] - qm[:nu]),
                qm[:nu] + b * (qm[nu : 2 * nu] - qm[:nu]),
                qm[2 * nu] / substeps,
            )
            Vs = newton(cs.repmat(x, POINTS, 1), x, qj, pm, cm)
            res = cs.fmax(res, cs.norm_inf(R(Vs, x, qj, pm, cm)))
            if S is not None:
                RV, Rx, Rp = RJ(Vs, x, qj, pm, cm)
                rhs = Rx @ S + cs.horzcat(cs.MX(nx * POINTS, nx), Rp @ Dm)
                S = -cs.solve(RV, rhs, "qr")[-nx:, :]
            x = Vs[-nx:]
        return x, S, res

    x1, _, r1 = advance(xm, None)
    value_step = cs.Function("value_step", [xm, qm, pm, cm], [x1, r1])
    x1, S1, r1 = advance(xm, Sm)
    sens_step = cs.Function("sens_step", [xm, Sm, qm, pm, Dm, cm], [x1, S1, r1])

    Q = cs.MX.sym("Q", q.numel(), length)
    acc_v = value_step.mapaccum("acc_v", length, [0], [0])
    Xi, rv = acc_v(xm, Q, cs.repmat(pm, 1, length), cs.repmat(cm, 1, length))
    values = cs.Function(
        "fit_values", [xm, Q, pm, cm], [Xi, rv], ["xi0", "Q", "p", "scale"], ["Xi", "res"]
    )
    acc_s = sens_step.mapaccum("acc_s", length, [0, 1], [0, 1])
    S0 = cs.horzcat(cs.DM.eye(nx), cs.DM.zeros(nx, ne))
    rep = [cs.repmat(a, 1, length) for a in (pm, Dm, cm)]
    Xs, Ss, rs = acc_s(xm, S0, Q, *rep)
    sens = cs.Function(
        "fit_sens",
        [xm, Q, pm, Dm, cm],
        [Xs, Ss, rs],
        ["xi0", "Q", "p", "D", "scale"],
        ["Xi", "S", "res"],
    )

    index = {n: i for i, n in enumerate(model.signal_names)}
    sig = model.function("signals")(model.x, cs.SX(0, 1), model.u, model.p)
    y = cs.vertcat(*[sig[index[o]] for o in outputs]) if outputs else cs.SX(0, 1)
    psel_m = cs.vertcat(*[model.p[i] for i in idx]) if idx else cs.SX(0, 1)
    out = cs.Function(
        "fit_outputs",
        [model.x, model.u, model.p],
        [y, cs.jacobian(y, model.x), cs.jacobian(y, psel_m)],
        ["x", "u", "p"],
        ["y", "Y_x", "Y_p"],
    )
    fe = ode(scale * xi, model.u, p) / scale
    eq = cs.Function(
        "fit_equilibrium",
        [xi, model.u, p, scale],
        [fe, cs.jacobian(fe, xi), cs.jacobian(fe, psel)],
        ["xi", "u", "p", "scale"],
        ["f", "F_xi", "F_p"],
    )
    stem = f"fit_{model.name}".replace(".", "_")
    Xo, Uo = cs.MX.sym("X", nx, length), cs.MX.sym("U", nu, length)
    out_map = out.map(length)
    outs = cs.Function("fit_outputs_map", [Xo, Uo, pm], out_map(Xo, Uo, cs.repmat(pm, 1, length)))
    lib = compiled.numpy_library([values, sens, outs, eq], stem)
    return Engine(
        lib["fit_values"], lib["fit_sens"], lib["fit_outputs_map"], lib["fit_equilibrium"], length
    )


@dataclass
class Shooting:
    """The shooting of one record: its model, samples ``t`` (n,) [s], inputs ``u`` (n, nu),
    the interval boundaries (sample indices), and the :class:`Engine`; ``idx``: the model
    parameters the estimated values set, ``ne`` how many estimated values the record uses.
    """

    model: Model
    t: np.ndarray
    u: np.ndarray
    bounds: list[tuple[int, int]]
    engine: Engine
    scale: np.ndarray

    @classmethod
    def of(
        cls, model: Model, t, u, interval: int | None, idx, ne: int, outputs, scale, substeps=1
    ) -> Shooting:
        n = len(t)
        size = n - 1 if interval is None else min(interval, n - 1)
        edges = list(range(0, n - 1, size)) + [n - 1]
        bounds = list(zip(edges[:-1], edges[1:], strict=True))
        eng = engine(model, tuple(idx), ne, size, tuple(outputs), substeps)
        return cls(model, np.asarray(t, float), np.asarray(u, float), bounds, eng, scale)

    @property
    def nodes(self) -> int:
        return len(self.bounds)

    def _q(self) -> np.ndarray:
        """``Q`` of every interval side by side, each padded to the interval length with
        steps of zero length at the last input (their states repeat, unused)."""
        L, u = self.engine.length, self.u
        cols = []
        for a, b in self.bounds:
            steps = np.arange(a, a + L)
            live = steps < b
            k0 = np.minimum(steps, b)
            k1 = np.where(live, steps + 1, b)
            h = np.where(live, self.t[np.minimum(steps + 1, len(self.t) - 1)] - self.t[k0], 0.0)
            cols.append(np.vstack([u[k0].T, u[k1].T, h[None, :]]))
        return np.hstack(cols)

    def _check(self, res: np.ndarray, X: np.ndarray) -> None:
        """A SolverError naming the first step whose Newton left a residual above
        :data:`RESIDUAL_TOL` or whose state is not finite."""
        L = self.engine.length
        finite = np.all(np.isfinite(X), axis=0)
        for j, (a, b) in enumerate(self.bounds):
            part = slice(j * L, j * L + (b - a))
            bad = np.flatnonzero(~(res[part] <= RESIDUAL_TOL) | ~finite[part])
            if bad.size:
                k, r = a + int(bad[0]), res[part][bad[0]]
                why = (
                    "a non-finite state"
                    if not finite[part][bad[0]]
                    else f"Newton left a scaled residual of {r:.3g} (above {RESIDUAL_TOL:g})"
                )
                raise SolverError(
                    f"the Radau IIA step from t = {self.t[k]:g} s to {self.t[k + 1]:g} s "
                    f"failed: {why}"
                )

    def _gather(self, X: np.ndarray, S0: np.ndarray) -> np.ndarray:
        """States at every sample (nx x n) from the intervals' outputs ``X`` (nx x L B):
        sample 0 is the first node, the rest come from the interval they end in."""
        L = self.engine.length
        cols = [S0[:, :1]]
        for j, (a, b) in enumerate(self.bounds):
            cols.append(X[:, j * L : j * L + (b - a)])
        return np.hstack(cols)

    def simulate(self, S: np.ndarray, p: np.ndarray) -> np.ndarray:
        """Scaled states at every sample (nx x n) from the nodes ``S`` (nx x nodes) at the
        parameter vector ``p``. Raises SolverError where a step fails."""
        L, Q = self.engine.length, self._q()
        parts = [
            self.engine.values(S[:, j], Q[:, j * L : (j + 1) * L], p, self.scale)
            for j in range(self.nodes)
        ]
        X = np.hstack([x for x, _ in parts])
        res = np.concatenate([r.ravel() for _, r in parts])
        self._check(res, X)
        return self._gather(X, S)

    def march(self, xi0: np.ndarray, p: np.ndarray) -> np.ndarray:
        """Scaled states at every sample integrated from ``xi0`` (each interval from the
        last one's end: the node guesses of a start)."""
        cols = [np.asarray(xi0, float)[:, None]]
        L, Q = self.engine.length, self._q()
        for j, (a, b) in enumerate(self.bounds):
            X, res = self.engine.values(cols[-1][:, -1], Q[:, j * L : (j + 1) * L], p, self.scale)
            res = res.ravel()
            rj = res[: b - a]
            if not np.all(rj <= RESIDUAL_TOL) or not np.all(np.isfinite(X)):
                raise SolverError(
                    f"the simulation failed between t = {self.t[a]:g} s and {self.t[b]:g} s "
                    f"(largest scaled Newton residual {np.nanmax(rj):.3g})"
                )
            cols.append(X[:, : b - a])
        return np.hstack(cols)

    def outputs(self, x: np.ndarray, p: np.ndarray) -> tuple[np.ndarray, ...]:
        """The measured signals at every sample (ny x n) from the unscaled states ``x``
        (nx x n), and their Jacobians ``Y_x`` (n, ny, nx) and ``Y_p`` (n, ny, k)."""
        L, n = self.engine.length, x.shape[1]
        chunks = -(-n // L)
        pad = chunks * L - n
        X = np.hstack([x, np.repeat(x[:, -1:], pad, axis=1)])
        U = np.vstack([self.u, np.repeat(self.u[-1:], pad, axis=0)]).T
        parts = [
            self.engine.outputs(X[:, c * L : (c + 1) * L], U[:, c * L : (c + 1) * L], p)
            for c in range(chunks)
        ]
        y = np.hstack([a for a, _, _ in parts])[:, :n]
        ny, nx = y.shape[0], x.shape[0]
        Yx = np.hstack([b for _, b, _ in parts]).reshape(ny, -1, nx)[:, :n].transpose(1, 0, 2)
        k = parts[0][2].shape[1] // L
        Yp = np.hstack([c for _, _, c in parts]).reshape(ny, -1, k)[:, :n].transpose(1, 0, 2)
        return y, Yx, Yp

    def sensitivities(self, S: np.ndarray, p: np.ndarray, D: np.ndarray):
        """States at every sample (nx x n) and their sensitivities: ``dS`` (n, nx, nx) to
        the node of the interval the sample lies in (sample 0: the identity to node 0),
        ``dT`` (n, nx, ne) to ``theta_e``, and that node's index per sample (n,)."""
        B, L, nx = self.nodes, self.engine.length, self.model.nx
        ne = D.shape[1]
        Q = self._q()
        parts = [
            self.engine.sens(S[:, j], Q[:, j * L : (j + 1) * L], p, D, self.scale) for j in range(B)
        ]
        X = np.hstack([x for x, _, _ in parts])
        Sens = np.hstack([sj for _, sj, _ in parts])
        res = np.concatenate([r.ravel() for _, _, r in parts])
        self._check(res, X)
        blocks = Sens.reshape(nx, B * L, nx + ne).transpose(1, 0, 2)
        n = len(self.t)
        dS, dT, node = np.zeros((n, nx, nx)), np.zeros((n, nx, ne)), np.zeros(n, int)
        dS[0] = np.eye(nx)
        for j, (a, b) in enumerate(self.bounds):
            part = blocks[j * L : j * L + (b - a)]
            dS[a + 1 : b + 1], dT[a + 1 : b + 1], node[a + 1 : b + 1] = (
                part[:, :, :nx],
                part[:, :, nx:],
                j,
            )
        if not np.all(np.isfinite(blocks)):
            raise SolverError("the sensitivities of the simulation are not finite")
        return self._gather(X, S), dS, dT, node
