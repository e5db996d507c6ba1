"""Scenario kind "closed_loop": controllers on the plant in the sampled loop, compared.

``[model]`` and ``[parameters]`` as kind "transient" (the plant: exact ISO 6358 flow law,
saturating regulator); ``[simulation] stop_time``; ``[solver]`` the plant's integrator.
``[control]``:

- ``output``: the tracked signal ("myofibril.length", "sensor.f");
- ``operating_pressure``: the start equilibrium's regulator command;
- the input limits, one set applied to every controller of the scene (like for like; a
  controller's own table may not set them): ``pressure_min`` and ``pressure_max``, the
  command's bounds (default 0 and 0.1 MPa), and ``pressure_rate_max``, its largest rate
  (default :data:`RATE_MAX_DEFAULT`, the MPCs' own default; each controller takes it as
  its ``rate_max`` setting);
- ``sample_time`` (default 10 ms; from 1 ms to the plant's slowest time constant, see
  :func:`~sarcomere.controllers.registry.check_sample_time`); ``seed`` of the noise
  (default 0); ``tension_min``: the thread tension bound (default 0 N), handed to every
  controller that can state it (the MPCs) and checked on the plant for all;
- ``preview``: whether the reference is known ahead (default true, as for every packaged
  scene's planned steps and sines): a controller that takes it (the NMPC, the LMPC) then
  sees the reference at each node of its horizon; false gives it ``r(t)`` held over the
  horizon, for comparison. The PID and LQI use ``r(t)`` either way;
- ``measured``: the signals a realistic sensor set gives (default the output and
  ``regulator.p_out``), read by estimators;
- ``[control.noise]``: measurement noise standard deviation by signal, with units;
- ``[control.reference]``, in the output's unit, relative to its operating value:
  ``step`` at ``step_time``, and ``sines`` (a list of ``{frequency, start, periods}``)
  of ``sine_amplitude`` around the stepped level, each starting at zero phase;
- ``[control.disturbance]``: ``load`` (an added mass) at ``time``;
- ``[control.controllers.<key>]``: one run per key; ``type`` is the registered slug
  (default the key), every other entry is the controller's own setting (SI numbers,
  or text such as ``estimator = "ekf"``).

Metrics, prefixed by the key: ``rmse_mm`` (force: ``rmse_N``), ``overshoot_pct`` and
``settling_time_s`` of the step (judged up to the next change of the reference less the
controller's preview horizon, or the disturbance:
:func:`~sarcomere.controllers.metrics.step_window_end`), ``tension_violation_max_mN`` and
``tension_violation_time_s`` (how far and how long the plant's threads broke
``tension_min``, more than 1 mN for the time:
:func:`~sarcomere.controllers.metrics.tension_violation`), ``solve_time_median_ms``,
``solve_time_p95_ms``, ``fallbacks``, and per sine ``rmse_sine_<f>_mm``, and
``disturbance_peak_mm`` (largest error from the disturbance to the next event). Each run's
status ("ok", "limit cycle", "diverged", "all fallback":
:func:`~sarcomere.controllers.metrics.loop_status`) is in ``summary.json`` (``status``,
``status_reason``) and a row of the printed table. Where each
controller gets its states (:func:`estimator_of`) is in the printed header and
``summary.json`` (``estimators``). One result (CSV, curves) per key.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from pathlib import Path

import numpy as np

from sarcomere.dynamics.errors import ParameterError

from .binding import Binding, bind, check_n, fidelity_level, solver_settings
from .output import RunOutput, quantity_tag
from .runner import register_runner
from .spec import Scenario, describe, did_you_mean, quantity, unknown_key

P_CMD = "regulator.p_cmd"
RATE_MAX_DEFAULT = "2 MPa/s"
"""The scene's default rate limit of the command: the MPCs' own default
(:class:`~sarcomere.controllers.lmpc.LMPCSettings`), a tenth of the 0.1 MPa range per
10 ms sample times two, slow against the regulator's 50 ms lag."""
LIMITS = ("u_min", "u_max", "rate_max")
"""Controller settings the scene's limits set: refused in a controller's own table."""
KEYS = (
    "output",
    "operating_pressure",
    "pressure_min",
    "pressure_max",
    "pressure_rate_max",
    "sample_time",
    "seed",
    "tension_min",
    "preview",
    "measured",
    "noise",
    "reference",
    "disturbance",
    "controllers",
)
REFERENCE_KEYS = ("step", "step_time", "sine_amplitude", "sines")


def _table(sc: Scenario, value: object, path: tuple, allowed=None) -> Mapping:
    if not isinstance(value, Mapping):
        raise sc.error(path, f"expected a table, got {value!r}")
    for key in value:
        if allowed is not None and key not in allowed:
            raise sc.error((*path, key), unknown_key(key, list(allowed)))
    return value


def _reference(sc: Scenario, tbl: dict, unit: str, y_op: float, stop: float):
    """``r(t)``, the events (times where the reference changes character) and the step;
    a step or a sine that starts at or after the end of the run ``stop`` is refused."""
    path = ("control", "reference")
    _table(sc, tbl, path, REFERENCE_KEYS)
    step = quantity(sc, tbl.get("step", 0.0), (*path, "step"), unit)
    t_step = quantity(sc, tbl.get("step_time", 0.0), (*path, "step_time"), "s", 0.0)
    if step and t_step >= stop:
        raise sc.error(
            (*path, "step_time"),
            f"{t_step:g} s is at or after the end of the run ([simulation] stop_time = "
            f"{stop:g} s): the step would never be taken",
        )
    amp = quantity(sc, tbl.get("sine_amplitude", 0.0), (*path, "sine_amplitude"), unit)
    sines = []
    raw = tbl.get("sines", [])
    if not isinstance(raw, list):
        raise sc.error((*path, "sines"), f"expected a list of tables, got {raw!r}")
    for i, item in enumerate(raw):
        p = (*path, "sines")
        item = _table(sc, item, p, ("frequency", "start", "periods"))
        f = quantity(sc, item.get("frequency"), p, "Hz", 0.0)
        start = quantity(sc, item.get("start"), p, "s", 0.0)
        periods = item.get("periods", 1)
        if f <= 0 or isinstance(periods, bool) or not isinstance(periods, int) or periods < 1:
            raise sc.error(p, f"sine {i + 1}: need frequency > 0 and periods an integer >= 1")
        if start >= stop:
            raise sc.error(
                p,
                f"sine {i + 1} starts at {start:g} s, at or after the end of the run "
                f"([simulation] stop_time = {stop:g} s): it could not be scored",
            )
        sines.append((f, start, start + periods / f))

    def reference(t: float) -> float:
        r = y_op + (step if t >= t_step else 0.0)
        for f, a, b in sines:
            if a <= t < b:
                r += amp * math.sin(2 * math.pi * f * (t - a))
        return r

    return reference, t_step, step, sines


SCENE_KEYS = {
    "dt": "sample_time",
    "u_min": "pressure_min",
    "u_max": "pressure_max",
    "rate_max": "pressure_rate_max",
    "measured": "measured",
    "noise_std": "noise",
}
"""A controller setting the scene sets -> the ``[control]`` key it comes from."""


def _blamed(name: str, slug: str, path: tuple) -> tuple:
    """The scene key a controller's ParameterError ``name`` is about: ``lqi.ekf.substeps``
    -> ``(*path, "ekf", "substeps")``, ``lqi.dt`` -> ``("control", "sample_time")``."""
    parts = name.split(".")
    if parts[0] == slug and len(parts) > 1:
        parts = parts[1:]
    for key in parts[: 1 + (parts[0] == "ekf")]:
        if key in SCENE_KEYS:
            return ("control", SCENE_KEYS[key])
    return (*path, *parts)


def estimator_of(controller, measured: list[str]) -> str:
    """Where ``controller`` gets its states: ``"ekf"`` (an extended Kalman filter fed the
    ``measured`` signals), ``"measured"`` (output feedback on the measured signals only, the
    PID) or ``"exact states"`` (state feedback reading the plant's states, noise-free)."""
    from sarcomere.controllers.estimated import OnEstimate

    if isinstance(controller, OnEstimate) or getattr(controller, "estimator", None) is not None:
        return "ekf"
    return "measured" if set(controller.outputs) <= set(measured) else "exact states"


def _builder(b: Binding):
    """``build_model(fidelity, flow_law, saturate)``: the scene's set-up at another fidelity
    level or flow law (a controller's prediction model; the plant is the scene's own)."""

    def build_model(fidelity: str = "full", flow_law: str | None = None, saturate: bool = True):
        return b.build(fidelity, flow_law=flow_law, saturate=saturate)

    return build_model


def run_closed_loop_scene(sc: Scenario, out_dir: Path) -> RunOutput:
    """Run every ``[control.controllers]`` entry on the same plant and reference."""
    # imported here: python-control and scipy.signal cost about 1 s, paid by control scenes only
    from sarcomere.controllers import CONTROLLERS, make_controller, operating_point
    from sarcomere.controllers.loop import Disturbance, check_disturbance, run_closed_loop
    from sarcomere.controllers.metrics import UNIT_SCALES

    sc.refuse_unused("inputs", "sweep", "outputs.tolerance", "cosim")
    b = bind(sc)
    fid = fidelity_level(sc, allow_auto=False)
    check_n(sc, ("model", "n"), b.n, fid)
    if sc.simulation is None:
        raise sc.error(("simulation",), "a closed loop needs [simulation] stop_time")
    if sc.simulation.output_interval is not None or sc.simulation.start_time:
        raise sc.error(("simulation",), "only stop_time: the samples are the output grid")
    ctl = _table(sc, sc.control, ("control",), KEYS)
    model = b.build(fid)
    output = ctl.get("output")
    if output not in model.signal_names:
        raise sc.error(("control", "output"), f"{output!r} is not a signal of the model")
    unit = model.unit(output)
    dt = quantity(sc, ctl.get("sample_time", "10 ms"), ("control", "sample_time"), "s", 0.0)
    p_op = quantity(sc, ctl.get("operating_pressure"), ("control", "operating_pressure"), "Pa", 0.0)
    p_min = quantity(sc, ctl.get("pressure_min", 0.0), ("control", "pressure_min"), "Pa", 0.0)
    p_max = quantity(sc, ctl.get("pressure_max", "0.1 MPa"), ("control", "pressure_max"), "Pa")
    high = model.variables[P_CMD].high
    if not (p_min <= p_op <= p_max <= high and 0 < p_op and p_min < p_max):
        # blame the limit that is out of place, else the operating point between them
        bad = "pressure_max" if p_max > high or p_max <= p_min else "operating_pressure"
        raise sc.error(
            ("control", bad),
            f"need pressure_min ({p_min:g} Pa) <= operating_pressure ({p_op:g} Pa) <= "
            f"pressure_max ({p_max:g} Pa) <= the regulator's {high:g} Pa, with "
            "operating_pressure > 0 and pressure_min < pressure_max",
        )
    rate = ("control", "pressure_rate_max")
    rate_max = quantity(sc, ctl.get("pressure_rate_max", RATE_MAX_DEFAULT), rate, "Pa/s", 0.0)
    if rate_max <= 0:
        raise sc.error(rate, f"{rate_max:g} Pa/s: expected a rate > 0")
    seed = ctl.get("seed", 0)
    if isinstance(seed, bool) or not isinstance(seed, int) or seed < 0:
        raise sc.error(("control", "seed"), f"{seed!r}: expected an integer >= 0")
    t_min = quantity(sc, ctl.get("tension_min", 0.0), ("control", "tension_min"), "N")
    preview = ctl.get("preview", True)
    if not isinstance(preview, bool):
        raise sc.error(("control", "preview"), f"{preview!r}: expected true or false")
    measured = ctl.get("measured", [output, "regulator.p_out"])
    if not (
        isinstance(measured, list)
        and measured
        and all(isinstance(m, str) and m in model.signal_names for m in measured)
    ):
        raise sc.error(
            ("control", "measured"), f"{measured!r}: expected a non-empty list of signals"
        )
    noise = {}
    for name, raw in _table(sc, ctl.get("noise", {}), ("control", "noise")).items():
        if name not in model.signal_names:
            hint = did_you_mean(name, [*measured, *model.signal_names])
            raise sc.error(("control", "noise", name), f"not a signal of the model{hint}")
        if name not in measured:
            raise sc.error(
                ("control", "noise", name),
                f"noise on a signal that is not measured (measured = {measured}): "
                "add it to [control] measured, or remove its noise",
            )
        noise[name] = quantity(sc, raw, ("control", "noise", name), model.unit(name), 0.0)
    op = operating_point(model, {P_CMD: p_op}, b.overrides)
    y_op = op[output]
    stop = sc.simulation.stop_time
    reference, t_step, step, sines = _reference(sc, ctl.get("reference", {}), unit, y_op, stop)
    dist = None
    if "disturbance" in ctl:
        path = ("control", "disturbance")
        d = _table(sc, ctl["disturbance"], path, ("load", "time"))
        if "load.m" not in model.param_names:
            raise sc.error(path, "the set-up holds no load to disturb")
        dist = Disturbance(
            quantity(sc, d.get("time"), (*path, "time"), "s", 0.0),
            "load.m",
            quantity(sc, d.get("load"), (*path, "load"), "kg"),
        )
        try:
            check_disturbance(model, op, dist, stop)
        except ParameterError as exc:
            key = "time" if exc.name == "disturbance.time" else "load"
            raise sc.error((*path, key), describe(exc)) from None
    events = sorted({stop, *(a for _, a, _ in sines), *([dist.time] if dist else [])})
    changes = sorted({stop, *(a for _, a, _ in sines)})  # where the reference changes
    reach = sorted(operating_point(model, {P_CMD: v}, b.overrides)[output] for v in (p_min, p_max))
    entries = _table(sc, ctl.get("controllers", {}), ("control", "controllers"))
    if not entries:
        raise sc.error(("control", "controllers"), "no controllers to run")
    settings = solver_settings(sc, model)
    scale, suffix = UNIT_SCALES.get(unit, (1.0, unit))
    metrics, results, estimators, status, reasons = {}, {}, {}, {}, {}
    for key, raw in entries.items():
        path = ("control", "controllers", key)
        own = dict(_table(sc, raw, path))
        slug = own.pop("type", key)
        for name in LIMITS:
            if name in own:
                raise sc.error(
                    (*path, name),
                    "the input limits are the scene's (pressure_min, pressure_max, "
                    "pressure_rate_max in [control]): one set for every controller",
                )
        if slug not in CONTROLLERS:
            raise sc.error((*path, "type"), f"'{slug}' is not one of {sorted(CONTROLLERS)}")
        task = {
            "output": output,
            "input": P_CMD,
            "u_min": p_min,
            "u_max": p_max,
            "rate_max": rate_max,
            "measured": list(measured),
            "noise_std": dict(noise),
            "tension_min": t_min,
            "build_model": _builder(b),
            "overrides": dict(b.overrides),
            **own,
        }
        try:
            controller = make_controller(slug, model, op, dt, task)
        except ParameterError as exc:
            raise sc.error(_blamed(exc.name, slug, path), describe(exc)) from None
        step_next = next((e for e in changes if e > t_step), stop)
        try:
            run = run_closed_loop(
                model,
                controller,
                op,
                reference,
                stop,
                output=output,
                settings=settings,
                noise_std=noise,
                seed=seed,
                disturbance=dist,
                reachable=(reach[0], reach[1]),
                step=(y_op, y_op + step, t_step, step_next) if step else None,
                tension_min=t_min,
                preview=preview,
            )
        except ParameterError as exc:
            if exc.name != "step_time":
                raise
            raise sc.error(("control", "reference", "step_time"), describe(exc)) from None
        res = run.result
        err = res[output] - res["reference"]
        for f, a, b_end in sines:
            keep = (res.index >= a) & (res.index < b_end)
            rms = float(np.sqrt(np.mean(err[keep] ** 2))) / scale if keep.any() else 0.0
            run.metrics[f"rmse_sine_{quantity_tag(f, 'Hz')}_{suffix}"] = rms
        if dist is not None:
            end = next((e for e in events if e > dist.time), stop)
            keep = (res.index >= dist.time) & (res.index < end)
            run.metrics[f"disturbance_peak_{suffix}"] = float(np.max(np.abs(err[keep]))) / scale
        metrics.update({f"{key}_{k}": v for k, v in run.metrics.items()})
        res.meta.update({"controller": slug, "sample_time_s": dt})
        results[key] = res
        estimators[key] = estimator_of(controller, measured)
        status[key] = run.status
        if run.status_reason:
            reasons[key] = run.status_reason
    extra = {
        "operating_point": {"pressure_Pa": p_op, output: y_op},
        "input_limits": {"u_min_Pa": p_min, "u_max_Pa": p_max, "rate_max_Pa_per_s": rate_max},
        "reachable": {output: reach},
        "reference_known_ahead": preview,
        "tension_min_N": t_min,
        "estimators": estimators,
        "status": status,
        "status_reason": reasons,
        "controllers": {k: dict(_table(sc, v, ("control",))) for k, v in entries.items()},
    }
    return RunOutput(
        sc.name,
        fid,
        f"{settings.method} plant, controllers sampled every {dt * 1e3:g} ms (zero-order hold); "
        "states from: " + ", ".join(f"{k} {v}" for k, v in estimators.items()),
        metrics=metrics,
        results=results,
        extra=extra,
    )


register_runner("closed_loop", run_closed_loop_scene)
