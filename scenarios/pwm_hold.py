"""Scenario kind "pwm_hold": a chain on a PWM-driven 3/2 valve holding a length, against
the proportional regulator doing the same job (issue 26).

``[model]``, ``[model.options]`` (hanging set-up), ``[parameters]`` and ``[solver]`` as
kind "closed_loop" (the regulator plant); the valve plant is the same set-up with
``supply = "valve_pwm"``. ``[control]``:

- ``output``: the held signal (default "myofibril.length");
- ``hold_pressure``: the held value is the output's equilibrium at this regulator command;
  each plant starts at its own equilibrium there (the valve's at the duty that holds it,
  on its averaged level; a switched plant then runs :data:`PREROLL_S` at that duty
  before t = 0, to start on its periodic orbit);
- ``pressure_max``: the regulator command's upper bound (default 0.3 MPa);
- ``regulator_sample_time``: the regulator PI's sample time (default 10 ms); the duty's
  controllers sample once per PWM period;
- ``frequencies``: the PWM frequencies of the PI runs (default 20, 50, 100 Hz, each
  20-100 Hz);
- ``nmpc_frequency``: the PWM frequency of the NMPC run (default 50 Hz; ``"0 Hz"``: none);
- ``points_per_period``: output points per sample (default 20: the ripple resolved);
- ``averaged_frequency``: the frequency (one of ``frequencies``, default 50 Hz) whose PI
  also runs on the averaged valve;
- ``[control.disturbance]``: ``load`` (added mass) at ``time``;
- ``[control.valve]``: valve options (:class:`~sarcomere.dynamics.supply.ValveOptions`,
  with units) other than ``frequency`` and ``level``.

Runs: ``regulator_pi`` (the IMC-tuned PI of the registry on the regulator command),
``pwm<f>_pi`` (the same PI design on the duty cycle, switched valve), ``pwm<f>_pi_averaged``
(the ``averaged_frequency`` PI on the averaged valve: its deviation from the switched
run, ``pwm<f>_averaged_deviation_mm`` over the run and ``..._held_mm`` before the
disturbance, against ``pwm<f>_averaged_predicted_error_mm``; ``pwm<f>_averaged_cpu_ratio``
the CPU times side by side), ``pwm<f>_nmpc`` (the NMPC
on the duty: its prediction is the averaged valve, no disturbance estimate). Metrics per
run: ``rmse_mm`` (the whole run, at every output point), ``disturbance_peak_mm``,
``ripple_pp_mm`` and ``ripple_pp_kPa`` (peak to peak of the output and of the first
chamber's pressure over the last 10 % of the run), ``air_used_mg`` (the supply's flow
integrated; the regulator's: the chain's inflow, venting not counted back) and
``cpu_s`` (process time of the run).
"""

from __future__ import annotations

import math
import time
from pathlib import Path

import numpy as np
from scipy.optimize import brentq

from sarcomere.controllers import make_controller, operating_point
from sarcomere.dynamics.errors import ParameterError
from sarcomere.dynamics.fidelity.ripple import predict
from sarcomere.dynamics.results import Result
from sarcomere.dynamics.simulation.simulator import Simulator
from sarcomere.dynamics.supply import ValveOptions

from .binding import bind, fidelity_level, solver_settings
from .output import RunOutput
from .runner import register_runner
from .spec import Scenario, describe, quantity, unknown_key

KEYS = (
    "output",
    "hold_pressure",
    "pressure_max",
    "regulator_sample_time",
    "frequencies",
    "nmpc_frequency",
    "averaged_frequency",
    "points_per_period",
    "disturbance",
    "valve",
)
U_VALVE, U_REG = "valve.cmd", "regulator.p_cmd"
NMPC_DUTY = {"input_std": 0.01, "rate_max": 20.0, "weight_du": 10.0, "disturbance": "none"}
"""The NMPC's settings scaled for a duty cycle (its defaults are for a command in Pa: 2 kPa
of input noise, 2 MPa/s, ``weight_du`` 1e-9 per Pa^2): 0.01 of duty, 20 /s (a full swing
in 50 ms), ``weight_du`` 10 per duty^2 (the same weight on a tenth of the range); no
disturbance estimate (the ripple breaks its one-step residual: with ``"load"`` it
diverged at 50 Hz)."""


PREROLL_S = 1.5
"""Time [s] a PWM plant runs at the held duty before t = 0, so that it starts on its
periodic orbit: from the averaged equilibrium the switched plant's load mode (about
7 Hz, lightly damped) rings by some 2 mm, decayed to the ripple within about 1 s."""


def _loop(model, controller, op, ref, stop, dist, settings, points, record, output):
    """The sampled loop with ``points`` outputs per sample: (Result, cpu seconds)."""
    sim = Simulator(model, settings)
    u_now = {n: float(v) for n, v in zip(model.input_names, op.u, strict=True)}
    dt = controller.dt
    # a PWM plant starts on its periodic orbit: PREROLL_S of the held duty before t = 0
    t0 = -math.ceil(PREROLL_S / dt) * dt if model.modulators else 0.0
    sim.reset(x0=op.x, z0=op.z, t0=t0)
    sim.p = op.p.copy()
    if t0 < 0:
        sim.advance(u_now, [0.0])
    controller.reset(u_now)
    n = int(math.floor(stop / dt + 1e-9))
    f = model.signals_function(record, points)
    start = model.signals_function(record)(sim.x, sim.z, sim.u, sim.p)
    T, S = [np.zeros(1)], [np.array(start)]
    disturbed = dist is None
    tic = time.process_time()
    for k in range(n):
        tk = k * dt
        if not disturbed and tk >= dist[0] - 1e-12:
            sim.p = sim.p.copy()
            sim.p[model.param_names.index("load.m")] += dist[1]
            disturbed = True
        y = sim.signals(controller.outputs)
        u_now.update(controller.checked(tk, y, {output: ref}))
        times = tk + dt * np.arange(1, points + 1) / points
        X, Z, U = sim.advance(u_now, times)
        T.append(times)
        S.append(np.array(f(X.T, Z.T, U.T, sim.p)))
    cpu = time.process_time() - tic
    data = np.hstack(S)
    raw = {name: data[i] for i, name in enumerate(record)}
    # every run the same columns (the plots overlay them): the output, the reference,
    # the first chamber's pressure, the command as a fraction of its range, the air flow
    inp, chamber, air = record[1], record[2], record[3:]
    var = model.variables[inp]
    signals = {
        output: raw[output],
        "reference": np.full(data.shape[1], ref),
        "chamber_p_gauge": raw[chamber],
        "command_fraction": (raw[inp] - var.low) / (controller.u_max[inp] - var.low),
        "air_flow": np.maximum(np.sum([raw[a] for a in air], axis=0), 0.0),
    }
    units = {output: model.unit(output), "reference": model.unit(output)}
    units |= {"chamber_p_gauge": "Pa", "command_fraction": "1", "air_flow": "kg/s"}
    return Result("time", "s", np.concatenate(T), signals, units), cpu


def _ripple(y: np.ndarray, tail: np.ndarray, points: int) -> float:
    """The median over the samples in ``tail`` of the peak to peak of ``y`` within each
    sample (``points`` outputs after its start), less the line through its ends: the
    ripple at the sampling (PWM) period, without the slower motion of the loop."""
    first = int(np.argmax(tail))
    first += (points - (first - 1) % points) % points  # a sample's start (row 0 is t = 0)
    spans = []
    for a in range(first, len(y) - points, points):
        w = y[a : a + points + 1]
        spans.append(np.ptp(w - np.linspace(w[0], w[-1], len(w))))
    return float(np.median(spans)) if spans else 0.0


def _metrics(res: Result, output: str, dist, points: int) -> dict:
    t, y = res.index, res[output]
    err = y - res["reference"]
    tail = t >= 0.9 * t[-1]
    flow = res["air_flow"]
    out = {
        "rmse_mm": float(np.sqrt(np.mean(err**2))) * 1e3,
        "ripple_pp_mm": _ripple(y, tail, points) * 1e3,
        "ripple_pp_kPa": _ripple(res["chamber_p_gauge"], tail, points) * 1e-3,
        "air_used_mg": float(np.sum(0.5 * (flow[1:] + flow[:-1]) * np.diff(t))) * 1e6,
    }
    if dist is not None:
        out["disturbance_peak_mm"] = float(np.max(np.abs(err[t >= dist[0]]))) * 1e3
    return out


def run_pwm_hold(sc: Scenario, out_dir: Path) -> RunOutput:
    ctl = dict(sc.control)
    for key in ctl:
        if key not in KEYS:
            raise sc.error(("control", key), unknown_key(key, list(KEYS)))
    b = bind(sc)
    if b.setup != "hanging":
        raise sc.error(("model", "options", "setup"), "pwm_hold holds a hanging load")
    fid = fidelity_level(sc, allow_auto=False)
    output = str(ctl.get("output", "myofibril.length"))
    path = ("control",)
    p_hold = quantity(sc, ctl.get("hold_pressure", "0.15 MPa"), (*path, "hold_pressure"), "Pa", 0)
    p_max = quantity(sc, ctl.get("pressure_max", "0.3 MPa"), (*path, "pressure_max"), "Pa", 0)
    dt_reg = quantity(
        sc, ctl.get("regulator_sample_time", "10 ms"), (*path, "regulator_sample_time"), "s"
    )
    freqs = [
        quantity(sc, f, (*path, "frequencies"), "Hz", 0.0)
        for f in ctl.get("frequencies", ["20 Hz", "50 Hz", "100 Hz"])
    ]
    if not freqs or any(not 20.0 <= f <= 100.0 for f in freqs):
        raise sc.error((*path, "frequencies"), f"{freqs} Hz: give PWM frequencies in [20, 100] Hz")
    f_nmpc = quantity(sc, ctl.get("nmpc_frequency", "50 Hz"), (*path, "nmpc_frequency"), "Hz", 0)
    f_avg = quantity(
        sc, ctl.get("averaged_frequency", "50 Hz"), (*path, "averaged_frequency"), "Hz", 0
    )
    if f_avg not in freqs:
        raise sc.error((*path, "averaged_frequency"), f"{f_avg:g} Hz: one of {freqs} Hz")
    points = int(ctl.get("points_per_period", 20))
    if not 2 <= points <= 200:
        raise sc.error((*path, "points_per_period"), f"{points}: give 2 to 200")
    dist = None
    if "disturbance" in ctl:
        d = ctl["disturbance"]
        dist = (
            quantity(sc, d.get("time"), (*path, "disturbance", "time"), "s", 0.0),
            quantity(sc, d.get("load"), (*path, "disturbance", "load"), "kg"),
        )
    valve_raw = dict(ctl.get("valve", {}))
    for key in ("frequency", "level"):
        if key in valve_raw:
            raise sc.error((*path, "valve", key), "set by the scene's runs; remove it")
    try:
        ValveOptions.from_mapping(valve_raw)
    except ParameterError as exc:
        raise sc.error((*path, "valve"), describe(exc)) from None
    reg = b.build(fid)
    stop, settings = sc.simulation.stop_time, solver_settings(sc, reg)
    op_reg = operating_point(reg, {U_REG: p_hold}, b.overrides)
    y_hold = op_reg[output]

    def valve_model(f, level="switched"):
        opts = {**valve_raw, "frequency": f, "level": level}
        return reg.setup.build(supply="valve_pwm", valve=opts, regulator_p_max=None)

    results, metrics, cpu, extra = {}, {}, {}, {"held": {output: y_hold}}
    chambers = [k for k in reg.signal_names if k.endswith("aps1.chamber.p_gauge")]
    tubes = [k for k in reg.signal_names if k.endswith(".m_flow") and ".tube" in k]
    runs = [("regulator_pi", reg, U_REG, dt_reg, "pid", {"u_max": p_max}, tubes)]
    for f in freqs:
        tag = f"pwm{f:g}"
        runs.append((f"{tag}_pi", valve_model(f), U_VALVE, 1 / f, "pid", {}, None))
        if f == f_avg:
            m_avg = valve_model(f, "averaged")
            runs.append((f"{tag}_pi_averaged", m_avg, U_VALVE, 1 / f, "pid", {}, None))
    if f_nmpc > 0:
        runs.append(
            (
                f"pwm{f_nmpc:g}_nmpc",
                valve_model(f_nmpc),
                U_VALVE,
                1 / f_nmpc,
                "nmpc",
                NMPC_DUTY,
                None,
            )
        )
    duty_hold = None
    for key, model, inp, dt, slug, own, air in runs:
        if inp == U_VALVE:
            duty_hold = duty_hold or _hold_duty(model, output, y_hold, b.overrides)
            op = operating_point(model, {inp: duty_hold}, b.overrides)
            air = ["valve_source.m_flow"]
        else:
            op = op_reg
        task = {"output": output, "input": inp, "u_min": 0.0, "u_max": 1.0, **own}
        try:
            controller = make_controller(slug, model, op, dt, task)
        except ParameterError as exc:
            raise sc.error(("control",), describe(exc)) from None
        record = [output, inp, chambers[0], *air]
        res, cpu[key] = _loop(
            model, controller, op, y_hold, stop, dist, settings, points, record, output
        )
        res.meta.update({"controller": slug, "sample_time_s": dt})
        results[key] = res
        run_metrics = _metrics(res, output, dist, points) | {"cpu_s": cpu[key]}
        metrics.update({f"{key}_{k}": v for k, v in run_metrics.items()})
    f0 = f"pwm{f_avg:g}"
    sw, av = results[f"{f0}_pi"], results[f"{f0}_pi_averaged"]
    pred = predict(valve_model(f_avg), duty_hold, [output], b.overrides)
    gap = np.abs(sw[output] - av[output])
    metrics[f"{f0}_averaged_deviation_mm"] = float(np.max(gap)) * 1e3
    metrics[f"{f0}_averaged_deviation_held_mm"] = (
        float(np.max(gap[sw.index < dist[0]])) * 1e3 if dist else float(np.max(gap)) * 1e3
    )
    metrics[f"{f0}_averaged_predicted_error_mm"] = pred.error[output] * 1e3
    metrics[f"{f0}_averaged_cpu_ratio"] = cpu[f"{f0}_pi"] / cpu[f"{f0}_pi_averaged"]
    extra["hold_duty"] = duty_hold
    extra["predicted_ripple"] = {
        "pressure_pp_Pa": pred.pressure_ripple,
        "mean_shift_Pa": pred.mean_shift,
        "tau_on_s": pred.tau_on,
        "tau_off_s": pred.tau_off,
        "period_s": pred.period,
    }
    extra["nmpc_settings"] = NMPC_DUTY
    return RunOutput(
        sc.name,
        fid,
        f"{settings.method} plants; the duty's controllers sample once per PWM period, the "
        f"regulator's every {dt_reg * 1e3:g} ms; CPU times are process times under load",
        metrics=metrics,
        results=results,
        extra=extra,
    )


def _hold_duty(model, output: str, y_hold: float, overrides: dict) -> float:
    """The duty whose (averaged) equilibrium holds ``output`` at ``y_hold``."""

    def gap(d: float) -> float:
        return operating_point(model, {U_VALVE: d}, overrides)[output] - y_hold

    try:
        return float(brentq(gap, 0.02, 0.98, xtol=1e-6))
    except ValueError:
        raise ParameterError(
            "hold_pressure", y_hold, "a value the valve can hold at a duty in [0.02, 0.98]"
        ) from None


register_runner("pwm_hold", run_pwm_hold)
