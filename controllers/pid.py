"""A sampled PID controller: the baseline the others are compared against.

``u = u0 + kp e + I + D`` with ``e = r - y``, held for one sample and clamped into the
input's bounds and, with a rate limit ``rate_max`` [input unit/s], to within
``rate_max dt`` of the previous command. The derivative acts on the measurement (no kick
at a reference step) through a first-order filter ``D = -kd s / (tf s + 1) y``,
discretised by backward Euler.
Anti-windup by back-calculation: the integral is corrected by ``dt / tt (u - v)`` where
``v`` is the unclamped command, so it stops growing while the command is held by a bound
or by the rate limit.

The law is one CasADi Function (:func:`pid_law`), the one source of truth: :class:`PID`
evaluates it every sample, and the controller FMU (:mod:`sarcomere.fmu.controller`)
generates its C code from it.

Gains are in the plant's units (Pa per m for length control): a chain shortens as the
pressure rises, so length control has negative gains. Left out, ``kp`` and ``ki`` come
from the linearisation at the operating point (:func:`imc_gains`).

Examples
--------
>>> from sarcomere.dynamics import hanging_load
>>> from sarcomere.controllers.linearize import operating_point
>>> m = hanging_load(n=1, load_kg=0.02)
>>> op = operating_point(m, {"regulator.p_cmd": 5e4})
>>> pid = make_pid(m, op, 0.01, {"output": "myofibril.length", "input": "regulator.p_cmd",
...                              "u_min": 0.0, "u_max": 1e5})
>>> pid.reset({"regulator.p_cmd": 5e4})
>>> u = pid.checked(0.0, {"myofibril.length": op["myofibril.length"]},
...                 {"myofibril.length": op["myofibril.length"] - 1e-3})
>>> bool(u["regulator.p_cmd"] > 5e4)  # shorter wanted: more pressure
True
"""

from __future__ import annotations

import functools
import math
from collections.abc import Mapping
from dataclasses import astuple, dataclass

import casadi as cs
import control as ct
import numpy as np

from sarcomere.dynamics.equilibrium import Equilibrium
from sarcomere.dynamics.errors import ParameterError
from sarcomere.dynamics.modeling.buffered import BufferedCall
from sarcomere.dynamics.modeling.labels import to_label
from sarcomere.dynamics.modeling.model import Model

from .base import Controller, finite
from .linearize import linearize
from .registry import (
    MAX_PREVIEW,
    count,
    max_step,
    own_settings,
    positive,
    refuse_rate_limit,
    register_controller,
)


@dataclass(frozen=True)
class PIDGains:
    """Gains of :class:`PID`, in the plant's SI units.

    Attributes
    ----------
    kp : float
        Proportional gain [input unit / output unit].
    ki : float
        Integral gain [input unit / (output unit s)].
    kd : float
        Derivative gain [input unit s / output unit].
    tf : float
        Time constant of the derivative filter [s], > 0.
    tt : float
        Tracking time constant of the anti-windup back-calculation [s], > 0.
    """

    kp: float
    ki: float = 0.0
    kd: float = 0.0
    tf: float = 0.02
    tt: float = 0.1


STATE_NAMES = ("integral", "derivative", "last_measurement", "started")
"""The law's state: the integral and the filtered derivative [input unit], the last
measurement [output unit] and whether a sample was taken (0 or 1)."""

LAW_PARAMETERS = ("kp", "ki", "kd", "tf", "tt", "u_min", "u_max", "du_max", "bias")
"""The law's parameters: the :class:`PIDGains` fields, the input's bounds, the largest
change of the command per sample (``rate_max dt``; ``u_max - u_min`` without a rate
limit) and the bias."""


@functools.cache
def pid_law(dt: float) -> cs.Function:
    """One sample of the PID law at the sample time ``dt`` [s]:
    ``pid(state[4], r, y, u_prev, g[9]) -> (next state, u)``, with ``state`` as
    :data:`STATE_NAMES`, ``u_prev`` the command held before this sample and ``g`` as
    :data:`LAW_PARAMETERS` (SI)."""
    state, r, y = cs.SX.sym("state", 4), cs.SX.sym("r"), cs.SX.sym("y")
    u_prev, g = cs.SX.sym("u_prev"), cs.SX.sym("g", len(LAW_PARAMETERS))
    kp, ki, kd, tf, tt, u_min, u_max, du_max, bias = cs.vertsplit(g)
    integral, deriv, y_last, started = cs.vertsplit(state)
    e = r - y
    dy = cs.if_else(started > 0.5, y - y_last, 0.0)  # no derivative kick at the first sample
    deriv = (tf * deriv - kd * dy) / (tf + dt)
    v = bias + kp * e + integral + deriv
    lo, hi = cs.fmax(u_min, u_prev - du_max), cs.fmin(u_max, u_prev + du_max)
    u = cs.fmin(cs.fmax(v, lo), hi)
    integral = integral + ki * dt * e + dt / tt * (u - v)
    return cs.Function(
        "pid",
        [state, r, y, u_prev, g],
        [cs.vertcat(integral, deriv, y, 1.0), u],
        ["state", "r", "y", "u_prev", "g"],
        ["next", "u"],
    )


class PID(Controller):
    """PID on one output and one input (see the module docstring)."""

    slug = "pid"

    def __init__(
        self,
        dt: float,
        output: str,
        input: str,
        u_min: float,
        u_max: float,
        gains: PIDGains,
        rate_max: float | None = None,
        preview: int = 0,
    ) -> None:
        super().__init__(dt, [input], [output], {input: u_min}, {input: u_max})
        self.preview = count("pid.preview", preview, 0, MAX_PREVIEW, "the MPCs' longest horizon")
        self.ahead = ()
        for key in ("kp", "ki", "kd"):
            if not math.isfinite(getattr(gains, key)):
                raise ParameterError(f"pid.{key}", getattr(gains, key), "a finite number")
        positive("pid", "tf", gains.tf)
        positive("pid", "tt", gains.tt)
        self.gains = gains
        self.output, self.input = output, input
        self.du_max = max_step("pid", rate_max, self.dt, u_min, u_max)
        self.bias = self.u_prev = 0.0
        self._state = np.zeros(len(STATE_NAMES))
        self._law = BufferedCall(pid_law(self.dt))  # bound arrays: ~1 us per call, not ~60
        self._law.args[4][:] = self.law_parameters(0.0)  # the bias (last) set per call

    def reset(self, u0: Mapping[str, float]) -> None:
        """Start from the held input ``u0`` (the bias), integral and derivative zero."""
        super().reset(u0)
        self.ahead = ()
        self.bias = self.u_prev = float(u0[self.input])
        self._state = np.zeros(len(STATE_NAMES))

    def law_parameters(self, bias: float) -> np.ndarray:
        """The parameter vector ``g`` of :func:`pid_law` (:data:`LAW_PARAMETERS`)."""
        lo, hi = self.u_min[self.input], self.u_max[self.input]
        return np.array([*astuple(self.gains), lo, hi, self.du_max, bias], dtype=float)

    def law(
        self, state: np.ndarray, r: float, y: float, u_prev: float, bias: float
    ) -> tuple[np.ndarray, float]:
        """One sample of :func:`pid_law`: ``(state, r, y, u_prev, bias) -> (next state,
        u)``; ``state`` as :data:`STATE_NAMES` (zeros before the first sample), ``u_prev``
        the command held before the sample."""
        x, r_in, y_in, u_in, g = self._law.args
        x[:], r_in[0], y_in[0], u_in[0], g[-1] = state, r, y, u_prev, bias
        self._law.trigger()
        return self._law.res[0].copy(), float(self._law.res[1][0])

    def update(self, t: float, y: Mapping[str, float], r: Mapping[str, float]) -> dict:
        y_now = y[self.output]
        # with preview, the reference the plant's lag ahead (the last one handed over)
        r_now = self.ahead[-1] if self.ahead else r[self.output]
        self.ahead = ()
        self._state, u = self.law(self._state, r_now, y_now, self.u_prev, self.bias)
        self.u_prev = u
        return {self.input: u}

    def as_iosystem(self, op: Equilibrium, model: Model) -> ct.NonlinearIOSystem:
        """The same law as a discrete python-control I/O system, in deviations from ``op``.

        Inputs ``reference`` and ``to_label(output)``, output ``to_label(input)``: it
        connects by name to :func:`~.linearize.linearize`'s plant in ``ct.interconnect``.
        The law only sees the error and the change of ``y``, so it runs on deviations
        with the operating input as bias; the output is clamped to the bounds of
        :meth:`update` and returned as a deviation. Start it from the zero state.

        Raises
        ------
        ParameterError
            For a rate-limited PID (the I/O system carries no held command).
        """
        refuse_rate_limit("pid", self)
        u_op = float(op.u[model.input_names.index(self.input)])

        def step(t, x, u, params):
            return self.law(np.asarray(x, dtype=float), u[0], u[1], u_op, u_op)

        return ct.nlsys(
            lambda t, x, u, params: step(t, x, u, params)[0],
            lambda t, x, u, params: np.array([step(t, x, u, params)[1] - u_op]),
            inputs=["reference", to_label(self.output)],
            outputs=[to_label(self.input)],
            states=list(STATE_NAMES),
            dt=self.dt,
            name="pid",
        )


def imc_gains(sys: ct.StateSpace, closed_loop_s: float) -> tuple[float, float]:
    """PI gains ``(kp, ki)`` by internal-model control on a first-order fit of ``sys``.

    The fit keeps the steady-state gain ``K = G(0)`` and the mean residence time
    ``tau = -G'(0) / G(0)`` (the sum of the time constants, minus those of the zeros):
    ``ki = 1 / (K lambda)``, ``kp = tau ki`` with the closed-loop time constant
    ``lambda``.
    """
    A, B, C, D = sys.A, sys.B, sys.C, sys.D
    AiB = np.linalg.solve(A, B)
    K = float((D - C @ AiB)[0, 0])
    dK = float(-(C @ np.linalg.solve(A, AiB))[0, 0])  # G'(0) = -C A^-2 B
    tau = -dK / K
    ki = 1.0 / (K * closed_loop_s)
    return tau * ki, ki


def make_pid(model: Model, op: Equilibrium, dt: float, settings: dict) -> PID:
    """Registry factory of ``pid``. Own settings: ``kp``, ``ki``, ``kd`` (None: ``kp`` and
    ``ki`` from :func:`imc_gains`, ``kd`` 0), ``closed_loop_s`` (the IMC time constant,
    default 0.15 s), ``tf`` and ``tt`` (see :class:`PIDGains`; ``tt`` None: ``kp / ki``),
    ``rate_max`` (the command's largest rate [input unit/s], None: no limit), ``preview``
    (samples, default 0: with the reference known ahead, the PID tracks the one that many
    samples ahead, a feed-forward of the plant's lag)."""
    defaults = {"kp": None, "ki": None, "kd": 0.0, "closed_loop_s": 0.15, "tf": 0.02}
    own = own_settings("pid", settings, {**defaults, "tt": None, "rate_max": None, "preview": 0})
    for key in ("kp", "ki", "tt"):
        if own[key] is not None and not finite(own[key]):
            raise ParameterError(f"pid.{key}", own[key], "a finite number, or None")
    out, inp = settings["output"], settings["input"]
    kp, ki = own["kp"], own["ki"]
    if kp is None or ki is None:
        lam = positive("pid", "closed_loop_s", own["closed_loop_s"])
        kp_imc, ki_imc = imc_gains(linearize(model, op, [out], inputs=[inp]), lam)
        kp = kp_imc if kp is None else kp
        ki = ki_imc if ki is None else ki
    tt = own["tt"]
    if tt is None:
        tt = abs(kp / ki) if ki else 1.0
    gains = PIDGains(float(kp), float(ki), float(own["kd"]), float(own["tf"]), float(tt))
    lo, hi = float(settings["u_min"]), float(settings["u_max"])
    return PID(dt, out, inp, lo, hi, gains, own["rate_max"], own["preview"])


register_controller("pid", make_pid)
