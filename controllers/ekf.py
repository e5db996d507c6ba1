"""An extended Kalman filter on the model's own CasADi Functions, for the realistic case
where only a few signals (the length and the regulator pressure) are measured, with noise.

Prediction over one sample ``dt`` with the input held: ``substeps`` steps of the
simulator's implicit Radau IIA step Function (L-stable, so the stiff pressure modes cost
nothing), and its exact Jacobian ``F = d x+ / d x`` by CasADi (through the implicit
step). Measurement: the named signals as functions of the state, Jacobian ``H`` exact.
Process noise enters where disturbances do: the input (``input_std``, an unknown
pressure error) and the parameters of ``disturbance_std`` (by default the load mass, for
an added weight), ``Q = dt G diag(std^2) G^T`` with ``G`` the exact ``df/d(u, p)`` at the
operating point. The covariance update is the Joseph form (stays symmetric positive
definite).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import casadi as cs
import numpy as np

from sarcomere.dynamics.equilibrium import Equilibrium
from sarcomere.dynamics.errors import ParameterError
from sarcomere.dynamics.modeling.model import Model
from sarcomere.dynamics.simulation.settings import SolverSettings
from sarcomere.dynamics.simulation.simulator import Simulator

from .registry import own_settings, positive

DEFAULT_STD = {"m": 2e-5, "Pa": 200.0, "N": 2e-3}
"""Measurement noise standard deviation by unit when the loop gives none [SI]."""


class EKF:
    """Extended Kalman filter (see the module docstring).

    Parameters
    ----------
    model : Model
        An explicit model (no algebraic unknowns).
    op : Equilibrium
        The operating point (parameters, start estimate, noise directions).
    dt : float
        Sample time [s].
    measured : sequence of str
        Measured signals.
    noise_std : mapping of str to float
        Measurement noise standard deviation of each measured signal [SI], > 0.
    input_std : float
        Process noise on the input [SI of the input], >= 0.
    disturbance_std : mapping of str to float
        Process noise on parameters [SI], e.g. ``{"load.m": 0.02}``.
    substeps : int
        Radau IIA steps per sample.
    """

    def __init__(
        self,
        model: Model,
        op: Equilibrium,
        dt: float,
        measured: Sequence[str],
        noise_std: Mapping[str, float],
        input_std: float = 2e3,
        disturbance_std: Mapping[str, float] | None = None,
        substeps: int = 2,
    ) -> None:
        if model.nz:
            raise ParameterError("ekf.model", model.name, "an explicit model (no algebraic)")
        if isinstance(substeps, bool) or not isinstance(substeps, int) or substeps < 1:
            raise ParameterError("ekf.substeps", substeps, "an integer >= 1")
        self.model, self.dt, self.p = model, float(dt), op.p.copy()
        self.measured = list(measured)
        unknown = [n for n in self.measured if n not in model.signal_names]
        if unknown or not self.measured:
            raise ParameterError("ekf.measured", unknown or measured, "signals of the model")
        std = np.array([positive("ekf", f"noise_std.{n}", noise_std[n]) for n in self.measured])
        self.R = np.diag(std**2)
        self.x0 = op.x.copy()
        x, u, p = (
            cs.MX.sym("x", model.nx),
            cs.MX.sym("u", model.u.numel()),
            cs.MX.sym("p", model.p.numel()),
        )
        settings = SolverSettings(method="radau_fixed", step=dt / substeps)
        step = Simulator(model, settings).step_function()
        xf = x
        for _ in range(substeps):
            xf = step(xf, cs.MX(0, 1), u, dt / substeps, p)[0]
        self._predict = cs.Function("ekf_predict", [x, u, p], [xf, cs.jacobian(xf, x)])
        ys = model.signals_function(self.measured)(model.x, cs.SX(0, 1), model.u, model.p)
        self._measure = cs.Function(
            "ekf_measure", [model.x, model.u, model.p], [ys, cs.jacobian(ys, model.x)]
        )
        # process noise: dt G diag(std^2) G^T, G = df/d[u, p_j] at the operating point
        dist = dict(disturbance_std or {})
        bad = [n for n in dist if n not in model.param_names]
        if bad:
            raise ParameterError("ekf.disturbance_std", bad, "parameters of the model")
        p_dist = cs.vertcat(cs.SX(0, 1), *[model.p[model.param_names.index(n)] for n in dist])
        G = np.hstack(
            [
                np.array(cs.Function("g", [model.x, model.u, model.p], [J])(op.x, op.u, op.p))
                for J in (cs.jacobian(model.ode, model.u), cs.jacobian(model.ode, p_dist))
            ]
        )
        s = np.array(
            [positive("ekf", "input_std", input_std, allow_zero=True)] * model.u.numel()
            + [positive("ekf", f"disturbance_std.{n}", v) for n, v in dist.items()]
        )
        self.Q = self.dt * (G * s**2) @ G.T + np.diag(np.full(model.nx, 1e-30))
        self.reset(op.x)

    def reset(self, x0: np.ndarray) -> None:
        """Restart at ``x0`` with the steady-state-free initial covariance ``10 Q``."""
        self.x = np.array(x0, dtype=float)
        self.P = 10.0 * self.Q

    def estimate(self, y: Mapping[str, float], u_last: float | np.ndarray) -> np.ndarray:
        """Predict over the last sample (input ``u_last`` held), correct with ``y``;
        returns the new state estimate."""
        u = np.atleast_1d(np.asarray(u_last, dtype=float))
        xf, F = self._predict(self.x, u, self.p)
        x = np.array(xf, dtype=float).ravel()
        F = np.array(F, dtype=float)
        P = F @ self.P @ F.T + self.Q
        h, H = self._measure(x, u, self.p)
        H = np.array(H, dtype=float)
        innov = np.array([y[n] for n in self.measured]) - np.array(h, dtype=float).ravel()
        S = H @ P @ H.T + self.R
        K = np.linalg.solve(S, H @ P).T
        self.x = x + K @ innov
        IKH = np.eye(len(x)) - K @ H
        self.P = IKH @ P @ IKH.T + K @ self.R @ K.T
        return self.x.copy()


def make_ekf(
    model: Model,
    op: Equilibrium,
    dt: float,
    measured: Sequence[str],
    noise_std: Mapping[str, float] | None,
    settings: Mapping[str, object],
) -> EKF:
    """An EKF from the loop's ``measured`` and ``noise_std`` (default :data:`DEFAULT_STD`
    by unit) and its own ``settings``:
    ``input_std`` [SI], ``disturbance_std`` (parameter -> std; default 20 g on
    ``load.m`` where the model has one) and ``substeps``."""
    if not isinstance(settings, Mapping):
        raise ParameterError("ekf", settings, "a table of EKF settings")
    dist = {"load.m": 0.02} if "load.m" in model.param_names else {}
    own = own_settings("ekf", settings, {"input_std": 2e3, "disturbance_std": dist, "substeps": 2})
    meas = list(measured)
    given = dict(noise_std or {})
    std = {n: given.get(n) or DEFAULT_STD.get(model.unit(n), 1e-6) for n in meas}
    return EKF(model, op, dt, meas, std, own["input_std"], own["disturbance_std"], own["substeps"])
