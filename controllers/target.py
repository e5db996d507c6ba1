"""Target calculation: the steady state ``(x_s, u_s)`` at which the tracked output equals
its reference, for given model parameters and disturbances, on the nonlinear model.

The unknowns ``w = [x_s; u_s]`` (one input moves one tracked output) solve the square
system ::

    f(x_s, u_s + d_in, p) = 0                 (nx equations: at rest)
    y(x_s, u_s + d_in, p) + d_out - r = 0     (the output on the reference)

with ``d_in`` a constant added to the command (an input disturbance [SI of the input])
and ``d_out`` a constant added to the measured output (an output disturbance [SI of the
output]). Newton's method with the exact Jacobian (one CasADi Function gives the residual
and the Jacobian), warm-started from the last target, stops when every step component is
below ``1e-10`` of the state's scale. The linear MPC linearises at this point
(:mod:`.lmpc`), so its model is the one of where the loop is going, at the load the
estimator found.
"""

from __future__ import annotations

import casadi as cs
import numpy as np

from sarcomere.dynamics.errors import ParameterError, SolverError
from sarcomere.dynamics.modeling.model import Model

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
            If Newton does not converge in :data:`MAX_NEWTON` steps, or meets a singular
            Jacobian (with the residual).
        """
        w = np.asarray(guess, dtype=float).copy()
        d = np.array([d_in, d_out], dtype=float)
        for _ in range(MAX_NEWTON):
            res, jac = self._newton(w, ref, p, d)
            try:
                step = np.linalg.solve(np.array(jac), -np.array(res).ravel())
            except np.linalg.LinAlgError:
                break
            w += step
            if not np.all(np.isfinite(w)):
                break
            if np.all(np.abs(step) <= 1e-10 * self.scale):
                return w[: self.nx], w[self.nx :]
        raise SolverError(
            f"target: no steady state with the output at {ref:.6g} after {MAX_NEWTON} Newton "
            f"steps (residual {np.max(np.abs(np.array(res))):.3g})"
        )
