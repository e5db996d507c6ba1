"""Disturbance models of the MPCs, and the linear MPC's Kalman filter of one.

A constant disturbance the prediction does not know leaves an offset or, in the linear
MPC's velocity form (offset-free by construction), a model of the wrong plant (after the
+50 g step the 20 g model's load mode is 1.9x too fast and the loop rings at 3 Hz). Each
model names one constant the estimator finds and the prediction uses:

- ``"load"``: the load mass ``load.m`` [kg], a parameter of the model;
- ``"input"``: a constant added to the regulator command in the prediction [Pa];
- ``"output"``: a constant added to the tracked output [SI of the output];
- ``"none"``: no disturbance estimate.

The nonlinear MPC gets them as run-time parameters of its prediction, from the EKF
(:mod:`.ekf`, augmented states) or, on the states it reads, from its own
:class:`StateDisturbanceFilter` (below). The linear MPC, on the states it reads, runs
:class:`DisturbanceFilter`: a Kalman filter of the one constant on its linearisation.
Because every state is read, the filter reduces to a scalar random walk observed through
the one-step prediction residual ::

    e_k = [x_k - x_l - Ad (x_{k-1} - x_l) - Bd (u_{k-1} - u_l) - c;  y_k - y_l - C (x_k - x_l)]
        = E d + v_k,     v_k ~ N(0, S)

with ``c`` the drift of the linearisation point (zero at a steady state), ``E`` the
disturbance's discretised direction (``load``: ``d f / d m`` through the zero-order hold,
and ``d y / d m``; ``input``: ``Bd`` and ``D``; ``output``: zero and 1) and ``S`` the
process noise of the input (``dt std_u^2 Bd Bd^T``), a floor of ``(1e-6 scale)^2`` on
each state and the output's noise variance. The estimate is relative to the
linearisation's value; it restarts at 0 (keeping its variance) when the model is
re-linearised there. The linear MPC keeps the total inside a range (the load's; the
input's range either side of 0; the reachable output span either side of 0).
:class:`StateDisturbanceFilter` is the same filter linearised afresh at every sample
(at the last state and input, at the present estimate), for the nonlinear MPC, whose
prediction has no fixed linearisation; it keeps the same ranges.
"""

from __future__ import annotations

import casadi as cs
import numpy as np

from sarcomere.dynamics.errors import ParameterError
from sarcomere.dynamics.modeling.model import Model

from .qp import zoh

DISTURBANCES = ("load", "input", "output", "none")
"""The disturbance models (module docstring)."""

RANDOM_WALK = {"load": 0.002, "input": 2.0e3, "output": 1.0e-4}
"""Random-walk intensity of each disturbance [SI/sqrt(s)]: 2 g/sqrt(s) (the EKF's
default for the load), 2 kPa/sqrt(s), 0.1 mm/sqrt(s)."""


def check_disturbance(slug: str, value: object, params: list[str]) -> str:
    """``value`` if it is a disturbance model the model supports (``"load"`` needs a
    ``load.m`` parameter)."""
    if value not in DISTURBANCES:
        raise ParameterError(f"{slug}.disturbance", value, f"one of {DISTURBANCES}")
    if value == "load" and "load.m" not in params:
        raise ParameterError(
            f"{slug}.disturbance", value, "'input', 'output' or 'none' (no load.m here)"
        )
    return str(value)


def residual_noise(
    Bd: np.ndarray, input_std: float, x_floor: np.ndarray, y_std: float
) -> np.ndarray:
    """Covariance of one sample's residual of the states and the output [SI^2]: the
    input's noise ``input_std`` through the discretised input matrix ``Bd``, a floor
    ``x_floor`` on each state (keeps it invertible) and the output's noise ``y_std``."""
    nx = Bd.shape[0]
    S = np.zeros((nx + 1, nx + 1))
    S[:nx, :nx] = input_std**2 * Bd @ Bd.T + np.diag(np.asarray(x_floor, float) ** 2)
    S[nx, nx] = y_std**2
    return S


class DisturbanceFilter:
    """The Kalman filter of one constant disturbance on a linearisation (module docstring).

    Parameters
    ----------
    E : numpy.ndarray
        The disturbance's direction in the residual ``[x; y]`` (nx + 1).
    S : numpy.ndarray
        The residual's noise covariance ((nx + 1) x (nx + 1)).
    q : float
        The random walk's variance per sample [SI^2].
    variance : float
        The estimate's variance to start from [SI^2].
    """

    def __init__(self, E: np.ndarray, S: np.ndarray, q: float, variance: float) -> None:
        self.E, self.q = np.asarray(E, float), float(q)
        self._SE = np.linalg.solve(S, self.E)  # S^-1 E
        self._ESE = float(self.E @ self._SE)
        self.value, self.variance = 0.0, float(variance)

    def update(self, residual: np.ndarray) -> float:
        """Correct with the residual at ``d = 0`` (``e_k`` with the disturbance left out);
        returns the new estimate [SI]."""
        prior = self.variance + self.q
        innovation = residual - self.E * self.value
        # scalar state: K = P E^T (E P E^T + S)^-1 = P (S^-1 E)^T / (1 + P E^T S^-1 E)
        gain = prior * self._SE / (1.0 + prior * self._ESE)
        self.value += float(gain @ innovation)
        self.variance = prior / (1.0 + prior * self._ESE)
        return self.value


class StateDisturbanceFilter:
    """:class:`DisturbanceFilter` of one run-time parameter ``p[index]`` of a nonlinear
    model whose every state is read (the nonlinear MPC's): the residual is the one of the
    module docstring with the linearisation made afresh at every sample, at the last
    sample's state and input and the present estimate (so ``c`` is one sample's motion
    from there, the zero-order-hold step of the linearised model, and ``e_k`` is taken at
    the present estimate, not at 0); the variance is carried from sample to sample.

    Parameters
    ----------
    model : Model
        An explicit model with the tracked output.
    output : str
        The tracked signal.
    kind : str
        "load", "input" or "output" (:data:`DISTURBANCES`).
    dt : float
        Sample time [s].
    x_scale : numpy.ndarray
        The size of each state [SI]; the residual's floor is ``1e-6`` of it.
    input_std, output_std : float
        The input's noise [SI of the input] and the output's as read [SI].
    bounds : (float, float)
        The estimate's range [SI].

    The vector ``p`` of :meth:`update` is the model's parameters followed by the input
    and output disturbances (:attr:`~.receding.RecedingHorizon.runtime_parameters`):
    ``f(x, u + d_in, p)`` and ``y(x, u + d_in, p) + d_out``.
    """

    def __init__(
        self,
        model: Model,
        output: str,
        kind: str,
        dt: float,
        x_scale: np.ndarray,
        input_std: float,
        output_std: float,
        bounds: tuple[float, float],
    ) -> None:
        if kind not in RANDOM_WALK:
            raise ParameterError("disturbance", kind, f"one of {sorted(RANDOM_WALK)}")
        n_model, nx = model.p.numel(), model.nx
        self.index = {"load": model.param_names.index("load.m") if kind == "load" else 0,
                      "input": n_model, "output": n_model + 1}[kind]  # fmt: skip
        x0, x, u = cs.SX.sym("x0", nx), cs.SX.sym("x", nx), cs.SX.sym("u", len(model.input_names))
        p = cs.SX.sym("p", n_model + 2)
        pm, z = p[:n_model], cs.SX(0, 1)
        f = model.function("ode")(x0, z, u + p[n_model], pm)
        y = model.signals_function([output])(x, z, u + p[n_model], pm) + p[n_model + 1]
        d = p[self.index]
        outs = [cs.jacobian(f, x0), cs.jacobian(f, u), f, cs.jacobian(f, d), y, cs.jacobian(y, d)]
        self._lin = cs.Function("disturbance_lin", [x0, x, u, p], outs)
        self.dt, self.floor = float(dt), 1e-6 * np.asarray(x_scale, float)
        self.input_std, self.output_std = float(input_std), float(output_std)
        self.q = self.dt * RANDOM_WALK[kind] ** 2
        self.bounds = (float(bounds[0]), float(bounds[1]))
        self.reset()

    def reset(self) -> None:
        """Forget the last sample and start from the variance ``10 q``."""
        self._last: np.ndarray | None = None
        self.variance = 10 * self.q

    def update(self, x: np.ndarray, u_prev: np.ndarray, out: float, p: np.ndarray) -> float:
        """The estimate [SI] after reading the state ``x`` and the output ``out`` now, with
        ``u_prev`` held over the last sample and ``p`` the values predicted with (its entry
        ``index`` the present estimate, returned unchanged at the first sample)."""
        x = np.asarray(x, float)
        last, self._last = self._last, x.copy()
        if last is None:
            return float(p[self.index])
        A, B, f, f_d, y, y_d = (np.array(v, float) for v in self._lin(last, x, u_prev, p))
        nx, nu = B.shape
        _, G = zoh(A, np.hstack([B, f, f_d]), self.dt)
        Bd, drift, E_x = G[:, :nu], G[:, nu], G[:, nu + 1]
        S = residual_noise(Bd, self.input_std, self.floor, self.output_std)
        residual = np.concatenate([x - last - drift, [out - float(y[0, 0])]])
        kalman = DisturbanceFilter(np.concatenate([E_x, y_d[0]]), S, self.q, self.variance)
        step = kalman.update(residual)
        self.variance = kalman.variance
        return float(np.clip(p[self.index] + step, *self.bounds))
