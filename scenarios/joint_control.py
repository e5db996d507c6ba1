"""Scenario kind "joint_control": the antagonistic joint (``[model] name = "joint"``)
controlled as a two-input system: both regulators' commands on the joint angle and its
stiffness (issue 26).

``[control]``:

- ``co_contraction``: the stiffness levels, two or more, each given as the co-contraction
  (both commands, Pa) whose equilibrium at the joint's rest angle sets the stiffness
  reference (``stiffness.K`` there); the run starts at the first level's equilibrium;
- ``angle_step`` (rad, default 0.2 rad), ``sine_amplitude`` (rad, default 0.1 rad),
  ``sine_frequency`` (Hz, default 1 Hz): at each level, for :data:`SEGMENT_S`, the angle
  reference is the rest angle until 0.5 s, the step until 1.5 s, the step plus one period
  of the sine from 1.5 s, the rest angle again from 2.5 s; the stiffness reference steps
  to the next level at the start of its segment;
- ``pressure_min``, ``pressure_max`` (default 0 and 0.4 MPa), ``pressure_rate_max``
  (default 2 MPa/s): one set of limits for every command and every controller;
- ``sample_time`` (default 10 ms); ``tension_min`` (default 0.1 N): the tendons' bound,
  handed to every controller that can state it and checked on the plant;
- ``[control.controllers.<key>]``: one run per key, ``type`` the registered slug (default
  the key), other entries the controller's own settings. Every controller reads the
  plant's states (exact, noise-free) and the reference at the sample only (no preview):
  the same information, said in ``summary.json`` (``information``).

Metrics, prefixed by the key: ``angle_rmse_mrad`` (the whole run), ``stiffness_rmse_pct``
(of the reference), ``coupling_stiffness_pct`` (the stiffness's largest deviation from its
reference while the angle moves, from 0.5 s into each segment, per cent of the
reference), ``coupling_angle_pct`` (the angle's largest deviation during each stiffness
change, the first 0.5 s of the later segments, per cent of ``angle_step``),
``tendon_tension_min_N``, ``tendon_violation_max_mN`` (how far below ``tension_min`` the
slacker tendon went), ``cpu_s`` and ``real_time_factor`` (simulated over CPU time, the
run's process time).
"""

from __future__ import annotations

import math
import time
from collections.abc import Mapping
from pathlib import Path

import numpy as np

from sarcomere.dynamics.equilibrium import solve_equilibrium
from sarcomere.dynamics.errors import ParameterError

from .binding import bind, command_range, solver_settings
from .output import RunOutput
from .runner import register_runner
from .spec import Scenario, describe, quantity, unknown_key

FLEX, EXT = "flexor_regulator.p_cmd", "extensor_regulator.p_cmd"
OUTPUTS = ("joint.theta", "stiffness.K")
TENDONS = ("flexor_tendon.T", "extensor_tendon.T")
SEGMENT_S = 3.0
"""Length of each stiffness level's segment [s]: step at 0.5 s, sine from 1.5 s, rest
from 2.5 s."""
SETTLE_S = 0.5
"""The part of a segment before the angle moves [s] (the stiffness change's)."""
KEYS = (
    "co_contraction",
    "angle_step",
    "sine_amplitude",
    "sine_frequency",
    "pressure_min",
    "pressure_max",
    "pressure_rate_max",
    "sample_time",
    "tension_min",
    "controllers",
)


def reference(theta0: float, levels: list[float], step: float, amp: float, freq: float):
    """``r(t) = (angle, stiffness)`` of the segments (module docstring)."""

    def r(t: float) -> tuple[float, float]:
        i = min(int(t // SEGMENT_S), len(levels) - 1)
        s = t - i * SEGMENT_S
        angle = theta0
        if SETTLE_S <= s < 2.5:
            angle += step
        if 1.5 <= s < 2.5:
            angle += amp * math.sin(2 * math.pi * freq * (s - 1.5))
        return angle, levels[i]

    return r


def run_joint_control(sc: Scenario, out_dir: Path) -> RunOutput:
    """Every ``[control.controllers]`` entry on the joint (module docstring)."""
    sc.refuse_unused("inputs", "sweep", "outputs.tolerance", "cosim")
    b = bind(sc)
    if b.setup != "joint":
        raise sc.error(("model", "name"), "kind 'joint_control' needs [model] name = 'joint'")
    b.require_regulators("joint_control")
    if sc.simulation is None or sc.simulation.output_interval is not None:
        raise sc.error(("simulation",), "give stop_time only: the samples are the output grid")
    ctl = sc.control if isinstance(sc.control, Mapping) else {}
    for key in ctl:
        if key not in KEYS:
            raise sc.error(("control", key), unknown_key(key, list(KEYS)))
    # imported here: python-control costs about 1 s, paid by control scenes only
    from sarcomere.controllers import CONTROLLERS, make_controller
    from sarcomere.controllers.loop import run_closed_loop

    model = b.build(sc.model.fidelity)
    over = dict(b.overrides)
    rng = command_range(model, over, FLEX)

    def q(key, default, unit, low=None):
        return quantity(sc, ctl.get(key, default), ("control", key), unit, low)

    raw = ctl.get("co_contraction")
    if not isinstance(raw, list | tuple) or len(raw) < 2:
        raise sc.error(("control", "co_contraction"), "give two or more levels (Pa)")
    pressures = [quantity(sc, v, ("control", "co_contraction"), "Pa", 0.0) for v in raw]
    p_min, p_max = q("pressure_min", 0.0, "Pa", 0.0), q("pressure_max", "0.4 MPa", "Pa")
    for p in pressures:
        if not (p_min < p < p_max <= rng[1]):
            raise sc.error(
                ("control", "co_contraction"),
                f"{p:g} Pa: need pressure_min ({p_min:g}) < level < pressure_max ({p_max:g}) "
                f"<= the regulators' {rng[1]:g} Pa",
            )
    stop = sc.simulation.stop_time
    if stop > SEGMENT_S * len(pressures) + 1e-9:
        raise sc.error(
            ("simulation", "stop_time"),
            f"{stop:g} s: at most {SEGMENT_S:g} s per level ({SEGMENT_S * len(pressures):g} s)",
        )
    eqs = [solve_equilibrium(model, {FLEX: p, EXT: p}, over) for p in pressures]
    op = eqs[0]
    levels = [float(e["stiffness.K"]) for e in eqs]
    step = q("angle_step", "0.2 rad", "rad")
    amp = q("sine_amplitude", "0.1 rad", "rad")
    ref = reference(float(op["joint.theta"]), levels, step, amp, q("sine_frequency", "1 Hz", "Hz"))
    dt = q("sample_time", "10 ms", "s", 0.0)
    rate_max = q("pressure_rate_max", "2 MPa/s", "Pa/s", 0.0)
    t_min = q("tension_min", "0.1 N", "N", 0.0)
    entries = ctl.get("controllers") or {}
    if not isinstance(entries, Mapping) or not entries:
        raise sc.error(("control", "controllers"), "no controllers to run")
    settings = solver_settings(sc, model)
    metrics, results, status = {}, {}, {}
    for key, own in entries.items():
        path = ("control", "controllers", key)
        own = dict(own)
        slug = own.pop("type", key)
        if slug not in CONTROLLERS:
            raise sc.error((*path, "type"), f"'{slug}' is not one of {sorted(CONTROLLERS)}")
        task = {
            "output": list(OUTPUTS),
            "input": [FLEX, EXT],
            "u_min": p_min,
            "u_max": p_max,
            "rate_max": rate_max,
            "tension_min": t_min,
            "overrides": over,
            **own,
        }
        try:
            controller = make_controller(slug, model, op, dt, task)
        except ParameterError as exc:
            raise sc.error((*path, exc.name.split(".")[-1]), describe(exc)) from None
        tic = time.process_time()
        run = run_closed_loop(model, controller, op, ref, stop, output=OUTPUTS, settings=settings)
        cpu = time.process_time() - tic
        res = run.result
        metrics.update({f"{key}_{k}": v for k, v in _scores(res, levels, step, t_min).items()})
        metrics[f"{key}_cpu_s"] = cpu
        metrics[f"{key}_real_time_factor"] = stop / cpu
        res.meta.update({"controller": slug, "sample_time_s": dt})
        results[key] = res
        status[key] = run.status
    extra = {
        "co_contraction_Pa": pressures,
        "stiffness_levels_Nm_per_rad": levels,
        "input_limits": {"u_min_Pa": p_min, "u_max_Pa": p_max, "rate_max_Pa_per_s": rate_max},
        "tension_min_N": t_min,
        "information": "every controller: the plant's exact states, the reference at the "
        "sample only (no preview)",
        "status": status,
    }
    return RunOutput(
        sc.name,
        sc.model.fidelity,
        f"{settings.method} plant, controllers sampled every {dt * 1e3:g} ms (zero-order "
        "hold); states: exact for every controller; reference: r(t) only",
        metrics=metrics,
        results=results,
        extra=extra,
    )


def _scores(res, levels: list[float], step: float, t_min: float) -> dict[str, float]:
    """The metrics of one run (module docstring)."""
    t = res.index
    e_theta = res["joint.theta"] - res["reference"]
    K_ref = res["stiffness.K.reference"]
    e_K = (res["stiffness.K"] - K_ref) / K_ref
    s = t % SEGMENT_S
    moving, changing = s >= SETTLE_S, (s < SETTLE_S) & (t >= SEGMENT_S)
    slack = np.minimum(res[TENDONS[0]], res[TENDONS[1]])
    return {
        "angle_rmse_mrad": float(np.sqrt(np.mean(e_theta**2))) * 1e3,
        "stiffness_rmse_pct": float(np.sqrt(np.mean(e_K**2))) * 100,
        "coupling_stiffness_pct": float(np.max(np.abs(e_K[moving]))) * 100,
        "coupling_angle_pct": float(np.max(np.abs(e_theta[changing]), initial=0.0))
        / abs(step)
        * 100,
        "tendon_tension_min_N": float(np.min(slack)),
        "tendon_violation_max_mN": max(0.0, t_min - float(np.min(slack))) * 1e3,
    }


register_runner("joint_control", run_joint_control)
