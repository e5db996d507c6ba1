"""The least-squares problem of a fit: unknowns, residuals and constraints as one CasADi
NLP, solved by IPOPT with the Gauss-Newton Hessian.

Unknowns ``v = [phi, S_1, ..., W_1, ...]``: the search variables of the estimated
parameters (:class:`.experiments.Estimated`), the scaled node states of every time series
(:mod:`.shooting`) and the scaled equilibrium unknowns ``[x; z]`` of every static point.
Residuals ``r``: prediction minus data, each divided by its standard deviation
(:class:`.experiments.Noise`; the weights are a parameter of the NLP, so estimating a
noise level re-solves without rebuilding). Constraints ``g(v) = 0``: each record's
equilibrium at its first sample and its continuity defects, and every static point's
equilibrium. The cost is ``1/2 |r|^2``; IPOPT gets the exact gradient and constraint
Jacobian and, as the Hessian of the Lagrangian, the Gauss-Newton matrix
``J_r^T J_r`` (no second derivatives; docs/fitting.md says why this solver).
"""

from __future__ import annotations

import functools
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import casadi as cs
import numpy as np

from ..equilibrium import solve_equilibrium
from ..errors import ParameterError, SolverError
from .experiments import Estimated, Noise, StaticPoint, Target, TimeSeries, check_uses
from .shooting import Shooting

IPOPT = {
    "ipopt.print_level": 0,
    "ipopt.sb": "yes",
    "print_time": False,
    "ipopt.tol": 1e-9,
    "ipopt.constr_viol_tol": 1e-9,
    "ipopt.acceptable_tol": 1e-6,
    "ipopt.acceptable_iter": 5,
    "ipopt.max_iter": 200,
}
"""IPOPT's options for every fit (tolerances on the scaled KKT conditions)."""


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
    unweighted residuals, the weights used, IPOPT's status and iterations."""

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
        return self.status in ("Solve_Succeeded", "Solved_To_Acceptable_Level")


class Problem:
    """The NLP of a fit (module docstring).

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
    options : mapping, optional
        IPOPT options over :data:`IPOPT` (tighter tolerances for a zero-residual fit).
    """

    def __init__(
        self,
        params: Sequence[Estimated],
        series: Sequence[TimeSeries] = (),
        points: Sequence[StaticPoint] = (),
        targets: Sequence[Target] = (),
        noise: Mapping[str, Noise] | None = None,
        options: Mapping[str, object] | None = None,
    ) -> None:
        self.params, self.series = list(params), list(series)
        self.points, self.targets = list(points), list(targets)
        names = [e.name for e in self.params]
        if len(set(names)) != len(names):
            raise ParameterError("parameters", names, "distinct names")
        self.noise = dict(noise or {})
        self.options = {**IPOPT, **(options or {})}
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
        phi = cs.MX.sym("phi", n_theta)
        theta = [e.to_theta(phi[k]) for k, e in enumerate(self.params)]
        unknowns, cons, preds = [phi], [], []
        rows = Rows([], [], [], np.zeros(0))
        data = []
        self.shootings = []
        for exp in self.series:
            m = exp.model
            shoot = Shooting.of(m, exp.t, exp.u, exp.interval, exp.substeps)
            self.shootings.append(shoot)
            S = cs.MX.sym(f"S_{exp.name}", m.nx, shoot.nodes)
            unknowns.append(cs.vec(S))
            p = self._p_expr(exp, theta)
            Xi, defects = shoot.states(S, p)
            scale = shoot.scale()
            u0 = cs.DM(exp.u[0])
            cons += [m.function("ode")(scale * S[:, 0], cs.MX(0, 1), u0, p) / scale, defects]
            n = len(exp.t)
            sig = m.signals_function(list(exp.outputs), n)
            Y = sig(cs.diag(cs.DM(scale)) @ Xi, cs.MX(0, n), cs.DM(exp.u.T), p)
            for j, name in enumerate(exp.outputs):
                ok = np.flatnonzero(np.isfinite(exp.data[:, j]))
                preds.append(Y[j, ok].T)
                data.append(exp.data[ok, j])
                rows.experiment += [exp.name] * len(ok)
                rows.signal += [name] * len(ok)
                rows.sample += ok.tolist()
        solved: dict[tuple[str, str], cs.MX] = {}
        self.point_vars = {}
        for pt in self.points:
            m = pt.model
            w = cs.MX.sym(f"W_{pt.name}", m.nx + m.nz)
            unknowns.append(w)
            scale = np.maximum(np.concatenate([m.nominal("x"), m.nominal("z")]), 1e-12)
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
        v = cs.vertcat(*unknowns)
        pred = cs.vertcat(*preds)
        r = pred - rows.data
        w = cs.MX.sym("w", r.numel())
        rw = w * r
        g = cs.vertcat(*cons)
        self.n_v, self.n_g = v.numel(), g.numel()
        self.sizes = [u.numel() for u in unknowns]
        Jr, Jg = cs.jacobian(rw, v), cs.jacobian(g, v)
        self.residual = cs.Function("residual", [v, w], [rw, Jr, r], ["v", "w"], ["rw", "J", "r"])
        self.constraint = cs.Function("constraint", [v], [g, Jg], ["v"], ["g", "J"])
        self.nlp = (v, w, rw, g, Jr)  # the symbols: unknowns, weights, residuals, constraints, J_r

    @functools.cached_property
    def ipopt(self) -> cs.Function:
        """IPOPT on the same NLP with the Gauss-Newton Hessian (built on first use)."""
        v, w, rw, g, Jr = self.nlp
        lam_f, lam_g = cs.MX.sym("lam_f"), cs.MX.sym("lam_g", g.numel())
        hess = cs.Function(
            "hess_lag",
            [v, w, lam_f, lam_g],
            [lam_f * cs.triu(cs.mtimes(Jr.T, Jr))],
            ["x", "p", "lam_f", "lam_g"],
            ["hess_gamma_x_x"],
        )
        nlp = {"x": v, "p": w, "f": 0.5 * cs.sumsqr(rw), "g": g}
        return cs.nlpsol("fit", "ipopt", nlp, {**self.options, "hess_lag": hess})

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

    def initial_guess(self, theta: np.ndarray) -> np.ndarray:
        """``v`` for parameter values ``theta`` (SI): each record simulated from its
        equilibrium (the node states), each static point solved (:func:`solve_equilibrium`).
        Raises SolverError (which experiment, why) where that fails."""
        theta = np.asarray(theta, dtype=float)
        parts = [np.array([e.to_phi(theta[k]) for k, e in enumerate(self.params)])]
        for exp, shoot in zip(self.series, self.shootings, strict=True):
            try:
                m = exp.model
                over = self._p_numeric(exp, theta)
                eq = solve_equilibrium(m, dict(zip(m.input_names, exp.u[0], strict=True)), over)
                Xi = shoot.simulate(eq.x / shoot.scale(), eq.p)
            except (SolverError, ParameterError) as exc:
                raise SolverError(f"experiment '{exp.name}': {exc}") from None
            starts = [a for a, _ in shoot.bounds]
            parts.append(Xi[:, starts].T.ravel())
        solved: dict[tuple[str, str], float] = {}
        guesses = {}
        for pt in self.points:
            m, scale = self.point_vars[pt.name]
            links = {k: solved[v] for k, v in pt.links.items()}
            try:
                over = self._p_numeric(pt, theta, links)
                inputs = dict(zip(m.input_names, pt.u, strict=True))
                eq = solve_equilibrium(m, inputs, over, guess=guesses.get(m.name))
            except (SolverError, ParameterError) as exc:
                raise SolverError(f"static point '{pt.name}': {exc}") from None
            guesses.setdefault(m.name, eq)
            for sname in (s for (pn, s) in _needed(self.points) if pn == pt.name):
                solved[pt.name, sname] = eq[sname]
            parts.append(np.concatenate([eq.x, eq.z]) / scale)
        return np.concatenate(parts)

    def solve(
        self,
        v0: np.ndarray,
        weights: np.ndarray,
        fixed: Mapping[int, float] | None = None,
    ) -> Solution:
        """Minimise from ``v0`` with the residual ``weights``; ``fixed``: parameter index ->
        search value held (a profile). IPOPT with the Gauss-Newton Hessian; never raises
        for a failed solve: the status says why."""
        lo, hi = self.bounds()
        for k, val in (fixed or {}).items():
            lo[k] = hi[k] = val
        v0 = np.clip(v0, lo, hi)
        try:
            sol = self.ipopt(x0=v0, p=weights, lbx=lo, ubx=hi, lbg=0, ubg=0)
            stats = self.ipopt.stats()
            status, iters = stats["return_status"], int(stats["iter_count"])
        except RuntimeError as exc:
            return _failed(self, v0, weights, f"IPOPT raised: {str(exc).splitlines()[-1][:200]}")
        return self.evaluate(np.array(sol["x"]).ravel(), weights, status, iters)

    def evaluate(self, v, weights, status: str = "evaluated", iters: int = 0) -> Solution:
        """The :class:`Solution` record of unknowns ``v`` (no solve)."""
        rw, _, r = self.residual(v, weights)
        rw, r = np.array(rw).ravel(), np.array(r).ravel()
        phi = v[: len(self.params)]
        return Solution(phi, self.values(phi), v, float(rw @ rw), r, weights, status, iters)

    def predictions(self, sol: Solution) -> np.ndarray:
        """The model's value at every residual row (data + residual)."""
        return self.rows.data + sol.residuals


def _failed(problem: Problem, v0, weights, why: str) -> Solution:
    phi = v0[: len(problem.params)]
    nan = np.full(len(problem.rows.data), np.nan)
    return Solution(phi, problem.values(phi), v0, np.inf, nan, weights, why, 0)


def _needed(points: Sequence[StaticPoint]) -> set[tuple[str, str]]:
    """(point, signal) pairs some later point links to."""
    return {v for pt in points for v in pt.links.values()}


__all__ = ["Problem", "Solution"]
