"""The least-squares problem of a fit: unknowns, residuals and constraints, solved by a
constrained Gauss-Newton (:mod:`.gauss_newton`).

Unknowns ``v = [phi, S_1, ..., W_1, ...]``: the search variables of the estimated
parameters (:class:`.experiments.Estimated`), the scaled node states of every time series
(:mod:`.shooting`, column after column) and the scaled equilibrium unknowns ``[x; z]`` of
every static point. Residuals ``r``: prediction minus data, each weighted by one over its
standard deviation (:class:`.experiments.Noise`; the weights are an argument, so
estimating a noise level re-solves without rebuilding). Constraints ``g(v) = 0``: each
record's equilibrium at its first sample and its continuity defects, and every static
point's equilibrium. :meth:`Problem.linearize` gives both with their exact sparse
Jacobians: the time series from the compiled shooting engine (states and forward
sensitivities in one call per record), the static points and targets from CasADi
Functions of ``[phi; W]``.
"""

from __future__ import annotations

import functools
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import casadi as cs
import numpy as np
import scipy.sparse as sp

from ..equilibrium import solve_equilibrium
from ..errors import ParameterError, SolverError
from .experiments import Estimated, Noise, StaticPoint, Target, TimeSeries, check_uses
from .gauss_newton import Options, gauss_newton
from .shooting import Shooting, auto_step, scales, step_error


@dataclass
class Rows:
    """Where each residual row comes from: experiment, signal, sample index (-1 for a
    static target), the data value, and the noise group (signal name)."""

    experiment: list[str]
    signal: list[str]
    sample: list[int]
    data: np.ndarray


@dataclass
class Solution:
    """One solve: search variables ``phi``, values ``theta`` (SI), all unknowns ``v``,
    ``cost`` = sum of squared weighted residuals (chi-squared with known noise), the
    unweighted residuals, the weights used, the solver's status and iterations."""

    phi: np.ndarray
    theta: np.ndarray
    v: np.ndarray
    cost: float
    residuals: np.ndarray
    weights: np.ndarray
    status: str
    iterations: int

    @property
    def success(self) -> bool:
        return self.status == "converged"


@dataclass
class Linearization:
    """Residuals and constraints at ``v``: weighted ``rw`` and unweighted ``r`` residuals,
    constraints ``g``, and (when asked) their sparse Jacobians ``Jr`` (of ``rw``), ``Jg``."""

    rw: np.ndarray
    r: np.ndarray
    g: np.ndarray
    Jr: sp.csc_matrix | None = None
    Jg: sp.csc_matrix | None = None


@dataclass
class _Series:
    """A record in the problem: the experiment, its shooting, where its nodes sit in
    ``v``, the model entries the estimated values set (``idx``), the estimated values it
    uses (``used``, indices into the parameters) and ``D`` (``p[idx] = D theta[used]``)."""

    exp: TimeSeries
    shoot: Shooting
    offset: int
    idx: list[int]
    used: list[int]
    D: np.ndarray
    rows: list[np.ndarray]


class Problem:
    """The least-squares problem of a fit (module docstring).

    Parameters
    ----------
    params : sequence of Estimated
        The estimated parameters, in order (a per-experiment value is its own entry).
    series : sequence of TimeSeries
    points : sequence of StaticPoint
        Equilibria (solved in order: a link refers to an earlier point).
    targets : sequence of Target
        Static measurements on the points.
    noise : mapping of signal name to Noise
        One per measured signal (time-series outputs and target signals).
    options : gauss_newton.Options, optional
        The solver's tolerances (tighter for a zero-residual fit).
    """

    def __init__(
        self,
        params: Sequence[Estimated],
        series: Sequence[TimeSeries] = (),
        points: Sequence[StaticPoint] = (),
        targets: Sequence[Target] = (),
        noise: Mapping[str, Noise] | None = None,
        options: Options | None = None,
    ) -> None:
        self.params, self.series = list(params), list(series)
        self.points, self.targets = list(points), list(targets)
        names = [e.name for e in self.params]
        if len(set(names)) != len(names):
            raise ParameterError("parameters", names, "distinct names")
        self.noise = dict(noise or {})
        self.options = options or Options()
        for exp in (*self.series, *self.points):
            check_uses(exp.model, exp.uses, names, f"experiment '{exp.name}'")
        measured = {s for e in self.series for s in e.outputs} | {t.signal for t in self.targets}
        missing = sorted(measured - set(self.noise))
        if missing:
            raise ParameterError("noise", missing, "a Noise for every measured signal")
        self._build()

    # --- building ---------------------------------------------------------------------
    def _p_expr(self, exp, theta, extra: Mapping[str, cs.MX] | None = None) -> cs.MX:
        idx = {e.name: k for k, e in enumerate(self.params)}
        entries = []
        for i, pname in enumerate(exp.model.param_names):
            if extra and pname in extra:
                entries.append(extra[pname])
            elif pname in exp.uses:
                ename, factor = exp.uses[pname]
                entries.append(factor * theta[idx[ename]])
            else:
                entries.append(cs.MX(float(exp.p[i])))
        return cs.vertcat(*entries)

    def _build(self) -> None:
        n_theta = len(self.params)
        index = {e.name: k for k, e in enumerate(self.params)}
        rows = Rows([], [], [], np.zeros(0))
        data = []
        offset = n_theta
        self._series: list[_Series] = []
        for exp in self.series:
            m = exp.model
            idx = [i for i, n in enumerate(m.param_names) if n in exp.uses]
            used = sorted({index[exp.uses[m.param_names[i]][0]] for i in idx})
            D = np.zeros((len(idx), len(used)))
            for r_, i in enumerate(idx):
                ename, factor = exp.uses[m.param_names[i]]
                D[r_, used.index(index[ename])] = factor
            states = self._scale_states(exp)
            scale = scales(m, list(states.values()))
            make = functools.partial(_shooting, exp, idx, len(used), scale)
            step = exp.step
            if step is None:  # at the start values, from the first equilibrium
                p0 = _record_p(exp, idx, D, used, np.array([e.start for e in self.params]))
                step = auto_step(make, states[0] / scale, p0, exp.data) if 0 in states else 1
            shoot = make(step)
            picks = []
            for j, name in enumerate(exp.outputs):
                ok = np.flatnonzero(np.isfinite(exp.data[:, j]))
                picks.append(ok)
                data.append(exp.data[ok, j])
                rows.experiment += [exp.name] * len(ok)
                rows.signal += [name] * len(ok)
                rows.sample += ok.tolist()
            self._series.append(_Series(exp, shoot, offset, idx, used, D, picks))
            offset += m.nx * shoot.nodes
        # static points and targets: CasADi Functions of [phi; W]
        phi = cs.MX.sym("phi", n_theta)
        theta = [e.to_theta(phi[k]) for k, e in enumerate(self.params)]
        unknowns, cons, preds = [phi], [], []
        solved: dict[tuple[str, str], cs.MX] = {}
        self.point_vars = {}
        for pt in self.points:
            m = pt.model
            w = cs.MX.sym(f"W_{pt.name}", m.nx + m.nz)
            unknowns.append(w)
            sx = scales(m, list(self._scale_states(pt).values()))
            scale = np.concatenate([sx, np.maximum(m.nominal("z"), 1e-12)])
            x, z = scale[: m.nx] * w[: m.nx], scale[m.nx :] * w[m.nx :]
            links = {k: solved[v] for k, v in pt.links.items()}
            p = self._p_expr(pt, theta, links)
            u = cs.DM(pt.u)
            ode = m.function("ode")(x, z, u, p) / scale[: m.nx]
            cons += [ode, m.function("alg")(x, z, u, p)]
            values = m.function("signals")(x, z, u, p)
            for i, sname in enumerate(m.signal_names):
                solved[pt.name, sname] = values[i]
            self.point_vars[pt.name] = (m, scale)

        def signal(point: str, name: str) -> cs.MX:
            if (point, name) not in solved:
                raise ParameterError("target", f"{point}:{name}", "a signal of a static point")
            return solved[point, name]

        for tg in self.targets:
            preds.append(tg.expr(signal))
            data.append(np.array([tg.value]))
            rows.experiment.append(tg.name)
            rows.signal.append(tg.signal)
            rows.sample.append(-1)
        rows.data = np.concatenate(data) if data else np.zeros(0)
        self.rows = rows
        vs = cs.vertcat(*unknowns)
        pred = cs.vertcat(*preds) if preds else cs.MX(0, 1)
        g = cs.vertcat(*cons) if cons else cs.MX(0, 1)
        self._static = cs.Function(
            "static", [vs], [pred, g, cs.jacobian(pred, vs), cs.jacobian(g, vs)]
        )
        self._w_offset = offset
        self.n_v = offset + vs.numel() - n_theta
        self.n_g = sum(s.exp.model.nx * s.shoot.nodes for s in self._series) + g.numel()

    def _scale_states(self, exp) -> dict[int, np.ndarray]:
        """States of the experiment's equilibria at the start values, at its first and its
        largest inputs, by sample index (for the state scales and the step; none where a
        solve fails)."""
        theta = np.array([e.start for e in self.params])
        over = self._p_numeric(exp, theta) if not getattr(exp, "links", None) else None
        if over is None:
            return {}
        u = np.atleast_2d(exp.u)
        out = {}
        for i in sorted({0, int(np.argmax(np.max(np.abs(u), axis=1)))}):
            try:
                inputs = dict(zip(exp.model.input_names, u[i], strict=True))
                out[i] = solve_equilibrium(exp.model, inputs, over).x
            except (SolverError, ParameterError):
                pass
        return out

    def grid_report(self, theta: np.ndarray) -> dict[str, dict]:
        """Per time series at ``theta`` (SI): the samples a Radau IIA step spans at most,
        the steps, the shooting intervals, and per output the largest difference of the
        predicted signal from one step per sample as a fraction of the data's noise
        level (:func:`.shooting.step_error`; :data:`.shooting.STEP_TOLERANCE` is the
        bound the automatic step keeps at the start values). Raises SolverError."""
        firsts, _ = self._equilibria_of(np.asarray(theta, dtype=float))
        out = {}
        for s, eq in zip(self._series, firsts, strict=True):
            sh, exp = s.shoot, s.exp
            xi0 = eq.x / sh.scale
            fine = _shooting(exp, s.idx, len(s.used), sh.scale, 1)
            err = step_error(sh, fine.predict(xi0, eq.p), xi0, eq.p, exp.data)
            out[exp.name] = {
                "samples_per_step": sh.step,
                "steps": len(sh.grid.k0),
                "intervals": sh.nodes,
                "error_per_noise": dict(zip(exp.outputs, err.tolist(), strict=True)),
            }
        return out

    @property
    def shootings(self) -> list[Shooting]:
        """The time series' shootings, in order."""
        return [s.shoot for s in self._series]

    # --- residuals, constraints and their Jacobians ------------------------------------
    def _p_numeric_series(self, s: _Series, theta: np.ndarray) -> np.ndarray:
        return _record_p(s.exp, s.idx, s.D, s.used, theta)

    def linearize(self, v: np.ndarray, weights: np.ndarray, jacobian: bool = True) -> Linearization:
        """Residuals and constraints at ``v`` (and their Jacobians when ``jacobian``).
        Raises SolverError where a record's simulation fails."""
        v = np.asarray(v, dtype=float)
        n = len(self.params)
        phi = v[:n]
        theta = self.values(phi)
        dtheta = np.array([e.dtheta_dphi(t) for e, t in zip(self.params, theta, strict=True)])
        preds, gs = [], []
        Jr_parts, Jg_parts = [], []  # (rows, cols, values) in COO, offsets added below
        row_r = row_g = 0
        for s in self._series:
            m, shoot = s.exp.model, s.shoot
            nx, nodes = m.nx, shoot.nodes
            p = self._p_numeric_series(s, theta)
            S = v[s.offset : s.offset + nx * nodes].reshape(nodes, nx).T
            if jacobian:
                Xi, dS, dT, node = shoot.sensitivities(S, p, s.D)
            else:
                Xi = shoot.simulate(S, p)
            scale = shoot.scale
            x = scale[:, None] * Xi
            y, Yx, Yp = shoot.outputs(x, p)
            for j, ok in enumerate(s.rows):
                preds.append(y[j, ok])
            f, Fxi, Fp = shoot.engine.equilibrium(S[:, 0], shoot.u[0], p, scale)
            ends = [b for _, b in shoot.bounds[:-1]]
            defects = (Xi[:, ends] - S[:, 1:]).T.ravel()
            gs += [f.ravel(), defects]
            if not jacobian:
                continue
            k = len(s.idx)
            Yx = Yx * scale
            dYs = Yx @ dS  # (n, ny, nx): to the sample's node
            scale_used = dtheta[s.used]  # d theta_used / d phi_used
            dYt = (Yx @ dT + Yp @ s.D) * scale_used
            r0 = row_r
            for j, ok in enumerate(s.rows):
                rr = r0 + np.arange(len(ok))
                cols_node = s.offset + node[ok][:, None] * nx + np.arange(nx)[None, :]
                Jr_parts.append((np.repeat(rr, nx), cols_node.ravel(), dYs[ok, j, :].ravel()))
                nu_ = len(s.used)
                Jr_parts.append(
                    (np.repeat(rr, nu_), np.tile(np.array(s.used), len(ok)), dYt[ok, j, :].ravel())
                )
                r0 += len(ok)
            # equilibrium at the first sample
            gr = row_g + np.arange(nx)
            Jg_parts.append((np.repeat(gr, nx), np.tile(s.offset + np.arange(nx), nx), Fxi.ravel()))
            Fphi = (Fp @ s.D) * scale_used if k else np.zeros((nx, len(s.used)))
            Jg_parts.append(
                (np.repeat(gr, len(s.used)), np.tile(np.array(s.used), nx), Fphi.ravel())
            )
            # continuity: X_end(node j) - node j+1
            for j, b in enumerate(ends):
                gr = row_g + nx * (j + 1) + np.arange(nx)
                cj = s.offset + nx * j + np.arange(nx)
                Jg_parts.append((np.repeat(gr, nx), np.tile(cj, nx), dS[b].ravel()))
                Jg_parts.append((gr, cj + nx, -np.ones(nx)))
                Jg_parts.append(
                    (
                        np.repeat(gr, len(s.used)),
                        np.tile(np.array(s.used), nx),
                        (dT[b] * scale_used).ravel(),
                    )
                )
            row_r = r0
            row_g += nx * nodes
        vs = np.concatenate([phi, v[self._w_offset :]])
        pred_s, g_s, Jp, Jgs = self._static(vs)
        preds.append(np.array(pred_s).ravel())
        gs.append(np.array(g_s).ravel())
        pred = np.concatenate(preds) if preds else np.zeros(0)
        r = pred - self.rows.data
        rw = weights * r
        g = np.concatenate(gs) if gs else np.zeros(0)
        if not jacobian:
            return Linearization(rw, r, g)
        cmap = np.concatenate([np.arange(n), self._w_offset + np.arange(len(vs) - n)])
        for target, base, J in ((Jr_parts, row_r, Jp), (Jg_parts, row_g, Jgs)):
            Js = sp.coo_matrix(J.sparse()) if J.nnz() else None
            if Js is not None:
                target.append((base + Js.row, cmap[Js.col], Js.data))
        Jr = _assemble(Jr_parts, len(r), self.n_v)
        Jr = sp.diags(weights) @ Jr
        Jg = _assemble(Jg_parts, len(g), self.n_v)
        if not (np.all(np.isfinite(rw)) and np.all(np.isfinite(g))):
            raise SolverError("a residual or constraint is not finite")
        return Linearization(rw, r, g, Jr.tocsc(), Jg.tocsc())

    # --- noise ------------------------------------------------------------------------
    def weights(self, sigma: Mapping[str, float] | None = None) -> np.ndarray:
        """``1 / sd`` per residual row; ``sigma``: the estimated signals' current values."""
        sd = np.empty(len(self.rows.data))
        for i, (s, d) in enumerate(zip(self.rows.signal, self.rows.data, strict=True)):
            nz = self.noise[s]
            base = nz.sigma if nz.sigma is not None else (sigma or {}).get(s, 1.0)
            sd[i] = np.hypot(base, nz.relative * abs(d))
        return 1.0 / sd

    @property
    def estimated_noise(self) -> list[str]:
        """Signals whose noise level is estimated."""
        return [s for s, nz in self.noise.items() if nz.sigma is None]

    # --- starts and solves ---------------------------------------------------------------
    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """Bounds of ``v``: the parameters' in search variables, the rest free."""
        lo, hi = np.full(self.n_v, -np.inf), np.full(self.n_v, np.inf)
        for k, e in enumerate(self.params):
            lo[k], hi[k] = e.to_phi(e.low), e.to_phi(e.high)
        return lo, hi

    def values(self, phi: np.ndarray) -> np.ndarray:
        """Parameter values (SI) of search variables ``phi``."""
        return np.array([e.to_theta(float(phi[k])) for k, e in enumerate(self.params)])

    def _p_numeric(self, exp, theta: np.ndarray, links: Mapping[str, float] | None = None):
        idx = {e.name: k for k, e in enumerate(self.params)}
        over = {}
        for pname, (ename, factor) in exp.uses.items():
            over[pname] = factor * theta[idx[ename]]
        for i, pname in enumerate(exp.model.param_names):
            if pname not in over and exp.p[i] != exp.model.variables[pname].value:
                over[pname] = float(exp.p[i])
        over.update(links or {})
        return over

    def _equilibria_of(self, theta: np.ndarray) -> tuple[list, list]:
        """Every record's first equilibrium and every static point's, at ``theta`` (SI),
        each continued from the last one found for it (this process's memory). Raises
        SolverError (which experiment, why) where one fails."""
        memory = self.__dict__.setdefault("_last_equilibria", {})
        firsts = []
        for exp in self.series:
            m = exp.model
            try:
                over = self._p_numeric(exp, theta)
                inputs = dict(zip(m.input_names, exp.u[0], strict=True))
                eq = _continued(m, inputs, over, memory.get(exp.name))
            except (SolverError, ParameterError) as exc:
                raise SolverError(f"experiment '{exp.name}': {exc}") from None
            memory[exp.name] = eq
            firsts.append(eq)
        solved: dict[tuple[str, str], float] = {}
        points = []
        for pt in self.points:
            m, scale = self.point_vars[pt.name]
            links = {k: solved[v] for k, v in pt.links.items()}
            try:
                over = self._p_numeric(pt, theta, links)
                inputs = dict(zip(m.input_names, pt.u, strict=True))
                guess = memory.get(pt.name, memory.get(("model", m.name)))
                eq = _continued(m, inputs, over, guess)
            except (SolverError, ParameterError) as exc:
                raise SolverError(f"static point '{pt.name}': {exc}") from None
            memory[pt.name] = eq
            memory.setdefault(("model", m.name), eq)
            for sname in (s for (pn, s) in _needed(self.points) if pn == pt.name):
                solved[pt.name, sname] = eq[sname]
            points.append(np.concatenate([eq.x, eq.z]) / scale)
        return firsts, points

    def initial_guess(self, theta: np.ndarray) -> np.ndarray:
        """``v`` for parameter values ``theta`` (SI): each record simulated from its
        equilibrium (the node states), each static point solved (:func:`solve_equilibrium`).
        Raises SolverError (which experiment, why) where that fails."""
        theta = np.asarray(theta, dtype=float)
        self.__dict__.pop("_last_equilibria", None)
        parts = [np.array([e.to_phi(theta[k]) for k, e in enumerate(self.params)])]
        firsts, points = self._equilibria_of(theta)
        for exp, shoot, eq in zip(self.series, self.shootings, firsts, strict=True):
            try:
                Xi = shoot.march(eq.x / shoot.scale, eq.p)
            except SolverError as exc:
                raise SolverError(f"experiment '{exp.name}': {exc}") from None
            starts = [a for a, _ in shoot.bounds]
            parts.append(Xi[:, starts].T.ravel())
        return np.concatenate(parts + points)

    def restore(self, v: np.ndarray) -> np.ndarray:
        """``v`` with every equilibrium unknown (each record's first node, each static
        point) solved exactly at its parameters (:func:`solve_equilibrium`, continued
        from the last solution); the other nodes kept (lifted). Raises SolverError."""
        v = np.array(v, dtype=float)
        theta = self.values(v[: len(self.params)])
        firsts, points = self._equilibria_of(theta)
        for s, eq in zip(self._series, firsts, strict=True):
            v[s.offset : s.offset + s.exp.model.nx] = eq.x / s.shoot.scale
        if points:
            v[self._w_offset :] = np.concatenate(points)
        return v

    def solve(
        self,
        v0: np.ndarray,
        weights: np.ndarray,
        fixed: Mapping[int, float] | None = None,
    ) -> Solution:
        """Minimise from ``v0`` with the residual ``weights``; ``fixed``: parameter index ->
        search value held (a profile). Constrained Gauss-Newton (:mod:`.gauss_newton`);
        never raises for a failed solve: the status says why."""
        lo, hi = self.bounds()
        for k, val in (fixed or {}).items():
            lo[k] = hi[k] = val
        n = len(self.params)
        v0 = np.asarray(v0, dtype=float).copy()
        v0[:n] = np.clip(v0[:n], lo[:n], hi[:n])

        def evaluate(v: np.ndarray, jacobian: bool):
            v = self.restore(v)
            return v, self.linearize(v, weights, jacobian)

        out = gauss_newton(evaluate, v0, lo[:n], hi[:n], self.options)
        if out.linearization is None:
            return _failed(self, out.v, weights, out.status)
        lin = out.linearization
        phi = out.v[:n]
        cost = float(lin.rw @ lin.rw)
        return Solution(
            phi, self.values(phi), out.v, cost, lin.r, weights, out.status, out.iterations
        )

    def evaluate(self, v, weights, status: str = "evaluated", iters: int = 0) -> Solution:
        """The :class:`Solution` record of unknowns ``v`` (no solve)."""
        lin = self.linearize(v, weights, jacobian=False)
        phi = v[: len(self.params)]
        return Solution(
            phi, self.values(phi), v, float(lin.rw @ lin.rw), lin.r, weights, status, iters
        )

    def predictions(self, sol: Solution) -> np.ndarray:
        """The model's value at every residual row (data + residual)."""
        return self.rows.data + sol.residuals


def _shooting(exp: TimeSeries, idx, ne: int, scale: np.ndarray, step: int) -> Shooting:
    """The shooting of a time series on a grid of at most ``step`` samples per step."""
    return Shooting.of(exp.model, exp.t, exp.u, exp.interval, idx, ne, exp.outputs, scale, step)


def _record_p(exp: TimeSeries, idx, D: np.ndarray, used, theta: np.ndarray) -> np.ndarray:
    """A time series' parameter vector with the estimated values ``theta`` (SI) entered:
    ``p[idx] = D theta[used]``."""
    p = np.array(exp.p, dtype=float)
    if len(idx):
        p[list(idx)] = D @ theta[used]
    return p


def _failed(problem: Problem, v0, weights, why: str) -> Solution:
    phi = v0[: len(problem.params)]
    nan = np.full(len(problem.rows.data), np.nan)
    return Solution(phi, problem.values(phi), v0, np.inf, nan, weights, why, 0)


def _continued(model, inputs, over, guess):
    """The equilibrium continued from ``guess``, else solved from the model's own start."""
    if guess is not None:
        try:
            return solve_equilibrium(model, inputs, over, guess=guess)
        except SolverError:
            pass
    return solve_equilibrium(model, inputs, over)


def _needed(points: Sequence[StaticPoint]) -> set[tuple[str, str]]:
    """(point, signal) pairs some later point links to."""
    return {v for pt in points for v in pt.links.values()}


def _assemble(parts, n_rows: int, n_cols: int) -> sp.csr_matrix:
    if not parts:
        return sp.csr_matrix((n_rows, n_cols))
    rows = np.concatenate([np.asarray(p[0]) for p in parts])
    cols = np.concatenate([np.asarray(p[1]) for p in parts])
    vals = np.concatenate([np.asarray(p[2], dtype=float) for p in parts])
    return sp.coo_matrix((vals, (rows, cols)), shape=(n_rows, n_cols)).tocsr()


__all__ = ["Linearization", "Problem", "Solution"]
