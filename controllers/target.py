"""Target calculation: the steady state ``(x_s, u_s)`` at which the tracked output equals
its reference, for given model parameters and disturbances, on the nonlinear model.

The unknowns ``w = [x_s; u_s]`` (one input moves one tracked output) solve the square
system ::

    f(x_s, u_s + d_in, p) = 0                 (nx equations: at rest)
    y(x_s, u_s + d_in, p) + d_out - r = 0     (the output on the reference)

with ``d_in`` a constant added to the command (an input disturbance [SI of the input])
and ``d_out`` a constant added to the measured output (an output disturbance [SI of the
output]). The damped Newton method of :mod:`sarcomere.dynamics.newton` with the exact
Jacobian (one CasADi Function gives the residual and the Jacobian), warm-started from the
last target, each row weighted by its largest Jacobian entry times the unknowns' scale,
stops when every step component is below ``1e-10`` of that scale. The linear MPC
linearises at this point (:mod:`.lmpc`), so its model is the one of where the loop is
going, at the load the estimator found.
"""

from __future__ import annotations

import casadi as cs
import numpy as np

from sarcomere.dynamics.errors import ParameterError, SolverError
from sarcomere.dynamics.modeling.model import Model
from sarcomere.dynamics.newton import NewtonFailure, damped_newton, row_weights

MAX_NEWTON = 30
"""Newton steps per target before it is refused (a warm start needs 2 to 4)."""


class SteadyTarget:
    """The steady state of ``model`` with ``output`` on a reference (module docstring).

    Parameters
    ----------
    model : Model
        An explicit model (no algebraic unknowns) with one input.
    output : str
        The tracked signal.
    scale : numpy.ndarray
        The size of each unknown ``[x; u]`` [SI]: the Newton step is converged when every
        component is below ``1e-10`` of it.
    """

    def __init__(self, model: Model, output: str, scale: np.ndarray) -> None:
        if model.nz:
            raise ParameterError("target.model", model.name, "an explicit model (no algebraic)")
        if len(model.input_names) != 1:
            raise ParameterError("target.model", model.input_names, "a model with one input")
        nx = model.nx
        w, r = cs.SX.sym("w", nx + 1), cs.SX.sym("r")
        p, d = cs.SX.sym("p", model.p.numel()), cs.SX.sym("d", 2)
        x, u = w[:nx], w[nx:] + d[0]
        z = cs.SX(0, 1)
        f = model.function("ode")(x, z, u, p)
        y = model.signals_function([output])(x, z, u, p)
        res = cs.vertcat(f, y + d[1] - r)
        self._newton = cs.Function("target", [w, r, p, d], [res, cs.jacobian(res, w)])
        self.scale = np.asarray(scale, dtype=float)
        self.nx = nx

    def __call__(
        self,
        guess: np.ndarray,
        ref: float,
        p: np.ndarray,
        d_in: float = 0.0,
        d_out: float = 0.0,
    ) -> tuple[np.ndarray, np.ndarray]:
        """``(x_s, u_s)`` [SI] for the reference ``ref``, parameters ``p`` and disturbances,
        from ``guess = [x; u]``.

        Raises
        ------
        SolverError
            If Newton does not converge in :data:`MAX_NEWTON` steps, meets a singular
            Jacobian or finds no descent (with the residual).
        """
        d = np.array([d_in, d_out], dtype=float)

        def fun(w):
            res, jac = self._newton(w, ref, p, d)
            return np.array(res).ravel(), np.array(jac)

        try:
            w = damped_newton(
                fun,
                guess,
                tol=0.0,
                max_iter=MAX_NEWTON,
                weights=lambda J: row_weights(J, self.scale),
                step_tol=1e-10 * self.scale,
            ).x
        except NewtonFailure as f:
            raise SolverError(
                f"target: no steady state with the output at {ref:.6g}: {f.why} after "
                f"{f.iterations} Newton steps (residual {f.residual:.3g})"
            ) from None
        return w[: self.nx], w[self.nx :]
