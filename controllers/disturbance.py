"""Disturbance models of the MPCs, and the linear MPC's Kalman filter of one.

A constant disturbance the prediction does not know leaves an offset or, in the linear
MPC's velocity form (offset-free by construction), a model of the wrong plant (after the
+50 g step the 20 g model's load mode is 1.9x too fast and the loop rings at 3 Hz). Each
model names one constant the estimator finds and the prediction uses:

- ``"load"``: the load mass ``load.m`` [kg], a parameter of the model;
- ``"input"``: a constant added to the regulator command in the prediction [Pa];
- ``"output"``: a constant added to the tracked output [SI of the output];
- ``"none"``: no disturbance estimate.

The nonlinear MPC gets them from the EKF (:mod:`.ekf`, augmented states) as run-time
parameters of its prediction. The linear MPC, on the states it reads, runs
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
"""

from __future__ import annotations

import numpy as np

from sarcomere.dynamics.errors import ParameterError

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
