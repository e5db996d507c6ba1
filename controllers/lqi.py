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

The state comes from the plant (``estimator = "none"``: every state is read by name, the
full-state case) or from an :class:`~.ekf.EKF` on the measured signals
(``estimator = "ekf"``).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import casadi as cs
import control as ct
import numpy as np

from sarcomere.dynamics.equilibrium import Equilibrium, solve_equilibrium
from sarcomere.dynamics.errors import ParameterError
from sarcomere.dynamics.modeling.labels import to_label
from sarcomere.dynamics.modeling.model import Model

from .base import Controller
from .ekf import EKF, make_ekf
from .linearize import linearize
from .registry import (
    check_input_bounds,
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
    y_scale : float
        Output scale [SI of the output], > 0.
    u_scale : float
        Input scale [SI of the input], > 0.
    """

    q_y: float = 100.0
    q_i: float = 1000.0
    r_u: float = 1.0
    y_scale: float = 1e-3
    u_scale: float = 1e4


class LQI(Controller):
    """LQR with integral action on one output and one input (see the module docstring).

    Parameters
    ----------
    dt : float
        Sample time [s].
    model : Model
        The model linearised for the design.
    op : Equilibrium
        The operating point.
    output, input : str
        Tracked signal and manipulated input.
    u_min, u_max : float
        Input bounds [SI], holding the operating point's input
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
        output: str,
        input: str,
        u_min: float,
        u_max: float,
        weights: LQIWeights,
        estimator: EKF | None = None,
        feedforward: str = "equilibria",
        rate_max: float | None = None,
        rate_weight: float | None = None,
    ) -> None:
        reads = estimator.measured if estimator else [*model.state_names, output]
        check_input_bounds("lqi", model, op, {"input": input, "u_min": u_min, "u_max": u_max})
        super().__init__(dt, [input], list(dict.fromkeys(reads)), {input: u_min}, {input: u_max})
        if estimator is not None and output not in estimator.measured:
            raise ParameterError("lqi.estimator", output, f"measured by {estimator.measured}")
        positive("lqi", "q_y", weights.q_y, allow_zero=True)
        for key in ("q_i", "r_u", "y_scale", "u_scale"):
            positive("lqi", key, getattr(weights, key))
        self.model, self.op, self.weights, self.estimator = model, op, weights, estimator
        self.du_max = max_step("lqi", rate_max, self.dt, u_min, u_max)
        self.output, self.input = output, input
        self.x_op = op.x.copy()
        self.y_op = float(op[output])
        self.u_op = float(op.u[model.input_names.index(input)])
        sysd = linearize(model, op, [output], dt=self.dt, inputs=[input])
        self.sysd = sysd
        self.Kx, self.Ki, self.Nx, self.Nu = _design(sysd, weights, self.dt)
        self.Ku = None  # the gain on the held command, with the rate in the design
        if rate_weight is not None:
            rw = positive("lqi", "rate_weight", rate_weight)
            self.Kx, self.Ku, self.Ki = _rate_design(sysd, weights, self.dt, rw, self.du_max)
        if feedforward not in FEEDFORWARDS:
            raise ParameterError("lqi.feedforward", feedforward, f"one of {FEEDFORWARDS}")
        self._grid = (
            _equilibria(model, op, output, input, u_min, u_max)
            if (feedforward == "equilibria")
            else None
        )
        self.xi = 0.0
        self.u_last = self.u_op
        self._laws: dict[bool, tuple] = {}

    def reset(self, u0: Mapping[str, float]) -> None:
        """Integral to zero; the estimator (if any) restarts at the operating point."""
        super().reset(u0)
        self.xi = 0.0
        self.u_last = float(u0[self.input])
        if self.estimator is not None:
            self.estimator.reset(self.x_op)

    def state(self, y: Mapping[str, float]) -> np.ndarray:
        """The state the law uses: read by name, or the estimator's update with ``y``."""
        if self.estimator is None:
            return np.array([y[n] for n in self.model.state_names])
        return self.estimator.estimate(y, self.u_last)

    def target_function(self) -> cs.Function:
        """``target(dr) -> (dx_ss, du_ss)``: the steady state of the reference deviation
        ``dr`` (the equilibria grid interpolated linearly, clamped at its ends; or the
        linear map)."""
        dr = cs.MX.sym("dr")
        if self._grid is None:
            x_ss, u_ss = cs.DM(self.Nx) * dr, self.Nu * dr
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

    def law_function(self, linear: bool = False) -> cs.Function:
        """One sample on deviations: ``lqi(xi, dx, dr, dy, u_prev, g) -> (next xi, u)``
        with ``u_prev`` the command held before the sample and ``g = (u_min, u_max,
        du_max)`` [SI] (``du_max``: the largest change per sample); ``linear`` uses the
        linear steady-state map whatever the setting (:meth:`target_function` otherwise)."""
        n = self.model.nx
        xi, dr, dy = cs.MX.sym("xi"), cs.MX.sym("dr"), cs.MX.sym("dy")
        dx, u_prev, g = cs.MX.sym("dx", n), cs.MX.sym("u_prev"), cs.MX.sym("g", 3)
        if linear:
            x_ss, u_ss = cs.DM(self.Nx) * dr, self.Nu * dr
        else:
            x_ss, u_ss = self.target_function()(dr)
        if self.Ku is None:
            v = self.u_op + u_ss - cs.dot(cs.DM(self.Kx), dx - x_ss) - self.Ki * xi
        else:
            held = self.Ku * (u_prev - self.u_op - u_ss)
            v = u_prev - cs.dot(cs.DM(self.Kx), dx - x_ss) - held - self.Ki * xi
        lo, hi = cs.fmax(g[0], u_prev - g[2]), cs.fmin(g[1], u_prev + g[2])
        u = cs.fmin(cs.fmax(v, lo), hi)
        xi_next = xi + self.dt * (dy - dr)
        # held (bound or rate), and integrating would push further out: hold the integral
        wind = cs.logic_and(u != v, cs.fabs(v - self.Ki * (xi_next - xi) - u) > cs.fabs(v - u))
        return cs.Function(
            "lqi",
            [xi, dx, dr, dy, u_prev, g],
            [cs.if_else(wind, xi, xi_next), u],
            ["xi", "dx", "dr", "dy", "u_prev", "g"],
            ["next", "u"],
        )

    def law(
        self,
        xi: float,
        dx: np.ndarray,
        dr: float,
        dy: float,
        u_prev: float,
        linear: bool = False,
    ) -> tuple[float, float]:
        """One sample of :meth:`law_function`: ``(xi, dx, dr, dy, u_prev) -> (next xi,
        u)`` [SI]."""
        if linear not in self._laws:  # bound arrays (Function.buffer): ~1 us per call
            f = self.law_function(linear)
            args = [np.zeros(f.nnz_in(i)) for i in range(f.n_in())]
            res = [np.zeros(f.nnz_out(i)) for i in range(f.n_out())]
            buf, trigger = f.buffer()
            for i, a in enumerate(args):
                buf.set_arg(i, memoryview(a))
            for i, a in enumerate(res):
                buf.set_res(i, memoryview(a))
            args[5][:] = self.u_min[self.input], self.u_max[self.input], self.du_max
            self._laws[linear] = (buf, trigger, args, res)
        _, trigger, (a_xi, a_dx, a_dr, a_dy, a_u, _), (r_xi, r_u) = self._laws[linear]
        a_xi[0], a_dx[:], a_dr[0], a_dy[0], a_u[0] = xi, dx, dr, dy, u_prev
        trigger()
        return float(r_xi[0]), float(r_u[0])

    def update(self, t: float, y: Mapping[str, float], r: Mapping[str, float]) -> dict:
        dx = self.state(y) - self.x_op
        dr, dy = r[self.output] - self.y_op, y[self.output] - self.y_op
        self.xi, u = self.law(self.xi, dx, dr, dy, self.u_last)
        self.u_last = u
        return {self.input: u}

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


def _design(sysd: ct.StateSpace, w: LQIWeights, dt: float):
    """``Kx, Ki`` from ``control.dlqr`` on the model with the error integral appended,
    and the steady-state map ``x_ss = Nx dr``, ``u_ss = Nu dr``."""
    A, B, C, D = sysd.A, sysd.B, sysd.C, sysd.D
    n = A.shape[0]
    Aa = np.block([[A, np.zeros((n, 1))], [dt * C, np.ones((1, 1))]])
    Ba = np.vstack([B, dt * D])
    Q = np.zeros((n + 1, n + 1))
    Q[:n, :n] = w.q_y / w.y_scale**2 * C.T @ C
    Q[n, n] = w.q_i / w.y_scale**2
    R = np.array([[w.r_u / w.u_scale**2]])
    K, _, _ = ct.dlqr(Aa, Ba, (Q + Q.T) / 2, R)
    M = np.block([[A - np.eye(n), B], [C, D]])
    N = np.linalg.solve(M, np.concatenate([np.zeros(n), [1.0]]))
    return K[0, :n], float(K[0, n]), N[:n], float(N[n])


def _rate_design(sysd: ct.StateSpace, w: LQIWeights, dt: float, rate_weight: float, du: float):
    """``Kx, Ku, Ki`` of the design with the move per sample as the input: the state
    ``[dx; u_prev - u_op; xi]`` (the command held before the sample appended), the input
    the move ``v = u - u_prev``, weighted ``rate_weight (v / du)^2`` with ``du`` the rate
    limit's move per sample (the input's own weight ``r_u`` then sits on ``u_prev``);
    the law is ``u = u_prev - Kx (dx - x_ss) - Ku (u_prev - u_op - u_ss) - Ki xi``."""
    A, B, C, D = sysd.A, sysd.B, sysd.C, sysd.D
    n = A.shape[0]
    Aa = np.block(
        [
            [A, B, np.zeros((n, 1))],
            [np.zeros((1, n)), np.ones((1, 1)), np.zeros((1, 1))],
            [dt * C, dt * D, np.ones((1, 1))],
        ]
    )
    Ba = np.vstack([B, np.ones((1, 1)), dt * D])
    Q = np.zeros((n + 2, n + 2))
    Q[:n, :n] = w.q_y / w.y_scale**2 * C.T @ C
    Q[n, n] = w.r_u / w.u_scale**2
    Q[n + 1, n + 1] = w.q_i / w.y_scale**2
    K, _, _ = ct.dlqr(Aa, Ba, (Q + Q.T) / 2, np.array([[rate_weight / du**2]]))
    return K[0, :n], float(K[0, n]), float(K[0, n + 1])


def make_lqi(model: Model, op: Equilibrium, dt: float, settings: dict) -> LQI:
    """Registry factory of ``lqi``. Own settings: the :class:`LQIWeights` fields
    (``y_scale`` default from :data:`Y_SCALES`), ``estimator`` ("none" or "ekf"), the
    EKF's settings under ``ekf`` (a table, see :func:`~.ekf.make_ekf`), ``feedforward``
    (:data:`FEEDFORWARDS`) and ``rate_max`` (the command's largest rate [input unit/s],
    None: no limit)."""
    out, inp = settings["output"], settings["input"]
    unit = model.unit(out)
    w0 = LQIWeights(y_scale=Y_SCALES.get(unit, 1.0))
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
        },
    )
    if own["estimator"] not in ("none", "ekf"):
        raise ParameterError("lqi.estimator", own["estimator"], "'none' or 'ekf'")
    weights = LQIWeights(**{k: float(own[k]) for k in defaults})
    est = None
    if own["estimator"] == "ekf":
        measured = settings.get("measured")
        if measured is None:
            measured = [out, "regulator.p_out"]
        elif not measured:
            raise ParameterError("lqi.measured", measured, "at least one signal for the EKF")
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
    )


register_controller("lqi", make_lqi)
