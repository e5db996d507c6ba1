"""Linear MPC: a condensed QP in velocity form on the exact, ZOH-discretised linearisation.

The prediction uses increments: the state ``xi = [dx_k; e_k]`` with ``dx_k = x_k - x_{k-1}``
(the measured states) and ``e_k = y_k - r`` (the tracked output minus its reference), the
decision variables are the input moves ``du_k``::

    dx_{k+1} = Ad dx_k + Bd du_k
    e_{k+1}  = e_k + C Ad dx_k + C Bd du_k

A constant disturbance or a model error shifts ``x`` and ``u`` but not the increments, so
the loop has integral action (offset-free) without an observer. The cost is
``sum_k q (y_k - r_k)^2 + r_du du_k^2`` over the horizon (``r_k`` the reference at node
``k``: the preview set by :meth:`~.receding.RecedingHorizon.set_preview` when the reference
is known ahead, else ``r(t)`` held; ``e_k - (r_k - r(t))`` in the increments); input
bounds and rate limits are hard (``du = 0`` always satisfies them, so the QP is always
feasible); lower bounds on other signals (``soft_min``, declared as the NMPC's:
:func:`~.receding.soft_bounds`; e.g. thread tension) are soft, with one slack per signal
(linear and quadratic penalty). The QP is condensed (only the moves and slacks are
unknowns) by :class:`VelocityQP` in numpy at each linearisation; one sample at a fixed
linearisation is one CasADi Function, :func:`velocity_law` (``(memory, x, u_prev, ref,
p) -> (memory_next, u, ok)``, the QP inside, the condensed matrices in ``p``):
:meth:`LinearMPC.update` evaluates it every sample (DAQP), and the controller FMU
generates its C code (DAQP linked statically from the CasADi wheel,
:func:`~.rti_compiled.daqp_build`; or qrqp, no library at all).

Outside the law, between samples: a Kalman filter of one constant disturbance on the
states read (:mod:`.disturbance`; ``disturbance = "load"`` by default: the load mass), and
re-linearisation. The model is re-linearised when the tracked output moved more than
``relinearize_m`` (2 mm), a state more than ``relinearize_x`` of its span over the input
range, or the input more than ``relinearize_u`` of its range from the point of the last
linearisation, or when a parameter (the filter's load, or one set at run time by
:meth:`~.receding.RecedingHorizon.set_parameters`, e.g. an EKF's) moved more than
``relinearize_rel`` (5 %) of its value there, or a disturbance past the input or output
threshold. The new point is the target (:class:`~.target.SteadyTarget`): the steady state
with the output on the reference at the present load and disturbances, so after +50 g
the model is the 70 g plant's where it is going (the 20 g model on the 70 g plant rang at
3 Hz in the control-length scene); where only the measurement left the point and the
target did not move, the measured point.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass

import casadi as cs
import numpy as np

from sarcomere.dynamics.equilibrium import Equilibrium
from sarcomere.dynamics.errors import ParameterError, SolverError
from sarcomere.dynamics.modeling.buffered import BufferedCall
from sarcomere.dynamics.modeling.model import Model

from .base import Controller
from .disturbance import (
    DISTURBANCES,
    RANDOM_WALK,
    DisturbanceFilter,
    check_disturbance,
    residual_noise,
)
from .ekf import DEFAULT_STD, estimated_parameters
from .qp import VelocityQP, velocity_law, zoh
from .receding import (
    RecedingHorizon,
    check_mpc_settings,
    mpc_settings,
    soft_bounds,
    with_estimator,
)
from .registry import positive, register_controller
from .target import SteadyTarget


@dataclass(frozen=True)
class LMPCSettings:
    """Settings of :class:`LinearMPC` (SI).

    Attributes
    ----------
    horizon : int
        Prediction and control horizon [samples].
    weight_y : float
        Weight of the squared tracking error [1/m^2].
    weight_du : float
        Weight of the squared input move per sample [1/Pa^2]. The default (a 1.8 kPa
        move costs as much as 1 mm of error; chosen by the tuning study
        ``benchmarks/studies/mpc_tuning.py``) keeps the loop stable when the
        plant carries 50 g more than the linearisation (at 1e-8 it cycles between 0.14
        and 0.3 MPa in the control-length scene).
    u_min, u_max : float
        Regulator command bounds [Pa gauge].
    rate_max : float
        Largest input rate [Pa/s]; a move per sample is at most ``rate_max * dt``.
    soft_min : tuple
        Soft lower bounds on signals, as the NMPC's (:func:`~.receding.soft_bounds`):
        entries ``(signal, bound)`` or ``(signal, bound, penalty)``, e.g.
        ``(("myofibril.actin1.T", 0.01),)`` [SI]; the signal a name or a pattern; the
        penalty finite (no hard bounds here: a hard bound could make the QP infeasible).
    soft_penalty : float
        Linear and quadratic penalty on a soft-bound violation [per unit of the signal],
        of the bounds declared without one.
    relinearize_m : float
        Re-linearise when the tracked output moved this far from the last point [m].
    relinearize_rel : float
        Re-linearise when a parameter (one set at run time, e.g. an estimated load) moved
        this fraction of its value at the last point [-] (default 5 %: 3.5 g of 70 g).
    relinearize_x : float
        Re-linearise when a state moved this fraction of its span over the input range
        (the difference of its values at the two ends, at the nominal parameters) from the
        last point [-] (default a quarter; states equal at both ends, the velocities, do
        not count: they are zero at every steady state).
    relinearize_u : float
        Re-linearise when an input moved this fraction of its range ``u_max - u_min``
        from the last point [-] (default a quarter).
    disturbance : str or None
        The disturbance model of the LMPC's own Kalman filter (:mod:`.disturbance`):
        "load", "input", "output" or "none"; None (default): "load" where the model has a
        ``load.m``, else "input".
    input_std, output_std : float or None
        The filter's noise: of the input [Pa] (default 2 kPa, the EKF's) and of the
        tracked output as read [SI] (None: :data:`~.ekf.DEFAULT_STD` of its unit).
    output : str
        The tracked signal.
    qp_solver : str
        The QP solver :meth:`LinearMPC.update` evaluates the law with: "daqp" (default),
        "qpoases" or "qrqp" (see :data:`~.qp.QP_SOLVERS`: DAQP and qrqp generate C code).
    """

    horizon: int = 20
    weight_y: float = 1.0e6
    weight_du: float = 3.0e-7
    u_min: float = 0.0
    u_max: float = 1.0e5
    rate_max: float = 2.0e6
    soft_min: tuple = ()
    soft_penalty: float = 1.0e4
    relinearize_m: float = 2.0e-3
    relinearize_rel: float = 0.05
    relinearize_x: float = 0.25
    relinearize_u: float = 0.25
    disturbance: str | None = None
    input_std: float = 2.0e3
    output_std: float | None = None
    output: str = "myofibril.length"
    qp_solver: str = "daqp"

    def __post_init__(self) -> None:
        check_mpc_settings("lmpc", self)
        if any(len(b) == 3 and not math.isfinite(b[2]) for b in self.soft_min):
            raise ParameterError("lmpc.soft_min", self.soft_min, "finite penalties (soft)")
        positive("lmpc", "relinearize_m", self.relinearize_m)
        positive("lmpc", "relinearize_rel", self.relinearize_rel)
        positive("lmpc", "relinearize_x", self.relinearize_x)
        positive("lmpc", "relinearize_u", self.relinearize_u)
        if self.disturbance is not None and self.disturbance not in DISTURBANCES:
            raise ParameterError("lmpc.disturbance", self.disturbance, f"one of {DISTURBANCES}")


class LinearMPC(RecedingHorizon):
    """Linear MPC of the tracked output (see the module docstring) by the regulator command.

    Reads every state of ``model``, the tracked output and the softly bounded signals by
    name (state feedback: the plant's signals of the same names, or an estimator's), and
    the reference of the tracked output.

    Parameters
    ----------
    model : Model
        The prediction model (its states must be signals the loop can measure).
    x_op, u_op : numpy.ndarray
        The first linearisation point (an equilibrium).
    dt : float
        Sample time [s].
    settings : LMPCSettings, optional
    params : mapping of str to float, optional
        Parameter overrides of ``model`` by name (SI), e.g. the plant's load.

    Attributes
    ----------
    disturbance : str
        The model of its own disturbance filter ("load", "input", "output", "none").
    relinearizations : int
        Linearisations since the last reset (the first at ``(x_op, u_op)``).
    targets_missed : int
        Re-linearisations where the target had no solution (at the measured point).

    Examples
    --------
    >>> from sarcomere.dynamics import hanging_load, solve_equilibrium
    >>> m = hanging_load(1, load_kg=0.02)
    >>> eq = solve_equilibrium(m, {"regulator.p_cmd": 5e4})
    >>> mpc = LinearMPC(m, eq.x, eq.u, 0.01)
    >>> y = {n: eq[n] for n in mpc.outputs}
    >>> u = mpc.checked(0.0, y, {"myofibril.length": eq["myofibril.length"]})
    >>> round(u["regulator.p_cmd"])
    50000
    """

    slug = "lmpc"

    def __init__(
        self,
        model: Model,
        x_op: np.ndarray,
        u_op: np.ndarray,
        dt: float,
        settings: LMPCSettings | None = None,
        params: Mapping[str, float] | None = None,
    ) -> None:
        s = settings or LMPCSettings()
        names = model.input_names
        self.bounds = soft_bounds("lmpc", model, s.soft_min, s.soft_penalty)
        self._soft = [name for name, _, _ in self.bounds]
        reads = list(dict.fromkeys([*model.state_names, s.output, *self._soft]))
        super().__init__(model, dt, s, reads, params)
        self._soft_min = np.array([low for _, low, _ in self.bounds])
        self._penalty = np.array([w for _, _, w in self.bounds])
        self._lin = model.linearization([s.output, *self._soft])
        self._du_max = np.full(len(names), s.rate_max * self.dt)
        self._u_scale = self._u_hi - self._u_lo
        self._law = BufferedCall(self.law_function())
        if model.nz:
            raise ParameterError("lmpc.model", model.name, "an explicit model (no algebraic)")
        kind = s.disturbance or ("load" if "load.m" in model.param_names else "input")
        self.disturbance = check_disturbance("lmpc", kind, model.param_names)
        ends = np.vstack([e.x for e in self.clip.ends])
        big = np.abs(ends).max(axis=0)
        big = np.where(big > 1e-12, big, 1e-2)  # velocities (zero at rest): 1 cm/s
        self._x_span = np.abs(ends[1] - ends[0])
        self._x_moves = self._x_span > 1e-6 * big  # not the velocities
        scale = np.concatenate([big, self._u_scale])
        self._target = SteadyTarget(model, s.output, scale)
        self._x_floor = 1e-6 * scale[: model.nx]
        self._y_std = s.output_std or DEFAULT_STD.get(model.unit(s.output), 1e-6)
        z = cs.SX(0, 1)
        fy = cs.vertcat(
            model.function("ode")(model.x, z, model.u, model.p),
            model.signals_function([s.output])(model.x, z, model.u, model.p),
        )
        k_m = model.param_names.index("load.m") if "load.m" in model.param_names else 0
        self._k_m = k_m
        # the range of the estimate: the load's, +-the input range, +-the reachable span
        if self.disturbance == "load":
            var = model.variables["load.m"]
            self._d_range = (var.low, var.high)
        elif self.disturbance == "input":
            self._d_range = (-self._u_scale[0], self._u_scale[0])
        else:
            span = self.clip.high - self.clip.low
            self._d_range = (-span, span)
        self._fy = cs.Function(
            "fy", [model.x, model.u, model.p], [fy, cs.jacobian(fy, model.p)[:, k_m]]
        )
        self._op = (np.asarray(x_op, float).copy(), np.asarray(u_op, float).copy())
        self.reset(u_op)

    def law_function(self, solver: str | None = None) -> cs.Function:
        """The law of one sample at a fixed linearisation, :func:`velocity_law` for this
        controller's sizes: :meth:`update` evaluates it every sample with
        ``settings.qp_solver`` (after re-linearising when due, which only changes
        :meth:`law_parameters`); the controller FMU generates C code from it (DAQP:
        compile with :func:`~.rti_compiled.daqp_build`; qrqp: no library, slower with
        soft bounds)."""
        s = self.settings
        return velocity_law(
            self.model.nx, len(self.inputs), len(self._soft), s.horizon, solver or s.qp_solver
        )

    def law_parameters(self) -> np.ndarray:
        """The ``p`` of :meth:`law_function` at the present linearisation: the condensed
        QP (:meth:`VelocityQP.data`), the input bounds, the largest move per sample and the
        soft lower bounds [SI]."""
        return np.concatenate(
            [self._qp.data(), self._u_lo, self._u_hi, self._du_max, self._soft_min]
        )

    @property
    def memory(self) -> np.ndarray:
        """The ``memory`` of :meth:`law_function` now (see :func:`velocity_law`)."""
        return self._memory.copy()

    def _linearize(self, x: np.ndarray, u: np.ndarray) -> VelocityQP:
        """The QP of the model linearised at ``(x, u)`` with the present parameters and
        disturbances; the disturbance filter restarts there (its variance kept)."""
        s, nx = self.settings, self.model.nx
        d_in, d_out = self._d
        ue = u + d_in
        A, B, C, D = (np.array(M) for M in self._lin(x, np.zeros(0), ue, self._p))
        Ad, Bd = zoh(A, B, self.dt)
        fy, fy_m = (np.array(v, dtype=float).ravel() for v in self._fy(x, ue, self._p))
        _, drift = zoh(A, fy[:nx, None], self.dt)  # one sample's motion of the point itself
        qp = VelocityQP(
            Ad, Bd, C[:1], C[1:], s.horizon, s.weight_y, s.weight_du, self._penalty,
            self._u_scale,
        )  # fmt: skip
        self._y_lin, self._p_lin, self._d_lin = (
            float(fy[nx]) + d_out,
            self._p.copy(),
            self._d.copy(),
        )
        self._lin_point = (x.copy(), u.copy(), self._y_lin)
        self._drift, self._D = drift[:, 0], D[0]
        self.relinearizations += 1
        self._p_law = None  # rebuilt by law_parameters() on the next update
        if self.disturbance == "none":
            return qp
        if self.disturbance == "load":
            _, Ed = zoh(A, fy_m[:nx, None], self.dt)
            E = np.concatenate([Ed[:, 0], fy_m[nx:]])
        elif self.disturbance == "input":
            E = np.concatenate([Bd[:, 0], D[0]])
        else:
            E = np.concatenate([np.zeros(nx), [1.0]])
        S = residual_noise(Bd, s.input_std, self._x_floor, self._y_std)
        q = self.dt * RANDOM_WALK[self.disturbance] ** 2
        variance = 10 * q if self._filter is None else self._filter.variance
        self._filter = DisturbanceFilter(E, S, q, variance)
        return qp

    @property
    def disturbance_estimate(self) -> float:
        """The estimated disturbance now [SI]: the load mass [kg], the input offset [Pa],
        the output offset [SI], or 0 for ``"none"``."""
        if self.disturbance == "load":
            return float(self._p[self._k_m])
        return float(self._d[0] if self.disturbance == "input" else self._d[1])

    def _estimate(self, x: np.ndarray, out: float) -> None:
        """Correct the disturbance filter with this sample's residual (module docstring of
        :mod:`.disturbance`) and move the disturbance the prediction uses."""
        nx, qp = self.model.nx, self._qp
        x_l, u_l, y_l = self._lin_point
        du = self._u - u_l
        e_x = x - x_l - qp.Ad @ (self._memory[:nx] - x_l) - qp.Bd @ du - self._drift
        e_y = out - y_l - qp.C[0] @ (x - x_l) - self._D @ du
        d = self._filter.update(np.concatenate([e_x, [e_y]]))
        if self.disturbance == "load":
            base = self._p_lin[self._k_m]
        else:
            k = 0 if self.disturbance == "input" else 1
            base = self._d_lin[k]
        value = float(np.clip(base + d, *self._d_range))
        self._filter.value = value - base  # kept inside its range, like the EKF's
        if self.disturbance == "load":
            self._p[self._k_m] = value
        else:
            self._d[k] = value

    def _far(self, x: np.ndarray, u: np.ndarray, y: float) -> bool:
        """Whether ``(x, u, y)`` is past a threshold from the linearisation point: the
        output, a state (of its span) or the input (of its range); see
        :class:`LMPCSettings`."""
        s = self.settings
        x_l, u_l, y_l = self._lin_point
        moved = np.abs(x - x_l)[self._x_moves] > s.relinearize_x * self._x_span[self._x_moves]
        return bool(
            abs(y - y_l) > s.relinearize_m
            or np.any(moved)
            or np.any(np.abs(u - u_l) > s.relinearize_u * self._u_scale)
        )

    def _moved(self) -> bool:
        """Whether a parameter or a disturbance moved past its threshold from the values
        at the linearisation (:class:`LMPCSettings`)."""
        s = self.settings
        dd = np.abs(self._d - self._d_lin)
        return bool(
            np.any(np.abs(self._p - self._p_lin) > s.relinearize_rel * np.abs(self._p_lin))
            or dd[0] > s.relinearize_u * self._u_scale[0]
            or dd[1] > s.relinearize_m
        )

    def _relinearize(self, x: np.ndarray, ref: float, moved: bool) -> None:
        """Linearise at the target: the steady state with the output on ``ref`` at the
        present parameters and disturbances (:class:`~.target.SteadyTarget`). Where these
        did not move (``moved`` false: the measurement left the point) and the target is
        still near the present point (the loop is on its way there), or where there is no
        target (counted in :attr:`targets_missed`), at the measured point ``(x, u)``. Newton
        starts from the last target found (a steady state)."""
        try:
            xs, us = self._target(self._steady, ref, self._p, *self._d)
        except SolverError:
            self.targets_missed += 1
            xs, us = x, self._u
        else:
            self._steady = np.concatenate([xs, us])
            if not (moved or self._far(xs, us, ref - self._d[1])):
                xs, us = x, self._u
        self._qp = self._linearize(xs, us)

    def reset(self, u0: Mapping[str, float] | np.ndarray) -> None:
        super().reset(u0)
        nx, N = self.model.nx, self.settings.horizon
        self._memory = np.concatenate([np.zeros(nx + 1), np.tile(self._u, N)])
        # the operating point's model again, with the nominal parameters, no disturbance
        self._d, self._filter = np.zeros(2), None
        self.relinearizations, self.targets_missed = 0, 0
        self._steady = np.concatenate(self._op)
        self._qp = self._linearize(*self._op)

    def update(self, t: float, y: Mapping[str, float], r: Mapping[str, float]) -> dict:
        s = self.settings
        x = np.array([y[n] for n in self.model.state_names], dtype=float)
        out = float(y[s.output])
        ref = self.clip(r)
        if self._filter is not None and self._memory[self.model.nx] > 0:
            self._estimate(x, out)
        moved = self._moved()
        if moved or self._far(x, self._u, out):
            self._relinearize(x, ref, moved)
        if self._p_law is None:
            self._p_law = self.law_parameters()
        meas = np.concatenate([x, [out], [y[n] for n in self._soft]])
        refs = np.concatenate([[ref], self.nodes(ref)])
        self._memory, u, ok = self._law.outputs(self._memory, meas, self._u, refs, self._p_law)
        if not ok[0]:
            self.stats.fallbacks += 1
        self._plan = self._memory[self.model.nx + 1 :].reshape(s.horizon, -1)
        self._u = u
        return dict(zip(self.inputs, u.tolist(), strict=True))


def make_lmpc(model: Model, op: Equilibrium, dt: float, settings: dict) -> Controller:
    """Registry factory of ``lmpc``: linearised on the plant ``model`` itself at ``op``.

    Common keys: ``output``, ``input`` (the model's one input), ``u_min``, ``u_max``;
    ``tension_min`` (if set) becomes a soft lower bound on every thread tension, after the
    own key ``soft_min`` (:func:`~.receding.factory_bounds`). Own keys:
    the other :class:`LMPCSettings` fields, ``estimator`` ("none", or "ekf": run on an
    EKF fed the ``measured`` signals, see :mod:`.estimated`) and ``ekf`` (its settings).
    The output's noise (``noise_std``) sets ``output_std`` unless given. On an EKF that
    estimates a parameter of the model (by default the load), the estimate is fed to the
    LMPC and ``disturbance`` defaults to "none" (the EKF's estimate, not a second one).
    """
    own, est, ekf_settings = mpc_settings("lmpc", model, settings, LMPCSettings, {}, None)
    if est == "ekf" and "disturbance" not in settings:
        fed = set(estimated_parameters(model, ekf_settings)) & set(model.param_names)
        own["disturbance"] = "none" if fed else own["disturbance"]
    given = dict(zip(model.param_names, np.asarray(op.p, float), strict=True))
    ctl = LinearMPC(model, op.x, op.u, dt, LMPCSettings(**own), given)
    return with_estimator("lmpc", ctl, model, op, dt, settings, est, ekf_settings)


register_controller("lmpc", make_lmpc)
