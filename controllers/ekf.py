"""An extended Kalman filter on the model's own CasADi Functions, for the realistic case
where only a few signals (the length and the regulator pressure) are measured, with noise.

Prediction over one sample ``dt`` with the input held: ``substeps`` steps of the
simulator's implicit Radau IIA step Function (L-stable, so the stiff pressure modes cost
nothing), and its exact Jacobian ``F = d x+ / d x`` by CasADi (through the implicit
step). Measurement: the named signals as functions of the state, Jacobian ``H`` exact.
Process noise enters where disturbances do: the input (``input_std``, an unknown
pressure error: ``dt std^2 B B^T`` with ``B`` the exact ``df/du`` at the operating point),
and the parameters of ``disturbance_std`` (by default the load mass, for an added weight),
which are appended to the state as random walks: the filter estimates them
(:attr:`EKF.parameters`, kept inside the parameters' ranges), so a persistent unknown
load does not bias the state. Two disturbances that are not parameters of the model can
be estimated the same way (:data:`OFFSETS`): ``"disturbance.input"``, a constant added to
the input [SI of the input], and ``"disturbance.output"``, a constant added to the tracked
output as measured [SI of the output] (the MPCs' input and output disturbance models,
:mod:`.disturbance`). The covariance update is the Joseph form (stays symmetric positive
definite).

The prediction is an ODE step: a model with algebraic unknowns (the "static_chain" level,
:data:`DAE_LEVELS`) is refused, naming the level and the levels allowed.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import casadi as cs
import numpy as np

from sarcomere.dynamics.assemblies import FIDELITIES
from sarcomere.dynamics.components.chains import CHAIN_LEVELS
from sarcomere.dynamics.equilibrium import Equilibrium
from sarcomere.dynamics.errors import ParameterError
from sarcomere.dynamics.modeling.model import Model
from sarcomere.dynamics.simulation.settings import SolverSettings
from sarcomere.dynamics.simulation.simulator import Simulator

from .registry import count, own_settings, positive

DEFAULT_STD = {"m": 2e-5, "Pa": 200.0, "N": 2e-3}
"""Measurement noise standard deviation by unit when the loop gives none [SI]."""


OFFSETS = ("disturbance.input", "disturbance.output")
"""Disturbances the EKF estimates that are not model parameters: a constant added to the
(one) input, and one added to the tracked output as measured."""

DAE_LEVELS = tuple(level for level, (_, massless) in CHAIN_LEVELS.items() if massless)
"""Fidelity levels whose models have algebraic unknowns (massless bodies: their positions
are algebraic), which the EKF refuses."""

MAX_SUBSTEPS = 50
"""Most Radau IIA steps per sample: each is unrolled into the prediction's CasADi graph
(its size and build time grow linearly). The step is L-stable, so substeps only buy
accuracy on the slow modes: the default 2 gives a 5 ms step at 10 ms sampling, and 50 a
0.2 ms step, below the chamber pressures' 0.4 ms time constant."""


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
        Random-walk intensity of the parameters (or :data:`OFFSETS`) estimated with the
        state [SI/sqrt(s)], e.g. ``{"load.m": 0.002}``.
    substeps : int
        Radau IIA steps per sample, in ``[1, MAX_SUBSTEPS]``.
    output : str, optional
        The tracked output, a measured signal (``"disturbance.output"`` is added to it;
        default: the first measured signal).
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
        output: str | None = None,
    ) -> None:
        if model.nz:
            refuse_dae(model)
        count("ekf.substeps", substeps, 1, MAX_SUBSTEPS, "each substep is unrolled in the graph")
        self.model, self.dt, self.p = model, float(dt), op.p.copy()
        self.measured = list(measured)
        unknown = [n for n in self.measured if n not in model.signal_names]
        if unknown or not self.measured:
            raise ParameterError("ekf.measured", unknown or measured, "signals of the model")
        std = np.array([positive("ekf", f"noise_std.{n}", noise_std[n]) for n in self.measured])
        self.R = np.diag(std**2)
        dist = dict(disturbance_std or {})
        bad = [n for n in dist if n not in (*model.param_names, *OFFSETS)]
        if bad:
            raise ParameterError(
                "ekf.disturbance_std", bad, f"parameters of the model or {OFFSETS}"
            )
        if OFFSETS[0] in dist and model.u.numel() != 1:
            raise ParameterError("ekf.disturbance_std", OFFSETS[0], "a model with one input")
        self.output = self.measured[0] if output is None else output
        if self.output not in self.measured:
            raise ParameterError("ekf.output", self.output, f"one of {self.measured}")
        self.disturbances = list(dist)
        nx, nd = model.nx, len(dist)
        # augmented state [x; d]: d, the disturbance parameters and offsets, walk at random
        x, d = cs.MX.sym("x", nx), cs.MX.sym("d", nd)
        u, p = cs.MX.sym("u", model.u.numel()), cs.MX.sym("p", model.p.numel())
        parts = cs.vertsplit(p)
        offset = dict.fromkeys(OFFSETS, cs.MX(0))
        for k, name in enumerate(dist):
            if name in OFFSETS:
                offset[name] = d[k]
            else:
                parts[model.param_names.index(name)] = d[k]
        pd, ud = cs.vertcat(*parts), u + offset[OFFSETS[0]]
        settings = SolverSettings(method="radau_fixed", step=dt / substeps)
        step = Simulator(model, settings).step_function()
        xf = x
        for _ in range(substeps):
            xf = step(xf, cs.MX(0, 1), ud, dt / substeps, pd)[0]
        xa, xaf = cs.vertcat(x, d), cs.vertcat(xf, d)
        self._predict = cs.Function("ekf_predict", [xa, u, p], [xaf, cs.jacobian(xaf, xa)])
        sig = model.signals_function(self.measured)
        at = np.array([n == self.output for n in self.measured], dtype=float)
        ys = sig(x, cs.MX(0, 1), ud, pd) + cs.DM(at) * offset[OFFSETS[1]]
        self._measure = cs.Function("ekf_measure", [xa, u, p], [ys, cs.jacobian(ys, xa)])
        # process noise: dt Gu std_u^2 Gu^T on x (Gu = df/du at the operating point) and
        # a random walk dt std_j^2 on each disturbance parameter
        Gu = np.array(
            cs.Function("gu", [model.x, model.u, model.p], [cs.jacobian(model.ode, model.u)])(
                op.x, op.u, op.p
            )
        )
        su = positive("ekf", "input_std", input_std, allow_zero=True)
        sd = np.array([positive("ekf", f"disturbance_std.{n}", v) for n, v in dist.items()])
        self.Q = np.zeros((nx + nd, nx + nd))
        self.Q[:nx, :nx] = self.dt * su**2 * Gu @ Gu.T + np.diag(np.full(nx, 1e-30))
        self.Q[nx:, nx:] = self.dt * np.diag(sd**2)
        var = {n: model.variables[n] for n in dist if n not in OFFSETS}
        self.d0 = np.array([op.p[model.param_names.index(n)] if n in var else 0.0 for n in dist])
        self.d_low = np.array([var[n].low if n in var else -np.inf for n in dist])
        self.d_high = np.array([var[n].high if n in var else np.inf for n in dist])
        self.reset(op.x)

    def reset(self, x0: np.ndarray) -> None:
        """Restart at ``x0`` (the disturbance parameters at the operating point's values)
        with the initial covariance ``10 Q``."""
        self.xa = np.concatenate([np.asarray(x0, dtype=float), self.d0])
        self.P = 10.0 * self.Q

    @property
    def parameters(self) -> dict[str, float]:
        """The current estimates of the disturbance parameters [SI], by name."""
        return dict(zip(self.disturbances, self.xa[self.model.nx :].tolist(), strict=True))

    def estimate(self, y: Mapping[str, float], u_last: float | np.ndarray) -> np.ndarray:
        """Predict over the last sample (input ``u_last`` held), correct with ``y``;
        returns the new state estimate (the model's states, without the disturbances)."""
        u = np.atleast_1d(np.asarray(u_last, dtype=float))
        xf, F = self._predict(self.xa, u, self.p)
        xa = np.array(xf, dtype=float).ravel()
        F = np.array(F, dtype=float)
        P = F @ self.P @ F.T + self.Q
        h, H = self._measure(xa, u, self.p)
        H = np.array(H, dtype=float)
        innov = np.array([y[n] for n in self.measured]) - np.array(h, dtype=float).ravel()
        S = H @ P @ H.T + self.R
        K = np.linalg.solve(S, H @ P).T
        self.xa = xa + K @ innov
        nx = self.model.nx
        self.xa[nx:] = np.clip(self.xa[nx:], self.d_low, self.d_high)
        IKH = np.eye(len(xa)) - K @ H
        self.P = IKH @ P @ IKH.T + K @ self.R @ K.T
        return self.xa[:nx].copy()


def make_ekf(
    model: Model,
    op: Equilibrium,
    dt: float,
    measured: Sequence[str],
    noise_std: Mapping[str, float] | None,
    settings: Mapping[str, object],
    output: str | None = None,
) -> EKF:
    """An EKF from the loop's ``measured`` and ``noise_std`` (default :data:`DEFAULT_STD`
    by unit) and its own ``settings``:
    ``input_std`` [SI], ``disturbance_std`` (parameter or :data:`OFFSETS` name ->
    random-walk intensity [SI/sqrt(s)]; default 2 g/sqrt(s) on ``load.m`` where the model
    has one: a 30 g step is found within 6 samples and the length is filtered to half the
    noise; 20 g/sqrt(s) finds it in 3 but hardly filters) and ``substeps``. ``output``:
    the tracked output (default the first measured signal)."""
    if not isinstance(settings, Mapping):
        raise ParameterError("ekf", settings, "a table of EKF settings")
    dist = default_disturbances(model)
    own = own_settings("ekf", settings, {"input_std": 2e3, "disturbance_std": dist, "substeps": 2})
    meas = list(measured)
    given = dict(noise_std or {})
    std = {n: given.get(n) or DEFAULT_STD.get(model.unit(n), 1e-6) for n in meas}
    dist_std, substeps = own["disturbance_std"], own["substeps"]
    return EKF(model, op, dt, meas, std, own["input_std"], dist_std, substeps, output)


def measured_signals(slug: str, settings: Mapping[str, object], output: str) -> list[str]:
    """The signals a controller's EKF reads: ``settings["measured"]``, by default the
    tracked ``output`` and ``regulator.p_out``; an empty list is refused (a mistake, not a
    request for the default)."""
    measured = settings.get("measured")
    if measured is None:
        return [output, "regulator.p_out"]
    if not measured:
        raise ParameterError(f"{slug}.measured", measured, "at least one signal for the EKF")
    return list(measured)


def default_disturbances(model: Model) -> dict[str, float]:
    """The parameters :func:`make_ekf` estimates unless told otherwise, with their
    random-walk intensity [SI/sqrt(s)]: the load mass (2 g/sqrt(s)) where the model has one."""
    return {"load.m": 0.002} if "load.m" in model.param_names else {}


def estimated_parameters(model: Model, settings: Mapping[str, object]) -> list[str]:
    """Names of the parameters :func:`make_ekf` estimates with these ``settings``."""
    dist = settings.get("disturbance_std") if isinstance(settings, Mapping) else None
    return list(dist) if isinstance(dist, Mapping) else list(default_disturbances(model))


def refuse_dae(model: Model) -> None:
    """Raise the EKF's refusal of a model with algebraic unknowns, naming its fidelity
    level (where an assembly recorded it) and the levels allowed."""
    setup = getattr(model, "setup", None)
    level = setup.arguments.get("fidelity") if setup is not None else None
    allowed = [f for f in FIDELITIES if f not in DAE_LEVELS]
    raise ParameterError(
        "ekf.fidelity" if level else "ekf.model",
        level or model.name,
        f"a level without algebraic unknowns: one of {allowed}",
        f"the EKF predicts with an ODE step; {model.name} has {model.nz} algebraic "
        "unknowns (massless bodies)",
    )
