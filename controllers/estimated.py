"""A state-feedback controller run on an extended Kalman filter's estimate.

The MPCs read every state of their prediction model by name; in the realistic case only a
few signals are measured (the length and the regulator pressure, with noise). This wrapper
reads what is measured, updates the :class:`~.ekf.EKF` (on the plant model) with the input
it applied last, and hands the inner controller the estimated states, and its other
signals evaluated on the estimate, by name. The prediction models' state names are a
subset of the full plant's, so this works for every prediction fidelity. Parameters the EKF
estimates (by default the load mass), and its input and output offsets
(:data:`~.ekf.OFFSETS`), that the inner controller accepts
(:attr:`~.base.Controller.runtime_parameters`: the NMPC takes all, the LMPC its model's
parameters) are passed to it every sample through
:meth:`~.base.Controller.set_parameters`, before it computes its input. So is the standard
deviation of the estimate of each signal the inner controller names in
``uncertain_signals`` (the NMPC's bounded signals with a ``backoff``: it raises their
bounds by a multiple of it), as ``backoff.<signal>``: ``sqrt(J P J^T)`` with ``P`` the
EKF's covariance and ``J`` the signal's derivative by the estimated states and
parameters.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import casadi as cs
import numpy as np

from sarcomere.dynamics.equilibrium import Equilibrium
from sarcomere.dynamics.modeling.model import Model

from .base import Controller
from .ekf import EKF, OFFSETS


class OnEstimate(Controller):
    """``inner`` fed with ``ekf``'s estimate (see the module docstring).

    Parameters
    ----------
    inner : Controller
        A controller reading plant states (and signals of them) by name.
    ekf : EKF
        The estimator, on the plant model.
    plant : Model
        The plant model the EKF runs on.
    op : Equilibrium
        The operating point: the estimate restarts there on :meth:`reset`.
    """

    def __init__(self, inner: Controller, ekf: EKF, plant: Model, op: Equilibrium) -> None:
        super().__init__(inner.dt, inner.inputs, ekf.measured, inner.u_min, inner.u_max)
        self.slug = inner.slug
        self.inner, self.ekf, self.plant, self.op = inner, ekf, plant, op
        states = set(plant.state_names)
        self._derived = [n for n in inner.outputs if n not in states]
        self._signals = plant.signals_function(self._derived)
        accepted = set(inner.runtime_parameters)
        self.fed = [n for n in ekf.disturbances if n in accepted]  # passed to inner
        self._uncertain = list(getattr(inner, "uncertain_signals", []))
        if self._uncertain:  # the signals' derivatives by the EKF's augmented state
            x, u = cs.MX.sym("x", plant.nx), cs.MX.sym("u", plant.u.numel())
            p = cs.MX.sym("p", plant.p.numel())
            sig = plant.signals_function(self._uncertain)(x, cs.MX(0, 1), u, p)
            by = {OFFSETS[0]: cs.jacobian(sig, u), OFFSETS[1]: cs.MX(len(self._uncertain), 1)}
            Jp = cs.jacobian(sig, p)
            by.update({n: Jp[:, k] for k, n in enumerate(plant.param_names)})
            J = cs.horzcat(cs.jacobian(sig, x), *(by[n] for n in ekf.disturbances))
            self._spread = cs.Function("signal_jacobian", [x, u, p], [J])
        self.reset(dict(zip(plant.input_names, op.u.tolist(), strict=True)))

    def reset(self, u0: Mapping[str, float]) -> None:
        super().reset(u0)
        self.inner.reset(u0)
        self.ekf.reset(self.op.x)
        self._u = np.array([u0[n] for n in self.plant.input_names], dtype=float)

    @property
    def preview_samples(self) -> int:
        return self.inner.preview_samples

    def set_preview(self, values: Mapping[str, Sequence[float]]) -> None:
        self.inner.set_preview(values)

    def update(self, t: float, y: Mapping[str, float], r: Mapping[str, float]) -> dict:
        x = self.ekf.estimate(y, self._u)
        est = dict(zip(self.plant.state_names, x.tolist(), strict=True))
        values = np.array(self._signals(x, np.zeros(self.plant.nz), self._u, self.op.p))
        est.update(zip(self._derived, values.ravel().tolist(), strict=True))
        if self.fed:
            estimates = self.ekf.parameters
            self.inner.set_parameters({n: estimates[n] for n in self.fed})
        if self._uncertain:  # at the estimated state and parameters
            p = self.op.p.copy()
            for n, v in self.ekf.parameters.items():
                if n in self.plant.param_names:
                    p[self.plant.param_names.index(n)] = v
            J = np.array(self._spread(self.ekf.xa[: self.plant.nx], self._u, p))
            std = np.sqrt(np.maximum(np.einsum("ij,jk,ik->i", J, self.ekf.P, J), 0.0))
            self.inner.set_parameters(
                {f"backoff.{n}": float(s) for n, s in zip(self._uncertain, std, strict=True)}
            )
        u = self.inner.checked(t, est, r)
        self.stats.fallbacks = self.inner.stats.fallbacks
        self._u = np.array(
            [u.get(n, v) for n, v in zip(self.plant.input_names, self._u, strict=True)]
        )
        return u
