"""Multiple shooting of a time series with Radau IIA collocation and exact derivatives.

The record is cut into shooting intervals of ``interval`` samples. The scaled state
``xi = x / x_nominal`` at each interval's start is an unknown of the fit; inside an
interval the states at the samples follow from it by Radau IIA steps (3 nodes, order 5:
the equations of :func:`..simulation.collocation.residual`, one step per sample or
``substeps`` steps) solved by ``casadi.rootfinder`` (Newton, derivatives by the implicit
function theorem: exact, no finite differences). The inputs are linear between samples
(the :class:`~sarcomere.dynamics.signals.Table` convention). Continuity at the interval
ends and the equilibrium at the first sample are equality constraints; single shooting is
one interval.
"""

from __future__ import annotations

from dataclasses import dataclass

import casadi as cs
import numpy as np

from ..errors import SolverError
from ..modeling.model import Model
from ..simulation import collocation

POINTS = 3
"""Radau IIA nodes per step (order 5)."""

NEWTON = {"abstol": 1e-9, "abstolStep": 1e-9, "max_iter": 50, "linear_solver": "qr"}
"""The step's Newton (scaled unknowns: states divided by their nominal values)."""


def _scales(model: Model) -> np.ndarray:
    return np.maximum(model.nominal("x"), 1e-12)


def step_function(model: Model, substeps: int = 1) -> cs.Function:
    """``step(xi0, u0, u1, h, p) -> xi1``: ``substeps`` Radau IIA steps over ``h`` [s] with
    the inputs linear from ``u0`` to ``u1`` (scaled states; memoised on the model)."""

    def build() -> cs.Function:
        nx, nu, n_p = model.nx, model.u.numel(), model.p.numel()
        scale = _scales(model)
        ode = cs.Function("ode", [model.x, model.u, model.p], [model.ode])
        tau, xi = cs.SX.sym("tau"), cs.SX.sym("xi", nx)
        q = cs.SX.sym("q", 2 * nu + 3 + n_p)  # u0, u1, h, tau0, dtau (of the sample), p
        u0, u1, h, a, b = q[:nu], q[nu : 2 * nu], q[2 * nu], q[2 * nu + 1], q[2 * nu + 2]
        s = a + b * tau  # the position inside the sample interval
        f = cs.Function(
            "f",
            [tau, xi, q],
            [h * b * ode(scale * xi, u0 + s * (u1 - u0), q[2 * nu + 3 :]) / scale],
        )
        R = collocation.residual(f, nx, POINTS)
        V, x0 = cs.SX.sym("V", nx * POINTS), cs.SX.sym("xi0", nx)
        rf = cs.rootfinder(
            "radau_newton", "newton", cs.Function("r", [V, x0, q], [R(x0, V, q)]), NEWTON
        )
        xs, us0, us1 = cs.MX.sym("xi0", nx), cs.MX.sym("u0", nu), cs.MX.sym("u1", nu)
        hs, ps = cs.MX.sym("h"), cs.MX.sym("p", n_p)
        x = xs
        for k in range(substeps):
            qk = cs.vertcat(us0, us1, hs, k / substeps, 1.0 / substeps, ps)
            x = rf(cs.repmat(x, POINTS, 1), x, qk)[-nx:]
        return cs.Function(
            "step", [xs, us0, us1, hs, ps], [x], ["xi0", "u0", "u1", "h", "p"], ["xi1"]
        )

    return model.cached(("identification.step", substeps), build)


def interval_function(model: Model, steps: int, substeps: int = 1) -> cs.Function:
    """``steps`` consecutive :func:`step_function` steps: ``(xi0, U0, U1, H, p) -> Xi``,
    ``U0, U1`` (nu x steps), ``H`` (1 x steps), ``Xi`` (nx x steps) the states after each."""
    key = ("identification.interval", steps, substeps)

    def build() -> cs.Function:
        step = step_function(model, substeps)
        f = cs.Function(
            "f", step.mx_in(), [step(*step.mx_in())], ["xi0", "u0", "u1", "h", "p"], ["xi1"]
        )
        acc = f.mapaccum("interval", steps, 1, {})  # xi accumulated, p repeated per column
        return acc

    return model.cached(key, build)


@dataclass
class Shooting:
    """The shooting of one record: interval boundaries (sample indices), the node
    unknowns' size and the Functions that build its symbolic parts."""

    model: Model
    t: np.ndarray
    u: np.ndarray
    bounds: list[tuple[int, int]]
    substeps: int

    @classmethod
    def of(cls, model: Model, t, u, interval: int | None, substeps: int) -> Shooting:
        n = len(t)
        size = n - 1 if interval is None else interval
        edges = list(range(0, n - 1, size)) + [n - 1]
        return cls(
            model,
            np.asarray(t),
            np.asarray(u),
            list(zip(edges[:-1], edges[1:], strict=True)),
            substeps,
        )

    @property
    def nodes(self) -> int:
        return len(self.bounds)

    def _interval_args(self, a: int, b: int, p):
        u = self.u.T
        h = np.diff(self.t[a : b + 1])[None, :]
        steps = b - a
        return interval_function(self.model, steps, self.substeps), (
            u[:, a:b],
            u[:, a + 1 : b + 1],
            h,
            cs.repmat(p, 1, steps) if isinstance(p, cs.MX) else np.tile(p[:, None], (1, steps)),
        )

    def states(self, S, p) -> tuple[cs.MX, cs.MX]:
        """Symbolic scaled states at every sample (nx x n) from the node unknowns ``S``
        (nx x nodes), and the continuity defects (nx * (nodes - 1))."""
        cols, defects = [S[:, 0]], []
        for j, (a, b) in enumerate(self.bounds):
            F, args = self._interval_args(a, b, p)
            X = F(S[:, j], *args)
            cols.append(X)
            if j + 1 < self.nodes:
                defects.append(X[:, -1] - S[:, j + 1])
        return cs.horzcat(*cols), cs.vertcat(*defects) if defects else cs.MX(0, 1)

    def simulate(self, xi0: np.ndarray, p: np.ndarray) -> np.ndarray:
        """Scaled states at every sample (nx x n), integrated from ``xi0`` at ``p``
        (numeric: the node guesses of a start). Raises SolverError where a step fails."""
        cols = [np.asarray(xi0, dtype=float)[:, None]]
        for a, b in self.bounds:
            F, args = self._interval_args(a, b, p)
            try:
                X = np.array(F(cols[-1][:, -1], *args))
            except RuntimeError as exc:
                raise SolverError(
                    f"the Radau IIA step failed between t = {self.t[a]:g} s and {self.t[b]:g} s "
                    f"({str(exc).splitlines()[-1][:120]})"
                ) from None
            if not np.all(np.isfinite(X)):
                raise SolverError(
                    f"the simulation diverged between t = {self.t[a]:g} s and {self.t[b]:g} s"
                )
            cols.append(X)
        return np.hstack(cols)

    def scale(self) -> np.ndarray:
        """Nominal state values: ``x = scale * xi``."""
        return _scales(self.model)
