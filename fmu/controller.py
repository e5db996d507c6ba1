"""The project's controllers as Co-Simulation FMUs.

:func:`pid_system` and :func:`lqi_system` wrap a controller's own law (the CasADi Function
the Python controller evaluates every sample: :func:`~sarcomere.controllers.pid.pid_law`,
:meth:`~sarcomere.controllers.lqi.LQI.law_function`) as a :class:`~.sampled.SampledSystem`;
:func:`export_controller_fmu` writes either. The FMU's variables (SI, units from the plant
model):

============== =========== ====================================================
variable       causality   meaning
============== =========== ====================================================
reference      input       the tracked output's reference ``r``
measurement    input       the measured output ``y``
<state names>  input       LQI only: the plant's states, by their model names
command        output      the plant input ``u``, held between samples
integral, ...  local       the law's state (PID: :data:`~.pid.STATE_NAMES`; LQI:
                           ``integral``) and the held command ``held_command``
kp, ki, kd,    parameter   PID: the gains (tunable: from the next sample on)
tf, tt
u_min, u_max   parameter   the command's bounds (tunable, within the exported ones)
du_max         parameter   the largest change of the command per sample (the rate
                           limit times ``dt``; ``u_max - u_min``: no limit; tunable)
bias           parameter   the command before the first sample (fixed: the start
                           state is computed from it)
============== =========== ====================================================

Sampled at the controller's ``dt`` from the start time (see :mod:`.sampled` for
``doStep``).
"""

from __future__ import annotations

import math
from pathlib import Path

import casadi as cs

from sarcomere.controllers.estimated import OnEstimate
from sarcomere.controllers.lmpc import LinearMPC
from sarcomere.controllers.lqi import LQI
from sarcomere.controllers.nmpc import NonlinearMPC
from sarcomere.controllers.pid import LAW_PARAMETERS, PID, STATE_NAMES, pid_law
from sarcomere.controllers.rti import GENERATED_SOLVERS, RealTimeIteration
from sarcomere.dynamics.equilibrium import solve_equilibrium
from sarcomere.dynamics.errors import ParameterError
from sarcomere.dynamics.modeling.model import Model

from .export import Experiment
from .sampled import SampledSystem, Variable, export_sampled_fmu

GENERATED_QP = ("daqp", "qrqp")
"""QP solvers of the MPCs whose CasADi-generated C the export compiles (qrqp's is
self-contained; DAQP's links the casadi wheel's static library)."""

TIME_PARAMETER_MIN_S = 1e-9
"""Smallest derivative-filter and tracking time constant the FMU accepts [s] (the law
divides by ``tt``)."""


def pid_system(pid: PID, model: Model, bias: float, name: str = "pid") -> SampledSystem:
    """``pid`` as a sampled system, its units from ``model`` (the plant), the command
    ``bias`` [input unit] before the first sample (the Python controller's ``reset(u0)``)."""
    yu, (uu, lo, hi) = model.unit(pid.output), _bias(pid, model, bias)
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
        "du_max": "largest change of the command per sample",
        "bias": "command before the first sample, and the law's offset",
    }
    params = []
    for key, value in zip(LAW_PARAMETERS, g, strict=True):
        low, high = -math.inf, math.inf
        if key in ("tf", "tt"):
            low = TIME_PARAMETER_MIN_S
        elif key in ("u_min", "u_max", "bias"):
            low, high = lo, hi  # the command stays inside the exported bounds
        elif key == "du_max":
            low = 0.0
        params.append(Variable(key, units.get(key, uu), text[key], float(value), low, high))
    integral, derivative, last, started = STATE_NAMES
    states = (
        Variable(integral, uu, "integral of the error, with the anti-windup correction"),
        Variable(derivative, uu, "filtered derivative term"),
        Variable(last, yu, "measurement of the last sample"),
        Variable(started, "1", "1 once a sample was taken", low=0.0, high=1.0),
        _held(uu, lo, hi),
    )
    x = cs.SX.sym("x", len(states))
    u, p = cs.SX.sym("u", 2), cs.SX.sym("p", len(LAW_PARAMETERS))
    nxt, cmd = pid_law(pid.dt)(x[: len(STATE_NAMES)], u[0], u[1], x[-1], p)
    bias_sym = p[LAW_PARAMETERS.index("bias")]
    return SampledSystem(
        name,
        f"PID of {pid.input} on {pid.output}, sampled every {pid.dt:g} s (sarcomere)",
        pid.dt,
        states,
        tuple(_inputs(pid.output, model)),
        (Variable("command", uu, f"{pid.input}, held between samples", low=lo, high=hi),),
        tuple(params),
        cs.Function("update", [x, u, p], [cs.vertcat(nxt, cmd)]),
        cs.Function("output", [x, p], [x[-1]]),
        cs.Function("start", [u, p], [cs.vertcat(cs.DM.zeros(len(STATE_NAMES)), bias_sym)]),
    )


def _bias(controller, model: Model, bias: float) -> tuple[str, float, float]:
    """The input's unit and bounds; ``bias`` checked inside them."""
    (name,) = controller.inputs
    uu = model.unit(name)
    lo, hi = controller.u_min[name], controller.u_max[name]
    if not lo <= bias <= hi:
        raise ParameterError("bias", bias, f"[{lo:g}, {hi:g}] {uu}")
    return uu, lo, hi


def _held(uu: str, lo: float, hi: float) -> Variable:
    """The state holding the command between samples."""
    return Variable("held_command", uu, "command held since the last sample", low=lo, high=hi)


def _limits(uu: str, lo: float, hi: float, du_max: float) -> list:
    """The parameters ``u_min``, ``u_max`` (start ``lo``, ``hi``) and ``du_max``
    [input unit ``uu``]."""
    return [
        Variable("u_min", uu, "lowest command", lo, lo, hi),
        Variable("u_max", uu, "highest command", hi, lo, hi),
        Variable("du_max", uu, "largest change of the command per sample", du_max, 0.0),
    ]


def _inputs(output: str, model: Model, y0: float = 0.0, x0=None, held: str = "") -> list:
    """The reference (``held``: how it is held) and the measured ``output``, both starting
    at ``y0``, and, with their start values ``x0``, the plant's states by name."""
    yu = model.unit(output)
    inputs = [
        Variable("reference", yu, f"reference of {output}{held}", y0),
        Variable("measurement", yu, f"measured {output}", y0),
    ]
    for n, v in zip(model.state_names, () if x0 is None else x0, strict=x0 is not None):
        inputs.append(Variable(n, model.unit(n), f"plant state {n}", float(v)))
    return inputs


def _mpc_inputs(mpc, pred: Model, uname: str, bias: float) -> list:
    """An exact-state MPC's inputs (:func:`_inputs`) starting at the prediction's
    equilibrium at ``bias`` under the parameters it predicts with now."""
    now = {k: v for k, v in mpc.parameters.items() if k in pred.param_names}
    op = solve_equilibrium(pred, {uname: bias}, now)
    out = mpc.settings.output
    return _inputs(out, pred, float(op[out]), op.x, " (held over the horizon)")


def lqi_system(lqi: LQI, model: Model, bias: float, name: str = "lqi") -> SampledSystem:
    """A full-state ``lqi`` (no estimator) as a sampled system: inputs the reference, the
    measured output and the plant's states by name; units from ``model``; the command
    ``bias`` [input unit] before the first sample."""
    if lqi.estimator is not None:
        raise ParameterError(
            "controller", "lqi on an EKF", "a full-state LQI (the EKF is not exported)"
        )
    if len(lqi.tracked) > 1:
        raise ParameterError("controller", lqi.tracked, "an LQI of one output and one input")
    yu, (uu, lo, hi) = model.unit(lqi.output), _bias(lqi, model, bias)
    states = (
        Variable("integral", f"{yu}*s", "integral of the tracking error (y - r)"),
        _held(uu, lo, hi),
    )
    inputs = _inputs(lqi.output, model, lqi.y_op, lqi.x_op)  # start values: the design point
    params = (
        *_limits(uu, lo, hi, lqi.du_max),
        Variable("bias", uu, "command before the first sample", bias, lo, hi),
    )
    x = cs.MX.sym("x", 2)
    u, p = cs.MX.sym("u", len(inputs)), cs.MX.sym("p", len(params))
    dx = u[2:] - cs.DM(lqi.x_op)
    law = lqi.law_function()
    nxt, cmd = law(x[0], dx, u[0] - lqi.y_op, u[1] - lqi.y_op, x[1], p[:3])
    return SampledSystem(
        name,
        f"LQI of {lqi.input} on {lqi.output} (full state), sampled every {lqi.dt:g} s (sarcomere)",
        lqi.dt,
        states,
        tuple(inputs),
        (Variable("command", uu, f"{lqi.input}, held between samples", low=lo, high=hi),),
        params,
        cs.Function("update", [x, u, p], [cs.vertcat(nxt, cmd)]),
        cs.Function("output", [x, p], [x[1]]),
        cs.Function("start", [u, p], [cs.vertcat(0.0, p[3])]),
    )


def nmpc_system(nmpc: NonlinearMPC, model: Model, bias: float, name: str = "nmpc") -> SampledSystem:
    """A full-state real-time-iteration ``nmpc`` (no estimator, ``disturbance = "none"``)
    as a sampled system.

    The update is the NMPC's own law (:meth:`NonlinearMPC.law_function`: one RTI step
    with its warm start as memory) with the Python controller's steps around it: the
    reference clipped to the reachable range and held over the horizon (the FMU sees the
    current reference only: the Python NMPC with ``preview = false``), the integral
    reference shift (when ``integral_gain > 0``) and the held command. Inputs: the
    reference, the measured output and the prediction's states by name; parameters: every
    parameter of the prediction model (tunable: the run-time inputs of the law; their
    start values those the prediction uses now, :attr:`NonlinearMPC.parameters`) and
    ``bias`` (fixed). The bounds and the rate limit are constraints of the QP, fixed at
    export. Units from the prediction model (``model``, the plant, must have its output and
    input).
    """
    if not isinstance(getattr(nmpc, "engine", None), RealTimeIteration):
        raise ParameterError(
            "controller", _what(nmpc), "an NMPC with solver 'rti' (the exported law)"
        )
    uname = _exportable("nmpc", nmpc, model)
    s, pred = nmpc.settings, nmpc.model
    if s.backoff:  # fed by an EKF, which is not exported
        raise ParameterError("nmpc.backoff", s.backoff, "0 (no estimator in the FMU)")
    if s.linear_solver not in GENERATED_SOLVERS:  # LAPACK's are calls, not generated C
        raise ParameterError(
            "nmpc.linear_solver",
            s.linear_solver,
            f"one of {GENERATED_SOLVERS} (generated C)",
            "build the NMPC to export with NMPCSettings(linear_solver='sparse_lu')",
        )
    yu, (uu, lo, hi) = pred.unit(s.output), _bias(nmpc, pred, bias)
    law = nmpc.law_function()
    nm = law.nnz_in(0)
    states = [
        Variable(f"memory[{i + 1}]", "1", f"entry {i + 1} of the RTI's warm start (law memory)")
        for i in range(nm)
    ]
    integral = s.integral_gain > 0
    if integral:
        states.append(Variable("integral_offset", yu, "integral shift of the reference"))
    states.append(_held(uu, lo, hi))
    inputs = _mpc_inputs(nmpc, pred, uname, bias)
    params = []
    offsets = {  # the run-time inputs of the prediction that are not model parameters
        "disturbance.input": (uu, f"constant disturbance added to {uname} in the prediction"),
        "disturbance.output": (yu, f"constant disturbance added to {s.output} as predicted"),
    }
    for n, value in nmpc.parameters.items():
        if n in pred.variables:
            v = pred.variables[n]
            text = f"prediction model: {v.description or n}"
            params.append(Variable(n, v.unit, text, float(value), v.low, v.high))
        else:
            params.append(Variable(n, *offsets[n], float(value)))
    params.append(Variable("bias", uu, "command before the first sample", bias, lo, hi))
    x = cs.MX.sym("x", len(states))
    u, p = cs.MX.sym("u", len(inputs)), cs.MX.sym("p", len(params))
    memory, held = x[:nm], x[-1]
    ref = cs.fmin(cs.fmax(u[0], nmpc.clip.low), nmpc.clip.high)
    offset = x[nm] if integral else 0.0
    nodes = cs.fmin(cs.fmax(ref + offset, nmpc.clip.low), nmpc.clip.high)
    nxt, cmd = law(memory, u[2:], held, cs.repmat(nodes, s.horizon, 1), p[:-1])[:2]
    after = [nxt]
    if integral:  # no windup at a bound or at the rate limit (NonlinearMPC.update)
        at_rate = cs.fabs(cmd - held) >= s.rate_max * nmpc.dt * (1 - 1e-6)
        free = cs.logic_and(cs.logic_and(cmd > s.u_min, cmd < s.u_max), cs.logic_not(at_rate))
        step = s.integral_gain * nmpc.dt * (ref - u[1])
        after.append(cs.if_else(free, offset + step, offset))
    return SampledSystem(
        name,
        f"NMPC (real-time iteration, horizon {s.horizon}) of {uname} on {s.output} "
        f"(full state), sampled every {nmpc.dt:g} s (sarcomere)",
        nmpc.dt,
        tuple(states),
        tuple(inputs),
        (Variable("command", uu, f"{uname}, held between samples", low=lo, high=hi),),
        tuple(params),
        cs.Function("update", [x, u, p], [cs.vertcat(*after, cmd)]),
        cs.Function("output", [x, p], [held]),
        cs.Function("start", [u, p], [cs.vertcat(cs.DM.zeros(len(states) - 1), p[-1])]),
    )


def lmpc_system(lmpc: LinearMPC, model: Model, bias: float, name: str = "lmpc") -> SampledSystem:
    """A full-state ``lmpc`` (no estimator, ``disturbance = "none"``) as a sampled system,
    **at its present linearisation**: the update is :meth:`LinearMPC.law_function` (the
    condensed velocity-form QP, solved by ``settings.qp_solver``) with its QP data fixed
    at export (:meth:`LinearMPC.law_parameters`); the FMU does not re-linearise (the
    Python LMPC's commands while it does not either). The reference is clipped to the
    reachable range and held over the horizon (``preview = false``). Inputs: the reference,
    the measured output, the model's states and the soft-bounded signals by name;
    parameters ``u_min``, ``u_max``, ``du_max``, one ``<signal>.soft_min`` per soft bound
    (tunable) and ``bias`` (fixed). Units from the prediction model."""
    uname = _exportable("lmpc", lmpc, model)
    s, pred = lmpc.settings, lmpc.model
    uu, lo, hi = _bias(lmpc, pred, bias)
    law, soft = lmpc.law_function(), [n for n, _ in s.soft_min]
    nm = law.nnz_in(0)
    states = [
        Variable(f"memory[{i + 1}]", "1", f"entry {i + 1} of the LMPC's memory") for i in range(nm)
    ]
    states.append(_held(uu, lo, hi))
    inputs = _mpc_inputs(lmpc, pred, uname, bias)
    for n in soft:
        inputs.append(Variable(n, pred.unit(n), f"measured {n} (soft lower bound)"))
    p_law = lmpc.law_parameters()
    nb = 3 * len(lmpc.inputs) + len(soft)  # u_lo, u_hi, du_max, soft_min at the end
    params = _limits(uu, lo, hi, p_law[-nb + 2 * len(lmpc.inputs)])
    for n, v in s.soft_min:
        params.append(Variable(f"{n}.soft_min", pred.unit(n), f"soft lower bound of {n}", v))
    params.append(Variable("bias", uu, "command before the first sample", bias, lo, hi))
    x = cs.MX.sym("x", len(states))
    u, p = cs.MX.sym("u", len(inputs)), cs.MX.sym("p", len(params))
    nx = pred.nx
    ref = cs.fmin(cs.fmax(u[0], lmpc.clip.low), lmpc.clip.high)
    meas = cs.vertcat(u[2 : 2 + nx], u[1], u[2 + nx :])
    data = cs.vertcat(cs.DM(p_law[:-nb]), p[:-1])
    nxt, cmd = law(x[:nm], meas, x[-1], cs.repmat(ref, s.horizon + 1, 1), data)[:2]
    N, nu = s.horizon, len(lmpc.inputs)
    start = cs.vertcat(cs.DM.zeros(nx + 1), cs.repmat(p[-1], N * nu, 1), p[-1])
    return SampledSystem(
        name,
        f"LMPC (velocity form, horizon {N}, fixed linearisation) of {uname} on {s.output} "
        f"(full state), sampled every {lmpc.dt:g} s (sarcomere)",
        lmpc.dt,
        tuple(states),
        tuple(inputs),
        (Variable("command", uu, f"{uname}, held between samples", low=lo, high=hi),),
        tuple(params),
        cs.Function("update", [x, u, p], [cs.vertcat(nxt, cmd)]),
        cs.Function("output", [x, p], [x[-1]]),
        cs.Function("start", [u, p], [start]),
    )


def _exportable(slug: str, mpc, model: Model) -> str:
    """The name of the input of an MPC (``slug`` "nmpc" or "lmpc") whose law can be
    exported; refused: one with its own disturbance filter, a QP solver without C
    generation, or a plant ``model`` without the tracked output and the input."""
    if mpc.disturbance != "none":
        raise ParameterError(
            "controller",
            f"{slug} (disturbance '{mpc.disturbance}')",
            f"an {slug.upper()} with disturbance 'none' (its disturbance filter is not exported)",
        )
    _generated(slug, mpc.settings.qp_solver)
    (uname,) = mpc.inputs
    for n in (mpc.settings.output, uname):
        if n not in model.signal_names:
            raise ParameterError(
                "model", model.name, f"a plant with the {slug.upper()}'s signal '{n}'"
            )
    return uname


def _generated(slug: str, solver: str) -> None:
    """Refuse a QP solver whose generated C cannot be compiled into the FMU."""
    if solver not in GENERATED_QP:
        raise ParameterError(
            f"{slug}.qp_solver", solver, f"one of {GENERATED_QP} (C code generation)"
        )


def _what(controller) -> str:
    """A controller's kind for messages: its slug and solver, or its estimator."""
    if isinstance(controller, OnEstimate):
        return f"{controller.slug} (on an EKF: the estimator is not exported)"
    solver = getattr(controller, "solver", None)  # the converged NMPC's NLP solver
    return f"{getattr(controller, 'slug', type(controller).__name__)}" + (
        f" (solver {solver!r})" if solver else ""
    )


def export_controller_fmu(
    controller: PID | LQI | NonlinearMPC | LinearMPC,
    model: Model,
    path: str | Path,
    bias: float,
    fmi_version: int = 2,
    name: str | None = None,
    stop_time: float | None = None,
) -> Path:
    """Write ``controller`` (a PID, a full-state LQI, a full-state RTI NMPC or LMPC) as a
    Co-Simulation FMU; see :func:`pid_system`, :func:`lqi_system`, :func:`nmpc_system`
    and :func:`lmpc_system`.

    Parameters
    ----------
    controller : PID, LQI, NonlinearMPC or LinearMPC
        The controller; its sample time is the FMU's period.
    model : Model
        The plant it controls: the units of its output and input.
    path : str or Path
        The ``.fmu`` file to write (its folder must exist).
    bias : float
        The command before the first sample [input unit], in the controller's bounds.
    fmi_version : int
        2 or 3.
    name : str, optional
        The model name and identifier (default the controller's slug).
    stop_time : float, optional
        The default experiment's stop time [s].

    Returns
    -------
    Path
        ``path``.

    Raises
    ------
    ParameterError
        For a controller without an exported law (a controller on an EKF, an NMPC solved
        by ipopt or fatrop, an NMPC or LMPC with a disturbance filter), a bias
        outside the bounds, a bad version or path.
    """
    builders = {PID: pid_system, LQI: lqi_system, NonlinearMPC: nmpc_system, LinearMPC: lmpc_system}
    build = builders.get(type(controller))
    if build is None:
        raise ParameterError(
            "controller", _what(controller), "a PID, an LQI, an NMPC or an LMPC (the exported laws)"
        )
    system = build(controller, model, bias, name or controller.slug)
    experiment = Experiment(stop_time=stop_time, step_size=controller.dt)
    return export_sampled_fmu(system, path, fmi_version, experiment=experiment)
