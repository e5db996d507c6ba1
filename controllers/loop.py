"""The sampled closed loop: a :class:`~sarcomere.dynamics.Simulator` driven by a
:class:`~.base.Controller` every ``dt`` seconds with zero-order hold.

At each sample ``t_k = k dt`` the loop reads the signals the controller asks for
(``controller.outputs``), adds seeded Gaussian noise to those named in ``noise_std``,
evaluates the reference (and, with ``preview``, its values at the controller's
``preview_samples`` next samples, handed over by :meth:`~.base.Controller.set_preview`),
calls :meth:`~.base.Controller.checked` (finite, inside the
bounds, timed) and holds its input over ``[t_k, t_k + dt)``. A load disturbance changes a
parameter (``load.m``) at the first sample at or after its time. The result holds, at the
samples: the reference, the true output, the measured output (with noise), the inputs,
the regulator and chamber pressures and every thread tension; its metrics; and its status
(:func:`~.metrics.loop_status`: a limit cycle, a divergence or a run that fell back on every
sample is said, not left to the numbers).

Examples
--------
>>> from sarcomere.dynamics import hanging_load
>>> from sarcomere.controllers import make_controller, operating_point
>>> m = hanging_load(n=1, load_kg=0.02)
>>> op = operating_point(m, {"regulator.p_cmd": 5e4})
>>> task = {"output": "myofibril.length", "input": "regulator.p_cmd", "u_min": 0.0,
...         "u_max": 1e5}
>>> pid = make_controller("pid", m, op, 0.01, task)
>>> y0 = op["myofibril.length"]
>>> run = run_closed_loop(m, pid, op, lambda t: y0 - 1e-3, 0.5, output="myofibril.length")
>>> bool(abs(run.result["myofibril.length"][-1] - (y0 - 1e-3)) < 2e-4)
True
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np

from sarcomere.dynamics.equilibrium import Equilibrium
from sarcomere.dynamics.errors import ParameterError
from sarcomere.dynamics.modeling.model import Model
from sarcomere.dynamics.results import Result
from sarcomere.dynamics.simulation.settings import SolverSettings
from sarcomere.dynamics.simulation.simulator import Simulator

from .base import Controller, ControllerStats
from .metrics import loop_metrics, loop_status, step_window_end


@dataclass(frozen=True)
class Disturbance:
    """A step change of a parameter during the run (an added weight: ``load.m``).

    Attributes
    ----------
    time : float
        When [s] (applied at the first sample at or after it).
    parameter : str
        Parameter path, e.g. ``"load.m"``.
    delta : float
        Change [SI of the parameter], e.g. 0.05 kg.
    """

    time: float
    parameter: str = "load.m"
    delta: float = 0.05


@dataclass
class ClosedLoopResult:
    """What a closed-loop run produced.

    Attributes
    ----------
    result : Result
        Signals at the sample times (see the module docstring); ``reference`` and
        ``measured`` are in the output's unit.
    metrics : dict
        :func:`~.metrics.loop_metrics` of the run (unprefixed).
    stats : ControllerStats
        The controller's solve times and fallbacks.
    status : str
        "ok", "limit cycle", "diverged" or "all fallback" (:func:`~.metrics.loop_status`).
    status_reason : str
        What was seen, when the status is not "ok".
    """

    result: Result
    metrics: dict[str, float]
    stats: ControllerStats = field(default_factory=ControllerStats)
    status: str = "ok"
    status_reason: str = ""


def recorded_signals(model: Model, output: str, inputs: list[str]) -> list[str]:
    """The signals a run records: the output, the inputs, the regulator and chamber
    pressures, every thread and tendon tension (in the model's order)."""
    keep = [output, *inputs]
    for name in model.signal_names:
        if (
            name == "regulator.p_out"
            or name.endswith(".chamber.p_gauge")
            or (".actin" in name and name.endswith(".T"))
            or name.endswith("_tendon.T")
        ):
            keep.append(name)
    return list(dict.fromkeys(keep))


def check_disturbance(model: Model, op: Equilibrium, d: Disturbance, stop_time: float) -> None:
    """Refuse a disturbance the run cannot apply: at a time outside ``[0, stop_time)``, on
    a parameter the model lacks, or one that moves the parameter out of its range (a
    negative added load larger than the load: a mass <= 0 sends the integrator off).

    Raises
    ------
    ParameterError
        Naming ``disturbance.time``, ``disturbance.parameter`` or ``disturbance.delta``.
    """
    if not (math.isfinite(d.time) and 0 <= d.time < stop_time):
        raise ParameterError("disturbance.time", d.time, f"[0, {stop_time:g}) s", "inside the run")
    if d.parameter not in model.param_names:
        raise ParameterError("disturbance.parameter", d.parameter, "a parameter of the model")
    var = model.variables[d.parameter]
    before = float(op.p[model.param_names.index(d.parameter)])
    after = before + d.delta
    if not (math.isfinite(after) and var.low <= after <= var.high):
        raise ParameterError(
            "disturbance.delta",
            d.delta,
            f"[{var.low - before:g}, {var.high - before:g}] {model.unit(d.parameter)}",
            f"{d.parameter} = {before:g} would become {after:g}, outside its range "
            f"[{var.low:g}, {var.high:g}]",
        )


MAX_SAMPLES = 10**6
"""Most samples of one closed-loop run: the recorded signals take ``samples x signals x
8`` bytes (160 MB at a million samples of twenty signals) and each sample costs 0.1-5 ms
of controller and plant (minutes to an hour). A million 10 ms samples are 2.8 hours of
plant time."""


def run_closed_loop(
    model: Model,
    controller: Controller,
    op: Equilibrium,
    reference: Callable[[float], float | Sequence[float]],
    stop_time: float,
    *,
    output: str | Sequence[str],
    settings: SolverSettings | None = None,
    noise_std: Mapping[str, float] | None = None,
    seed: int = 0,
    disturbance: Disturbance | None = None,
    reachable: tuple[float, float] | None = None,
    step: tuple[float, float, float, float] | None = None,
    tension_min: float = 0.0,
    preview: bool = False,
) -> ClosedLoopResult:
    """Run ``controller`` on ``model`` from the operating point ``op`` to ``stop_time``.

    Parameters
    ----------
    model : Model
        The plant.
    controller : Controller
        Sampled at ``controller.dt``.
    op : Equilibrium
        Start point (states, inputs, parameters).
    reference : callable
        ``reference(t)`` of the tracked ``output`` [SI] (a sequence, one per output, for
        several).
    stop_time : float
        End of the run [s] (the last sample is before it).
    output : str or sequence of str
        The tracked signal, or signals (a vector controller's): the metrics, the status,
        ``reachable`` and ``step`` are of the first; the others' references are recorded as
        ``<name>.reference``; ``preview`` is refused (it hands over one signal's).
    settings : SolverSettings, optional
        The plant's integrator (default CVODES, rtol 1e-6).
    noise_std : mapping, optional
        Measurement noise standard deviation by signal [SI]; others are exact.
    seed : int
        Seed of the noise.
    disturbance : Disturbance, optional
    reachable : (float, float), optional
        The output range the input can hold: a reference outside it is clipped, with one
        warning per run.
    step : (r_before, r_after, t_step, t_next), optional
        The reference step whose overshoot and settling time are measured, judged up to
        :func:`~.metrics.step_window_end`: the next change of the reference ``t_next``
        less the controller's preview horizon (``preview_samples * dt`` when ``preview``),
        or the disturbance or the end of the run if first.
    tension_min : float
        The thread tension bound [N] whose violation on the plant
        (:func:`~.metrics.tension_violation`, at the samples) is measured.
    preview : bool
        Whether the reference is known ahead: if so, before every update a controller with
        ``preview_samples > 0`` (the MPCs) gets ``reference`` at its next samples (clipped to
        ``reachable`` like ``r(t)``); a controller without preview sees ``r(t)`` either way.
    """
    dt = controller.dt
    tracked = [output] if isinstance(output, str) else list(output)
    output = tracked[0]
    if len(tracked) > 1 and preview and controller.preview_samples:
        raise ParameterError("preview", preview, "false with several tracked outputs")
    if not (math.isfinite(stop_time) and dt <= stop_time <= MAX_SAMPLES * dt):
        raise ParameterError(
            "stop_time",
            stop_time,
            f"[{dt:g}, {MAX_SAMPLES * dt:g}] s",
            f"one sample at least, at most {MAX_SAMPLES:g} samples of {dt:g} s",
        )
    noise = dict(noise_std or {})
    for name, std in noise.items():
        if name not in model.signal_names:
            raise ParameterError("noise_std", name, "a signal of the model")
        if not (math.isfinite(std) and std >= 0):
            raise ParameterError(f"noise_std.{name}", std, "[0, inf)")
    if disturbance is not None:
        check_disturbance(model, op, disturbance, stop_time)
    judged = None  # the step and the end of its window, checked before the run
    if step is not None:
        lead = controller.preview_samples * dt if preview else 0.0
        after = [stop_time]
        if disturbance is not None and disturbance.time > step[2]:
            after.append(disturbance.time)
        judged = (*step[:3], step_window_end(step[2], step[3], lead, min(after)))
    sim = Simulator(model, settings)
    sim.reset(x0=op.x, z0=op.z)
    sim.p = op.p.copy()
    u_now = {n: float(v) for n, v in zip(model.input_names, op.u, strict=True)}
    controller.reset(u_now)
    rng = np.random.default_rng(seed)
    record = recorded_signals(model, output, controller.inputs)
    record += [n for n in tracked[1:] if n not in record]
    n_samples = int(math.floor(stop_time / dt + 1e-9))
    others = np.empty((n_samples, len(tracked) - 1))  # the other outputs' references
    read = list(dict.fromkeys([*controller.outputs, *record]))
    t = np.arange(n_samples) * dt
    rows = np.empty((n_samples, len(record)))
    refs, meas = np.empty(n_samples), np.empty(n_samples)
    disturbed, clipped = disturbance is None, False
    for k, tk in enumerate(t):
        if not disturbed and tk >= disturbance.time - 1e-12:
            p = sim.p.copy()
            p[model.param_names.index(disturbance.parameter)] += disturbance.delta
            sim.p, disturbed = p, True
        sig = sim.signals(read)
        y = {n: sig[n] for n in controller.outputs}
        for name, std in noise.items():
            if name in y and std > 0:
                y[name] += std * rng.standard_normal()
        r, *rest = np.atleast_1d(reference(float(tk))).astype(float).tolist()
        others[k] = rest
        if preview and controller.preview_samples:
            ahead = [
                float(reference(float(tk + j * dt)))
                for j in range(1, 1 + controller.preview_samples)
            ]
            if reachable is not None:
                ahead = np.clip(ahead, reachable[0], reachable[1]).tolist()
            controller.set_preview({output: ahead})
        if reachable is not None and not reachable[0] <= r <= reachable[1]:
            r = min(max(r, reachable[0]), reachable[1])
            if not clipped:
                warnings.warn(
                    f"reference {output} outside the reachable [{reachable[0]:.6g}, "
                    f"{reachable[1]:.6g}] from t = {tk:g} s: clipped",
                    stacklevel=2,
                )
                clipped = True
        u_now.update(controller.checked(float(tk), y, dict(zip(tracked, [r, *rest], strict=True))))
        rows[k] = [sig[n] for n in record]
        for name in controller.inputs:  # the input held from t_k on
            rows[k, record.index(name)] = u_now[name]
        refs[k] = r
        meas[k] = y.get(output, sig[output])
        sim.step(u_now, dt)
    signals = {"reference": refs, "measured": meas}
    signals.update({f"{n}.reference": others[:, i] for i, n in enumerate(tracked[1:])})
    signals.update({n: rows[:, i] for i, n in enumerate(record)})
    unit = model.unit(output)
    units = {"reference": unit, "measured": unit} | {n: model.unit(n) for n in record}
    units |= {f"{n}.reference": model.unit(n) for n in tracked[1:]}
    result = Result("time", "s", t, signals, units)
    tensions = np.array([signals[n] for n in record if n.endswith(".T")])
    metrics = loop_metrics(
        unit,
        t,
        signals[output],
        refs,
        tensions,
        controller.stats.solve_times_s,
        judged,
        tension_min,
        dt,
    )
    metrics["fallbacks"] = float(controller.stats.fallbacks)
    status = loop_status(
        t,
        signals[output],
        refs,
        [disturbance.time] if disturbance is not None else [],
        reachable[1] - reachable[0] if reachable is not None else 0.0,
        controller.stats.fallbacks,
        unit,
    )
    return ClosedLoopResult(result, metrics, controller.stats, *status)
