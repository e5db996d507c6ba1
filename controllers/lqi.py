"""LQI: a discrete LQR with integral action, designed with python-control on the exact
zero-order-hold linearisation at the operating point.

The design model is the sampled linearisation ``dx+ = Ad dx + Bd du``, ``dy = C dx +
D du`` (deviations from the operating point) with the integral of the tracking error
``xi+ = xi + dt (y - r)`` appended; ``control.dlqr`` gives ``u = -Kx dx - Ki xi``. Weights
are set on scaled signals: ``q_y (dy / y_scale)^2 + q_i (xi / (y_scale 1 s))^2 +
r_u (du / u_scale)^2``. A reference feed-forward moves the target to the steady state
``(x_ss, u_ss)`` of the reference, so a step is followed at once, not through the slow
integral: ``u = u_op + u_ss(r) - Kx (dx - x_ss(r)) - Ki xi``, clamped into the bounds
and, with a rate limit ``rate_max`` [input unit/s], to within ``rate_max dt`` of the
previous command.
The steady states are the model's own equilibria on a grid of the input range
(``feedforward = "equilibria"``, the default: the linear map is 9 % off for a 1.5 mm step
at 50 kPa, which the integral then takes a second to remove) or the linearisation's
(``"linear"``).
Anti-windup by clamping: the integral does not grow while the command is held (by a bound
or by the rate limit) in the direction it would push.
The law is one CasADi Function per feed-forward (:meth:`LQI.law_function`): :class:`LQI`
evaluates it every sample, and the controller FMU (:mod:`sarcomere.fmu.controller`)
generates its C code from it.

Vector inputs and outputs: ``output`` and ``input`` may each be a list of as many
signals as inputs (a square system, e.g. the antagonistic joint's two commands on its
angle and stiffness). The same design then gives ``Kx`` (inputs x states), ``Ki`` (inputs
x outputs) and the linear steady-state map ``Nx, Nu`` (the solve of ``[A - I, B; C, D]
[x_ss; u_ss] = [0; I]``); ``y_scale`` is one scale per output (a list) or one for all,
``u_scale`` one for all inputs, the bounds and the rate limit the same for every input.
The integral is held (anti-windup) while any input is held in the direction it would
push. Settings built on one input and one output are refused there: the ``"equilibria"``
feed-forward (a grid over one input's range), ``rate_weight``, ``load_feedforward``,
``preview`` and the EKF.

The state comes from the plant (``estimator = "none"``: every state is read by name, the
full-state case) or from an :class:`~.ekf.EKF` on the measured signals
(``estimator = "ekf"``).

Three opt-in settings give the LQI what the MPCs are given (the defaults leave the law
as above):

* ``rate_weight``: the rate limit in the design. The move per sample ``v = u - u_prev`` is
  the design's input, weighted ``rate_weight (v / (rate_max dt))^2``, and the held command
  a state (its weight ``r_u``): ``u = u_prev - Kx (dx - x_ss) - Ku (u_prev - u_op - u_ss)
  - Ki xi``. The default design, whose moves the rate limit only clamps, limit-cycles at
  n = 8 under 2 MPa/s; this one tracks there.
* ``load_feedforward``: the target moved by the load estimate, ``x_ss + Sx (m - m_op)``,
  ``u_ss + Su (m - m_op)`` (``Sx, Su``: the steady state's sensitivity to the load at the
  operating point's output, from equilibria), the estimate the EKF's (on the EKF) or the
  NMPC's own filter of it (:class:`~.disturbance.StateDisturbanceFilter`, on the states).
* ``preview``: the reference that many samples ahead, through the LQ-optimal preview
  term ``-sum_j G_j w_j`` (``w_j`` the target's change from ``j`` to ``j + 1`` samples
  ahead, ``G_j = (R + B' S B)^-1 B' (A - B K)'^j S`` of the design's Riccati solution).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import casadi as cs
import control as ct
import numpy as np

from sarcomere.dynamics.equilibrium import Equilibrium, solve_equilibrium
from sarcomere.dynamics.errors import ParameterError
from sarcomere.dynamics.modeling.buffered import BufferedCall
from sarcomere.dynamics.modeling.labels import to_label
from sarcomere.dynamics.modeling.model import Model

from .base import Controller
from .disturbance import StateDisturbanceFilter
from .ekf import DEFAULT_STD, EKF, make_ekf, measured_signals
from .linearize import linearize, operating_point
from .lqr import lqi_design, preview_gains
from .registry import (
    MAX_PREVIEW,
    check_input_bounds,
    count,
    max_step,
    own_settings,
    positive,
    refuse_rate_limit,
    register_controller,
)

Y_SCALES = {"m": 1e-3, "N": 1e-2}
"""Default ``y_scale`` by the tracked output's unit: 1 mm of length, 10 mN of force."""


@dataclass(frozen=True)
class LQIWeights:
    """Weights of the LQI design (each on a scaled signal, dimensionless).

    Attributes
    ----------
    q_y : float
        Tracked output, per ``y_scale``, >= 0.
    q_i : float
        Integral of the tracking error, per ``y_scale`` times 1 s, > 0.
    r_u : float
        Input, per ``u_scale``, > 0.
    y_scale : float or tuple of float
        Output scale [SI of the output], > 0; one per output of a vector LQI (or one
        for all).
    u_scale : float
        Input scale [SI of the input], > 0.
    """

    q_y: float = 100.0
    q_i: float = 1000.0
    r_u: float = 1.0
    y_scale: float = 1e-3
    u_scale: float = 1e4


class LQI(Controller):
    """LQR with integral action on one or more outputs and as many inputs (see the
    module docstring).

    Parameters
    ----------
    dt : float
        Sample time [s].
    model : Model
        The model linearised for the design.
    op : Equilibrium
        The operating point.
    output, input : str or sequence of str
        Tracked signal(s) and manipulated input(s), as many of each.
    u_min, u_max : float
        Input bounds [SI] (of every input), holding the operating point's inputs
        (:func:`~.registry.check_input_bounds`).
    weights : LQIWeights
    estimator : EKF or None
        None: the state is read from the plant by name.
    feedforward : str
        "equilibria" (the model's steady states) or "linear".
    rate_max : float or None
        Largest rate of the command [input unit/s], > 0; None: no rate limit.
    """

    slug = "lqi"

    def __init__(
        self,
        dt: float,
        model: Model,
        op: Equilibrium,
        output: str | Sequence[str],
        input: str | Sequence[str],
        u_min: float,
        u_max: float,
        weights: LQIWeights,
        estimator: EKF | None = None,
        feedforward: str = "equilibria",
        rate_max: float | None = None,
        rate_weight: float | None = None,
        load_feedforward: bool = False,
        preview: int = 0,
        output_std: float | None = None,
    ) -> None:
        outs, ins = _names("output", output), _names("input", input)
        if len(outs) != len(ins):
            raise ParameterError("lqi.output", outs, f"as many outputs as inputs ({ins})")
        self.tracked, self.manipulated = outs, ins
        if len(outs) > 1:
            _refuse_vector(
                estimator is not None, feedforward, rate_weight, load_feedforward, preview
            )
        reads = estimator.measured if estimator else [*model.state_names, *outs]
        check_input_bounds("lqi", model, op, {"input": ins, "u_min": u_min, "u_max": u_max})
        bounds = ({n: u_min for n in ins}, {n: u_max for n in ins})
        super().__init__(dt, ins, list(dict.fromkeys(reads)), *bounds)
        if estimator is not None and output not in estimator.measured:
            raise ParameterError("lqi.estimator", output, f"measured by {estimator.measured}")
        positive("lqi", "q_y", weights.q_y, allow_zero=True)
        for key in ("q_i", "r_u", "u_scale"):
            positive("lqi", key, getattr(weights, key))
        scales = np.broadcast_to(np.asarray(weights.y_scale, dtype=float), (len(outs),))
        if len(np.ravel(weights.y_scale)) not in (1, len(outs)):
            raise ParameterError("lqi.y_scale", weights.y_scale, f"one or {len(outs)} scales")
        for v in scales:
            positive("lqi", "y_scale", float(v))
        self.model, self.op, self.weights, self.estimator = model, op, weights, estimator
        self.du_max = max_step("lqi", rate_max, self.dt, u_min, u_max)
        self.output, self.input = outs[0], ins[0]
        self.x_op = op.x.copy()
        y_op = np.array([float(op[n]) for n in outs])
        u_op = np.array([float(op.u[model.input_names.index(n)]) for n in ins])
        sysd = linearize(model, op, outs, dt=self.dt, inputs=ins)
        self.sysd = sysd
        rw = None if rate_weight is None else positive("lqi", "rate_weight", rate_weight)
        # Ku: the gain on the held command, with the rate in the design (else None)
        Kx, self.Ku, Ki, Nx, Nu, aug = lqi_design(sysd, weights, scales, self.dt, rw, self.du_max)
        # one input and output: the scalars and vectors of the one-input law
        one = len(outs) == 1
        self.y_op, self.u_op = (float(y_op[0]), float(u_op[0])) if one else (y_op, u_op)
        self.Kx, self.Ki = (Kx[0], float(Ki[0, 0])) if one else (Kx, Ki)
        self.Nx, self.Nu = (Nx[:, 0], float(Nu[0, 0])) if one else (Nx, Nu)
        self.preview = count("lqi.preview", preview, 0, MAX_PREVIEW, "the MPCs' longest horizon")
        # the target's part of the state: x (and the held command, with the rate design)
        self.preview_gains = preview_gains(*aug, self.preview)[
            :, : model.nx + (self.Ku is not None)
        ]
        self.ahead = ()
        if feedforward not in FEEDFORWARDS:
            raise ParameterError("lqi.feedforward", feedforward, f"one of {FEEDFORWARDS}")
        self._grid = (
            _equilibria(model, op, output, input, u_min, u_max)
            if (feedforward == "equilibria")
            else None
        )
        self.load = None  # (index in p, dx_ss/dm, du_ss/dm, own filter or None)
        if load_feedforward:
            self.load = self._load_feedforward(output_std)
        self._extended = self.load is not None or self.preview > 0
        self.xi = 0.0 if one else np.zeros(len(outs))
        self.u_last = self.u_op
        self._laws: dict[bool, BufferedCall] = {}

    def _load_feedforward(self, output_std: float | None) -> tuple:
        """What ``load_feedforward`` needs: the steady state's sensitivity to the load
        mass at the operating point's output (central differences of equilibria, +-2 g),
        and the load's estimate: the EKF's (it must estimate ``load.m``) or, on the states
        read, the NMPC's own Kalman filter of it (:class:`~.disturbance.StateDisturbanceFilter`)."""
        model, op = self.model, self.op
        if "load.m" not in model.param_names:
            raise ParameterError("lqi.load_feedforward", True, "false: the plant holds no load")
        if self.estimator is not None and "load.m" not in self.estimator.disturbances:
            raise ParameterError(
                "lqi.load_feedforward", True, "false, or an EKF that estimates load.m"
            )
        k = model.param_names.index("load.m")
        params = dict(zip(model.param_names, op.p.tolist(), strict=True))
        ends = []
        for dm in (-LOAD_STEP, LOAD_STEP):
            e = operating_point(
                model,
                dict(zip(model.input_names, op.u.tolist(), strict=True)),
                {**params, "load.m": op.p[k] + dm},
                target=(self.output, self.y_op),
                input_name=self.input,
            )
            ends.append((e.x, e.u[model.input_names.index(self.input)]))
        sx = (ends[1][0] - ends[0][0]) / (2 * LOAD_STEP)
        su = float(ends[1][1] - ends[0][1]) / (2 * LOAD_STEP)
        own = None
        if self.estimator is None:
            var = model.variables["load.m"]
            y_std = output_std or DEFAULT_STD.get(model.unit(self.output), 1e-6)
            scale = np.maximum(np.abs(self.x_op), 1e-2)
            own = StateDisturbanceFilter(
                model, self.output, "load", self.dt, scale, 2e3, y_std, (var.low, var.high)
            )
        return k, sx, su, own

    def feedforward(self, y: Mapping[str, float], x: np.ndarray, dr: float) -> np.ndarray:
        """The law's ``ff`` this sample: the target's shift by the load estimate
        ``(dx_ss/dm, du_ss/dm) (m - m_op)``, and the preview's move ``-sum_j G_j w_j``
        with ``w_j`` the target's change from ``j`` to ``j + 1`` samples ahead."""
        n = self.model.nx
        ff = np.zeros(n + 2)
        if self.load is not None:
            k, sx, su, own = self.load
            if own is None:
                m = self.estimator.parameters["load.m"]
            else:
                p = np.concatenate([self.op.p, [0.0, 0.0]])
                p[k] = self.load_estimate
                m = own.update(x, np.array([self.u_last]), y[self.output], p)
            self.load_estimate = m
            ff[:n], ff[n] = sx * (m - self.op.p[k]), su * (m - self.op.p[k])
        if self.preview and self.ahead:
            refs = [dr, *(a - self.y_op for a in self.ahead)]
            x_ss, u_ss = self._targets(len(refs))(np.array(refs)[None, :])
            z = np.vstack([np.array(x_ss, float), np.array(u_ss, float)])
            z = z[: self.preview_gains.shape[1]]
            w = z[:, :-1] - z[:, 1:]  # the target's change sample to sample
            ff[n + 1] = -float(np.sum(self.preview_gains[: w.shape[1]] * w.T))
        return ff

    def _targets(self, count: int) -> cs.Function:
        """:meth:`target_function` over ``count`` references at once (cached)."""
        if getattr(self, "_mapped", (0, None))[0] != count:
            self._mapped = (count, self.target_function().map(count))
        return self._mapped[1]

    def reset(self, u0: Mapping[str, float]) -> None:
        """Integral to zero; the estimator (if any) restarts at the operating point."""
        super().reset(u0)
        one = len(self.tracked) == 1
        self.xi = 0.0 if one else np.zeros(len(self.tracked))
        u = np.array([float(u0[n]) for n in self.manipulated])
        self.u_last = float(u[0]) if one else u
        self.ahead = ()
        if self.estimator is not None:
            self.estimator.reset(self.x_op)
        if self.load is not None:
            self.load_estimate = float(self.op.p[self.load[0]])
            if self.load[3] is not None:
                self.load[3].reset()

    def state(self, y: Mapping[str, float]) -> np.ndarray:
        """The state the law uses: read by name, or the estimator's update with ``y``."""
        if self.estimator is None:
            return np.array([y[n] for n in self.model.state_names])
        return self.estimator.estimate(y, self.u_last)

    def target_function(self) -> cs.Function:
        """``target(dr) -> (dx_ss, du_ss)``: the steady state of the reference deviation
        ``dr`` (the equilibria grid interpolated linearly, clamped at its ends; or the
        linear map)."""
        n, ny, nu = self.model.nx, len(self.tracked), len(self.manipulated)
        dr = cs.MX.sym("dr", ny)
        if self._grid is None:
            x_ss, u_ss = _linear_target(self, n, ny, nu, dr)
        else:
            ys, X, U = self._grid
            y = cs.fmin(cs.fmax(dr + self.y_op, ys[0]), ys[-1])
            cols = [cs.interpolant(f"x{i}", "linear", [ys], X[:, i])(y) for i in range(X.shape[1])]
            x_ss = cs.vertcat(*cols) - cs.DM(self.x_op)
            u_ss = cs.interpolant("u", "linear", [ys], U)(y) - self.u_op
        return cs.Function("lqi_target", [dr], [x_ss, u_ss], ["dr"], ["dx_ss", "du_ss"])

    def target(self, dr: float) -> tuple[np.ndarray, float]:
        """:meth:`target_function` at ``dr`` [output unit]."""
        x_ss, u_ss = self.target_function()(dr)
        return np.array(x_ss, dtype=float).ravel(), float(u_ss)

    def law_function(self, linear: bool = False, extended: bool = False) -> cs.Function:
        """One sample on deviations: ``lqi(xi, dx, dr, dy, u_prev, g) -> (next xi, u)``
        with ``u_prev`` the command held before the sample and ``g = (u_min, u_max,
        du_max)`` [SI] (``du_max``: the largest change per sample); ``linear`` uses the
        linear steady-state map whatever the setting (:meth:`target_function` otherwise).
        ``extended`` adds the input ``ff`` (:meth:`feedforward`: the target's shift by the
        load estimate, ``n + 1``, and the preview's move).

        Raises
        ------
        ParameterError
            For the law without ``ff`` of an LQI that uses a load estimate or a preview
            (the exported law takes ``r(t)`` and the states only).
        """
        if self._extended and not extended:
            raise ParameterError(
                "lqi.load_feedforward/preview",
                (self.load is not None, self.preview),
                "(False, 0): the law without feed-forward takes r(t) and the states only",
            )
        n, ny, nu = self.model.nx, len(self.tracked), len(self.manipulated)
        xi, dr, dy = cs.MX.sym("xi", ny), cs.MX.sym("dr", ny), cs.MX.sym("dy", ny)
        dx, u_prev = cs.MX.sym("dx", n), cs.MX.sym("u_prev", nu)
        g = cs.MX.sym("g", 2 * nu + 1)  # u_min (each input), u_max (each input), du_max
        ff = cs.MX.sym("ff", n + 2)
        Kx, Ki = cs.DM(np.reshape(self.Kx, (nu, n))), cs.DM(np.reshape(self.Ki, (nu, ny)))
        if linear:
            x_ss, u_ss = _linear_target(self, n, ny, nu, dr)
        else:
            x_ss, u_ss = self.target_function()(dr)
        if extended:
            x_ss, u_ss = x_ss + ff[:n], u_ss + ff[n]
        if self.Ku is None:
            v = cs.DM(self.u_op) + u_ss - cs.mtimes(Kx, dx - x_ss) - cs.mtimes(Ki, xi)
        else:
            held = self.Ku * (u_prev - self.u_op - u_ss)
            v = u_prev - cs.mtimes(Kx, dx - x_ss) - held - cs.mtimes(Ki, xi)
        if extended:
            v = v + ff[n + 1]
        lo = cs.fmax(g[:nu], u_prev - g[2 * nu])
        hi = cs.fmin(g[nu : 2 * nu], u_prev + g[2 * nu])
        u = cs.fmin(cs.fmax(v, lo), hi)
        xi_next = xi + self.dt * (dy - dr)
        # held (bound or rate), and integrating would push further out: hold the integral
        # (every one, while any input is so held)
        push = cs.fabs(v - cs.mtimes(Ki, xi_next - xi) - u) > cs.fabs(v - u)
        wind = cs.mmax(cs.logic_and(u != v, push))
        ins = [xi, dx, dr, dy, u_prev, g, *([ff] if extended else [])]
        return cs.Function(
            "lqi",
            ins,
            [cs.if_else(wind, xi, xi_next), u],
            ["xi", "dx", "dr", "dy", "u_prev", "g", *(["ff"] if extended else [])],
            ["next", "u"],
        )

    def law(
        self,
        xi: float | np.ndarray,
        dx: np.ndarray,
        dr: float | np.ndarray,
        dy: float | np.ndarray,
        u_prev: float | np.ndarray,
        linear: bool = False,
        ff: np.ndarray | None = None,
    ) -> tuple:
        """One sample of :meth:`law_function`: ``(xi, dx, dr, dy, u_prev[, ff]) -> (next
        xi, u)`` [SI] (floats for one output and input, else vectors); ``ff``
        (:meth:`feedforward`) for an LQI that uses one."""
        if linear not in self._laws:  # bound arrays (Function.buffer): ~1 us per call
            call = BufferedCall(self.law_function(linear, self._extended))
            ins = self.manipulated
            lo, hi = [self.u_min[n] for n in ins], [self.u_max[n] for n in ins]
            call.args[5][:] = [*lo, *hi, self.du_max]
            self._laws[linear] = call
        call = self._laws[linear]
        a_xi, a_dx, a_dr, a_dy, a_u = call.args[:5]
        a_xi[:], a_dx[:], a_dr[:], a_dy[:], a_u[:] = xi, dx, dr, dy, u_prev
        if self._extended:
            call.args[6][:] = ff
        call.trigger()
        if len(self.tracked) == 1:
            return float(call.res[0][0]), float(call.res[1][0])
        return np.array(call.res[0]), np.array(call.res[1])

    def update(self, t: float, y: Mapping[str, float], r: Mapping[str, float]) -> dict:
        x = self.state(y)
        dx = x - self.x_op
        if len(self.tracked) == 1:
            dr, dy = r[self.output] - self.y_op, y[self.output] - self.y_op
        else:
            dr = np.array([r[n] for n in self.tracked]) - self.y_op
            dy = np.array([y[n] for n in self.tracked]) - self.y_op
        ff = self.feedforward(y, x, dr) if self._extended else None
        self.xi, u = self.law(self.xi, dx, dr, dy, self.u_last, ff=ff)
        self.u_last = u
        return dict(zip(self.manipulated, np.atleast_1d(u).tolist(), strict=True))

    def as_iosystem(self) -> ct.NonlinearIOSystem:
        """The full-state law as a discrete python-control I/O system, in deviations from
        the operating point: inputs ``reference``, the states and the output (labels as
        :func:`~.linearize.linearize`: link a plant linearised with outputs
        ``state_names + [output]``), output the input; one state, the integral. The
        feed-forward is the linear one (the plant it is linked with is linear).

        Raises
        ------
        ParameterError
            For a rate-limited LQI (the I/O system carries no held command).
        """
        refuse_rate_limit("lqi", self)
        if len(self.tracked) > 1:
            raise ParameterError("lqi.output", self.tracked, "one output for the I/O system")
        self.law_function(True)  # refuses an LQI with feed-forward
        n = self.model.nx

        def step(t, x, u, params):
            dx, dy = np.asarray(u[1 : 1 + n]), u[1 + n]
            return self.law(float(x[0]), dx, u[0], dy, self.u_op, True)

        return ct.nlsys(
            lambda t, x, u, params: np.array([step(t, x, u, params)[0]]),
            lambda t, x, u, params: np.array([step(t, x, u, params)[1] - self.u_op]),
            inputs=["reference", *[to_label(s) for s in self.model.state_names]]
            + [to_label(self.output)],
            outputs=[to_label(self.input)],
            states=["integral"],
            dt=self.dt,
            name="lqi",
        )


LOAD_STEP = 2e-3
"""The load change [kg] of the central differences of the steady state's load sensitivity."""

FEEDFORWARDS = ("equilibria", "linear")
"""Where the reference's steady state comes from (see the module docstring)."""

GRID_POINTS = 41
"""Equilibria on the input range for the ``"equilibria"`` feed-forward."""


def _equilibria(model: Model, op: Equilibrium, output: str, input: str, lo: float, hi: float):
    """``(y, X, u)``: the output, states and input at equilibria on a grid of the input
    range at the operating point's other inputs and parameters, sorted by ``y``."""
    k = model.input_names.index(input)
    others = {n: float(v) for n, v in zip(model.input_names, op.u, strict=True)}
    rows, guess = [], op
    for v in np.linspace(lo, hi, GRID_POINTS):
        guess = solve_equilibrium(model, {**others, input: v}, guess=guess)
        rows.append((guess[output], guess.x, guess.u[k]))
    rows.sort(key=lambda r: r[0])
    ys = np.array([r[0] for r in rows])
    if np.any(np.diff(ys) <= 0):
        raise ParameterError(
            "lqi.feedforward", "equilibria", "'linear' (the output is not monotone in the input)"
        )
    return ys, np.array([r[1] for r in rows]), np.array([r[2] for r in rows])


def _linear_target(lqi: LQI, n: int, ny: int, nu: int, dr) -> tuple:
    """The linear steady state ``(Nx dr, Nu dr)`` of the reference deviation ``dr``."""
    return tuple(
        cs.mtimes(cs.DM(np.reshape(N, shape)), dr)
        for N, shape in ((lqi.Nx, (n, ny)), (lqi.Nu, (nu, ny)))
    )


def _names(key: str, value) -> list[str]:
    """``value`` (one signal name or a sequence of them) as a non-empty list."""
    names = [value] if isinstance(value, str) else list(value)
    if not names or not all(isinstance(n, str) for n in names):
        raise ParameterError(f"lqi.{key}", value, "a signal name or a list of them")
    return names


def _refuse_vector(ekf: bool, feedforward, rate_weight, load_feedforward, preview) -> None:
    """Refuse, on a vector LQI, the settings built on one input and one output."""
    why = "the setting is built on one input and one output"
    if ekf:
        raise ParameterError("lqi.estimator", "ekf", "'none' on a vector LQI", why)
    if feedforward != "linear":
        raise ParameterError(
            "lqi.feedforward",
            feedforward,
            "'linear' on a vector LQI",
            "the equilibria grid runs over one input's range",
        )
    for key, value, off in (
        ("rate_weight", rate_weight, None),
        ("load_feedforward", load_feedforward, False),
        ("preview", preview, 0),
    ):
        if value != off:
            raise ParameterError(f"lqi.{key}", value, f"{off!r} on a vector LQI", why)


def make_lqi(model: Model, op: Equilibrium, dt: float, settings: dict) -> LQI:
    """Registry factory of ``lqi``. Own settings: the :class:`LQIWeights` fields
    (``y_scale`` default from :data:`Y_SCALES`), ``estimator`` ("none" or "ekf"), the
    EKF's settings under ``ekf`` (a table, see :func:`~.ekf.make_ekf`), ``feedforward``
    (:data:`FEEDFORWARDS`), ``rate_max`` (the command's largest rate [input unit/s],
    None: no limit), and the opt-in ``rate_weight`` (None or > 0), ``load_feedforward``
    (false) and ``preview`` (samples, 0; see the module docstring)."""
    out, inp = settings["output"], settings["input"]
    scales = [Y_SCALES.get(model.unit(n), 1.0) for n in _names("output", out)]
    w0 = LQIWeights(y_scale=scales[0] if isinstance(out, str) else tuple(scales))
    defaults = {k: getattr(w0, k) for k in ("q_y", "q_i", "r_u", "y_scale", "u_scale")}
    own = own_settings(
        "lqi",
        settings,
        {
            **defaults,
            "estimator": "none",
            "ekf": {},
            "feedforward": "equilibria",
            "rate_max": None,
            "rate_weight": None,
            "load_feedforward": False,
            "preview": 0,
        },
    )
    if own["estimator"] not in ("none", "ekf"):
        raise ParameterError("lqi.estimator", own["estimator"], "'none' or 'ekf'")
    scalar = {k: float(own[k]) for k in defaults if k != "y_scale"}
    y_scale = own["y_scale"]
    y_scale = tuple(map(float, y_scale)) if isinstance(y_scale, list | tuple) else float(y_scale)
    weights = LQIWeights(**scalar, y_scale=y_scale)
    if not isinstance(out, str):  # before the EKF is built
        keys = ("feedforward", "rate_weight", "load_feedforward", "preview")
        _refuse_vector(own["estimator"] == "ekf", *(own[k] for k in keys))
    est = None
    if own["estimator"] == "ekf":
        measured = measured_signals("lqi", settings, out)
        est = make_ekf(model, op, dt, measured, settings.get("noise_std"), own["ekf"])
    u_min, u_max = float(settings["u_min"]), float(settings["u_max"])
    return LQI(
        dt,
        model,
        op,
        out,
        inp,
        u_min,
        u_max,
        weights,
        est,
        own["feedforward"],
        own["rate_max"],
        own["rate_weight"],
        own["load_feedforward"],
        own["preview"],
        (settings.get("noise_std") or {}).get(_names("output", out)[0]),
    )


register_controller("lqi", make_lqi, vector=True)
