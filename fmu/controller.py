"""The project's controllers as Co-Simulation FMUs.

:func:`pid_system` wraps a :class:`~sarcomere.controllers.pid.PID`'s own law
(:func:`~sarcomere.controllers.pid.pid_law`, the CasADi Function the Python controller
evaluates every sample) as a :class:`~.sampled.SampledSystem`; :func:`export_controller_fmu`
writes it. The FMU's variables (SI, units from the plant model):

============== =========== ====================================================
variable       causality   meaning
============== =========== ====================================================
reference      input       the tracked output's reference ``r``
measurement    input       the measured output ``y``
command        output      the plant input ``u``, held between samples
integral, ...  local       the law's state (:data:`~.pid.STATE_NAMES`) and the
                           held command ``held_command`` (discrete)
kp, ki, kd,    parameter   the gains and the command's bounds (tunable: from the
tf, tt, u_min,             next sample on; the bounds within the exported ones)
u_max
bias           parameter   the command before the first sample (fixed: the start
                           state is computed from it)
============== =========== ====================================================

Sampled at the PID's ``dt`` from the start time (see :mod:`.sampled` for ``doStep``).
"""

from __future__ import annotations

import math
from pathlib import Path

import casadi as cs

from sarcomere.controllers.pid import LAW_PARAMETERS, PID, STATE_NAMES, pid_law
from sarcomere.dynamics.errors import ParameterError
from sarcomere.dynamics.modeling.model import Model

from .export import Experiment
from .sampled import SampledSystem, Variable, export_sampled_fmu

TIME_PARAMETER_MIN_S = 1e-9
"""Smallest derivative-filter and tracking time constant the FMU accepts [s] (the law
divides by ``tt``)."""


def pid_system(pid: PID, model: Model, bias: float, name: str = "pid") -> SampledSystem:
    """``pid`` as a sampled system, its units from ``model`` (the plant), the command
    ``bias`` [input unit] before the first sample (the Python controller's ``reset(u0)``)."""
    yu, uu = model.unit(pid.output), model.unit(pid.input)
    lo, hi = pid.u_min[pid.input], pid.u_max[pid.input]
    if not lo <= bias <= hi:
        raise ParameterError("bias", bias, f"[{lo:g}, {hi:g}] {uu}")
    rate = f"{uu}/{yu}"
    g = pid.law_parameters(bias)
    units = {"kp": rate, "ki": f"{rate}/s", "kd": f"{rate}*s", "tf": "s", "tt": "s"}
    text = {
        "kp": "proportional gain",
        "ki": "integral gain",
        "kd": "derivative gain",
        "tf": "time constant of the derivative filter",
        "tt": "tracking time constant of the anti-windup",
        "u_min": "lowest command",
        "u_max": "highest command",
        "bias": "command before the first sample, and the law's offset",
    }
    params = []
    for key, value in zip(LAW_PARAMETERS, g, strict=True):
        low, high = -math.inf, math.inf
        if key in ("tf", "tt"):
            low = TIME_PARAMETER_MIN_S
        elif key in ("u_min", "u_max", "bias"):
            low, high = lo, hi  # the command stays inside the exported bounds
        params.append(Variable(key, units.get(key, uu), text[key], float(value), low, high))
    integral, derivative, last, started = STATE_NAMES
    states = (
        Variable(integral, uu, "integral of the error, with the anti-windup correction"),
        Variable(derivative, uu, "filtered derivative term"),
        Variable(last, yu, "measurement of the last sample"),
        Variable(started, "1", "1 once a sample was taken", low=0.0, high=1.0),
        Variable("held_command", uu, "command held since the last sample", low=lo, high=hi),
    )
    x = cs.SX.sym("x", len(states))
    u, p = cs.SX.sym("u", 2), cs.SX.sym("p", len(LAW_PARAMETERS))
    nxt, cmd = pid_law(pid.dt)(x[: len(STATE_NAMES)], u[0], u[1], p)
    bias_sym = p[LAW_PARAMETERS.index("bias")]
    return SampledSystem(
        name,
        f"PID of {pid.input} on {pid.output}, sampled every {pid.dt:g} s (sarcomere)",
        pid.dt,
        states,
        (
            Variable("reference", yu, f"reference of {pid.output}"),
            Variable("measurement", yu, f"measured {pid.output}"),
        ),
        (Variable("command", uu, f"{pid.input}, held between samples", low=lo, high=hi),),
        tuple(params),
        cs.Function("update", [x, u, p], [cs.vertcat(nxt, cmd)]),
        cs.Function("output", [x, p], [x[-1]]),
        cs.Function("start", [u, p], [cs.vertcat(cs.DM.zeros(len(STATE_NAMES)), bias_sym)]),
    )


def export_controller_fmu(
    controller: PID,
    model: Model,
    path: str | Path,
    bias: float,
    fmi_version: int = 2,
    name: str = "pid",
    stop_time: float | None = None,
) -> Path:
    """Write ``controller`` (a PID) as a Co-Simulation FMU; see :func:`pid_system`.

    Parameters
    ----------
    controller : PID
        The controller; its sample time is the FMU's period.
    model : Model
        The plant it controls: the units of its output and input.
    path : str or Path
        The ``.fmu`` file to write (its folder must exist).
    bias : float
        The command before the first sample [input unit], in the controller's bounds.
    fmi_version : int
        2 or 3.
    name : str
        The model name and identifier.
    stop_time : float, optional
        The default experiment's stop time [s].

    Returns
    -------
    Path
        ``path``.

    Raises
    ------
    ParameterError
        For a controller without a CasADi law (only PID has one), a bias outside the
        bounds, a bad version or path.
    """
    if not isinstance(controller, PID):
        raise ParameterError(
            "controller", type(controller).__name__, "a PID (the controller with an exported law)"
        )
    system = pid_system(controller, model, bias, name)
    experiment = Experiment(stop_time=stop_time, step_size=controller.dt)
    return export_sampled_fmu(system, path, fmi_version, experiment=experiment)
