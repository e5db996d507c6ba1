"""Scenario kind "cosim" with ``[cosim.participants]``: a system of several participants
(FMUs and native models) co-simulated by :func:`~sarcomere.fmu.cosim.cosimulate`.

``[simulation]``: ``stop_time``, ``start_time`` and ``output_interval``, the communication
step (required). ``[solver]``: the native participants' integrator. ``[cosim]``:

- ``participants``: one table per participant, stepped (and started) in the listed order.
  Each has exactly one of
  ``fmu = "file.fmu"`` (relative to the scene file), ``scene = "step-50g"`` (a transient
  scene exported during the run; ``fmi``) or ``build``, a model the project builds:

  * ``"muscle"``: :func:`~sarcomere.dynamics.assemblies.force_driven` (inputs
    ``regulator.p_cmd`` and ``pull.f``, output ``end.s``); keys ``n`` (3), ``fidelity``
    ("full"), ``as`` ("fmu" or "native", default "fmu"), ``fmi`` (2), ``start`` (a table
    of start inputs: the FMU's export point and the native start);
  * ``"load"``: :func:`~sarcomere.dynamics.assemblies.spring_mass_load` (input
    ``drive.s``, output ``sensor.f``); ``mass``, ``stiffness``, ``damping`` (defaults
    :data:`~sarcomere.dynamics.assemblies.SPRING_LOAD`), ``as``, ``fmi``, ``start``;
  * ``"pid"``: the project's PID exported as a controller FMU (inputs ``reference`` and
    ``measurement``, output ``command``; docs/fmu.md); ``plant`` (a ``build = "muscle"``
    participant: its model at its start equilibrium designs the gains, and its start
    command is the bias), ``sample_time``, ``output`` ("myofibril.length"), ``input``
    ("regulator.p_cmd"), ``u_min`` (0 Pa), ``u_max`` (0.1 MPa), ``gains`` (a table of the
    PID's own settings, ``controllers/pid.py``), ``fmi``;

- ``connections``: ``[["source.output", "target.input"], ...]``;
- ``sources``: a table ``"participant.input" = {signal}`` (the ``[inputs]`` signal
  tables), sampled at each step's start;
- ``ordering``, ``inputs``: as the single-FMU form; ``record``: the signals to record
  (default every participant's inputs and outputs);
- ``compare = "monolithic-loop"``: also run the same PID on the monolithic model
  (:func:`~sarcomere.dynamics.assemblies.sprung_load`, the muscle and the load in one
  model) in the project's sampled loop (:func:`~sarcomere.controllers.loop.run_closed_loop`,
  CVODES per ``[solver]``); needs one muscle, one load and one PID wired as
  pid -> muscle -> load -> muscle, muscle -> pid.

Metrics: ``<pid>_tracking_rmse_<unit>``, the RMS of measurement minus reference at the
communication points; with ``compare``, ``max_error_vs_monolithic_loop_<unit>``, the
largest difference of the PID's measured output between the co-simulation and the loop,
at the PID's samples. Results: ``cosim`` (with the PID references as
``reference``) and ``monolithic`` (the same names).
"""

from __future__ import annotations

import contextlib
import dataclasses
import math
import tempfile
from collections.abc import Mapping
from pathlib import Path

import numpy as np

from sarcomere.controllers.loop import run_closed_loop
from sarcomere.controllers.pid import PID, make_pid
from sarcomere.dynamics.assemblies import (
    FIDELITIES,
    SPRING_LOAD,
    force_driven,
    spring_mass_load,
    sprung_load,
)
from sarcomere.dynamics.equilibrium import solve_equilibrium
from sarcomere.dynamics.errors import ParameterError
from sarcomere.dynamics.modeling.model import Model
from sarcomere.dynamics.results import Result
from sarcomere.dynamics.units import to_si
from sarcomere.fmu.archive import open_fmu
from sarcomere.fmu.controller import export_controller_fmu
from sarcomere.fmu.cosim import INPUT_LAWS, ORDERINGS, Connection, cosimulate
from sarcomere.fmu.export import FMI_VERSIONS, Experiment, export_fmu
from sarcomere.fmu.participants import FmuParticipant, NativeParticipant

from .dynamic import _settings
from .export_fmu import scenario_setup
from .output import RunOutput
from .progress import report
from .signals import signal_from_spec
from .spec import Scenario, describe, unknown_key

KEYS = ("participants", "connections", "sources", "ordering", "inputs", "compare", "record")
BUILDS = {
    "muscle": ("n", "fidelity", "as", "fmi", "start"),
    "load": ("mass", "stiffness", "damping", "as", "fmi", "start"),
    "pid": ("plant", "sample_time", "output", "input", "u_min", "u_max", "gains", "fmi"),
}
"""Project-built participants and their own keys (besides ``build``)."""
SOURCES = {"fmu": (), "scene": ("fmi",)}
"""Participants from a file or a scene and their own keys."""
COMPARE = ("monolithic-loop",)
KEY_OF = {
    "connection source": "connections",
    "connection target": "connections",
    "source": "sources",
}
"""The ``[cosim]`` key behind each name :func:`cosimulate` refuses."""
PID_DEFAULTS = {"output": "myofibril.length", "input": "regulator.p_cmd"}
PID_BOUNDS_PA = (0.0, 1e5)
"""Default command range of a PID participant [Pa]: 0 to 0.1 MPa, the control scenes'."""


@dataclasses.dataclass
class Part:
    """One participant as the scene gives it, and what the run made of it."""

    name: str
    kind: str  # "fmu", "scene", or a build
    spec: Mapping
    model: Model | None = None
    start: dict = dataclasses.field(default_factory=dict)
    native: bool = False
    fmu: Path | None = None
    pid: PID | None = None


def _quantity(sc: Scenario, value, path: tuple, unit: str, low: float | None = None) -> float:
    try:
        v = to_si(value, unit, ".".join(path))
    except ParameterError as exc:
        raise sc.error(path, describe(exc)) from None
    if not math.isfinite(v) or (low is not None and v < low):
        raise sc.error(path, f"{value!r} is outside [{low:g}, inf) {unit}")
    return v


def _choice(sc: Scenario, tbl: Mapping, path: tuple, key: str, choices: tuple, default):
    value = tbl.get(key, default)
    if value not in choices:
        raise sc.error((*path, key), f"{value!r}: one of {', '.join(map(str, choices))}")
    return value


def _parse(sc: Scenario) -> list[Part]:
    tables = sc.cosim.get("participants")
    if not isinstance(tables, Mapping) or not tables:
        raise sc.error(("cosim", "participants"), "expected a table of participant tables")
    parts = []
    for name, spec in tables.items():
        path = ("cosim", "participants", name)
        if not isinstance(spec, Mapping):
            raise sc.error(path, f"expected a table, got {spec!r}")
        given = [k for k in ("fmu", "scene", "build") if k in spec]
        if len(given) != 1:
            raise sc.error(path, "give exactly one of 'fmu', 'scene' or 'build'")
        kind = given[0] if given[0] != "build" else spec["build"]
        if kind not in (*SOURCES, *BUILDS):
            raise sc.error((*path, "build"), f"{kind!r}: one of {', '.join(BUILDS)}")
        allowed = (given[0], *SOURCES.get(kind, BUILDS.get(kind, ())))
        for key in spec:
            if key not in allowed:
                raise sc.error((*path, key), unknown_key(key, allowed))
        parts.append(Part(name, kind, spec))
    return parts


def _start(sc: Scenario, part: Part, path: tuple) -> dict:
    tbl = part.spec.get("start", {})
    if not isinstance(tbl, Mapping):
        raise sc.error((*path, "start"), f"expected a table of inputs, got {tbl!r}")
    m = part.model
    for key in tbl:
        if key not in m.input_names:
            raise sc.error((*path, "start", key), unknown_key(key, m.input_names))
    return {k: _quantity(sc, v, (*path, "start", k), m.unit(k)) for k, v in tbl.items()}


def _build(sc: Scenario, part: Part) -> None:
    """The model, start inputs and native flag of a built muscle or load."""
    path = ("cosim", "participants", part.name)
    spec = part.spec
    if part.kind == "muscle":
        n = spec.get("n", 3)
        if isinstance(n, bool) or not isinstance(n, int) or n < 1:
            raise sc.error((*path, "n"), f"expected an integer >= 1, got {n!r}")
        fidelity = _choice(sc, spec, path, "fidelity", FIDELITIES, "full")
        try:
            part.model = force_driven(n, fidelity=fidelity)
        except ParameterError as exc:
            raise sc.error((*path, exc.name), describe(exc)) from None
    else:
        keys = (("mass", "mass_kg", "kg"), ("stiffness", "stiffness", "N/m"))
        kw = {arg: _quantity(sc, spec[k], (*path, k), u, 0.0) for k, arg, u in keys if k in spec}
        if "damping" in spec:
            kw["damping"] = _quantity(sc, spec["damping"], (*path, "damping"), "N*s/m", 0.0)
        try:
            part.model = spring_mass_load(**kw)
        except ParameterError as exc:
            raise sc.error((*path, exc.name), describe(exc)) from None
    part.native = _choice(sc, spec, path, "as", ("fmu", "native"), "fmu") == "native"
    part.start = _start(sc, part, path)


def _pid(sc: Scenario, part: Part, parts: dict[str, Part]) -> None:
    """The PID designed on its plant participant's start equilibrium."""
    path = ("cosim", "participants", part.name)
    spec = part.spec
    plant = parts.get(spec.get("plant"))
    if plant is None or plant.kind != "muscle":
        muscles = [p.name for p in parts.values() if p.kind == "muscle"]
        raise sc.error((*path, "plant"), f"{spec.get('plant')!r}: one of {muscles}")
    m = plant.model
    task = {k: spec.get(k, v) for k, v in PID_DEFAULTS.items()}
    if task["output"] not in m.signal_names:
        raise sc.error((*path, "output"), unknown_key(task["output"], m.output_names))
    if task["input"] not in m.input_names:
        raise sc.error((*path, "input"), unknown_key(task["input"], m.input_names))
    u_unit = m.unit(task["input"])
    for key, default in zip(("u_min", "u_max"), PID_BOUNDS_PA, strict=True):
        task[key] = _quantity(sc, spec.get(key, default), (*path, key), u_unit)
    if "sample_time" not in spec:
        raise sc.error((*path, "sample_time"), "a sample time is required, e.g. '10 ms'")
    dt = _quantity(sc, spec["sample_time"], (*path, "sample_time"), "s", 0.0)
    gains = spec.get("gains", {})
    if not isinstance(gains, Mapping):
        raise sc.error((*path, "gains"), f"expected a table, got {gains!r}")
    start = {**dict(zip(m.input_names, m.u0(), strict=True)), **plant.start}
    try:
        op = solve_equilibrium(m, start)
        part.pid = make_pid(m, op, dt, {**task, **gains})
    except ParameterError as exc:
        raise sc.error(path, describe(exc)) from None
    part.model = m
    part.start = {"bias": float(op.u[m.input_names.index(task["input"])])}


def _export(sc: Scenario, part: Part, folder: Path, stop_time: float) -> None:
    """The FMU file of ``part`` (exported into ``folder`` unless given)."""
    path = ("cosim", "participants", part.name)
    if part.kind == "fmu":
        part.fmu = sc.base_dir / str(part.spec["fmu"])
        return
    fmi = _choice(sc, part.spec, path, "fmi", FMI_VERSIONS, 2)
    out = folder / f"{part.name}.fmu"
    if part.kind == "scene":
        model, params, inputs, experiment = scenario_setup(str(part.spec["scene"]))
        part.fmu = export_fmu(model, out, fmi, params, inputs, experiment)
    elif part.kind == "pid":
        part.fmu = export_controller_fmu(
            part.pid, part.model, out, part.start["bias"], fmi, part.name, stop_time
        )
    elif not part.native:
        experiment = Experiment(stop_time=stop_time)
        part.fmu = export_fmu(part.model, out, fmi, None, part.start, experiment)


def _connections(sc: Scenario) -> list[Connection]:
    raw = sc.cosim.get("connections", [])
    path = ("cosim", "connections")
    ok = isinstance(raw, list) and all(
        isinstance(c, list) and len(c) == 2 and all(isinstance(s, str) for s in c) for c in raw
    )
    if not ok:
        raise sc.error(path, 'expected [["source.output", "target.input"], ...]')
    return [Connection(a, b) for a, b in raw]


def _sources(sc: Scenario, participants: dict) -> dict:
    raw = sc.cosim.get("sources", {})
    if not isinstance(raw, Mapping):
        raise sc.error(("cosim", "sources"), f"expected a table, got {raw!r}")
    out = {}
    for target, spec in raw.items():
        path = ("cosim", "sources", target)
        owner, _, var = target.partition(".")
        if owner not in participants or var not in participants[owner].inputs:
            raise sc.error(path, "not an input of a participant ('participant.input')")
        if not isinstance(spec, Mapping):
            raise sc.error(path, f"expected a signal table, got {spec!r}")
        try:
            out[target] = signal_from_spec(
                spec, participants[owner].units[var], ".".join(path), sc.base_dir
            )
        except ParameterError as exc:
            raise sc.error(tuple(exc.name.split(".")), describe(exc)) from None
    return out


def _compare(sc, parts, connections, sources, stop_time: float, step: float):
    """The monolithic closed loop of the scene's muscle, load and PID (see the module
    docstring); returns the loop's result and the names it maps to."""
    kinds = {k: [p for p in parts if p.kind == k] for k in ("muscle", "load", "pid")}
    path = ("cosim", "compare")
    if any(len(v) != 1 for v in kinds.values()):
        raise sc.error(path, "needs exactly one built muscle, one load and one pid")
    (mu,), (lo,), (ctl,) = kinds["muscle"], kinds["load"], kinds["pid"]
    pid = ctl.pid
    wiring = {
        (f"{ctl.name}.command", f"{mu.name}.{pid.input}"),
        (f"{mu.name}.{pid.output}", f"{ctl.name}.measurement"),
        (f"{lo.name}.sensor.f", f"{mu.name}.pull.f"),
        (f"{mu.name}.end.s", f"{lo.name}.drive.s"),
    }
    if not wiring <= {(c.source, c.target) for c in connections}:
        raise sc.error(path, f"needs the connections {sorted(wiring)}")
    ratio = pid.dt / step
    if abs(ratio - round(ratio)) > 1e-9 * ratio:
        raise sc.error(path, "needs a sample time that is a whole number of steps")
    reference = sources.get(f"{ctl.name}.reference")
    if reference is None:
        raise sc.error(path, f"needs a source for '{ctl.name}.reference'")
    load = lo.spec
    kw = {
        "mass_kg": load.get("mass", SPRING_LOAD["mass_kg"]),
        "stiffness": load.get("stiffness", SPRING_LOAD["stiffness"]),
        "damping": load.get("damping", SPRING_LOAD["damping"]),
    }
    mono = sprung_load(mu.spec.get("n", 3), fidelity=mu.spec.get("fidelity", "full"), **kw)
    op = solve_equilibrium(mono, {pid.input: ctl.start["bias"]})
    loop = run_closed_loop(
        mono, pid, op, reference, stop_time, output=pid.output, settings=_settings(sc, mono)
    )
    return loop.result, mu, ctl


def run_system(sc: Scenario, out_dir: Path) -> RunOutput:
    """Co-simulate the scene's participants (see the module docstring)."""
    for key in sc.cosim:
        if key not in KEYS:
            raise sc.error(("cosim", key), unknown_key(key, KEYS))
    sc.refuse_unused("inputs", "sweep", "control")
    sim = sc.simulation
    if sim is None or not sim.output_interval:
        raise sc.error(("simulation",), "needs stop_time and output_interval (the step)")
    step = sim.output_interval
    ordering = _choice(sc, sc.cosim, ("cosim",), "ordering", ORDERINGS, "jacobi")
    law = _choice(sc, sc.cosim, ("cosim",), "inputs", INPUT_LAWS, "hold")
    compare = sc.cosim.get("compare")
    if compare is not None and compare not in COMPARE:
        raise sc.error(("cosim", "compare"), f"{compare!r}: one of {', '.join(COMPARE)}")
    parts = _parse(sc)
    by_name = {p.name: p for p in parts}
    for p in parts:
        if p.kind in ("muscle", "load"):
            _build(sc, p)
    for p in parts:
        if p.kind == "pid":
            _pid(sc, p, by_name)
    connections = _connections(sc)
    total = sim.stop_time - sim.start_time
    with tempfile.TemporaryDirectory(prefix="sarcomere-cosim-") as tmp, contextlib.ExitStack() as s:
        participants = {}
        for p in parts:
            _export(sc, p, Path(tmp), sim.stop_time)
            if p.fmu is None:
                settings = _settings(sc, p.model)
                participants[p.name] = NativeParticipant(p.model, p.name, None, settings)
            else:
                participants[p.name] = FmuParticipant(s.enter_context(open_fmu(p.fmu)), p.name)
        sources = _sources(sc, participants)
        record = sc.cosim.get("record") or [
            f"{n}.{v}" for n, q in participants.items() for v in (*q.inputs, *q.outputs)
        ]
        try:
            result = cosimulate(
                list(participants.values()),
                connections,
                stop_time=sim.stop_time,
                start_time=sim.start_time,
                step=step,
                ordering=ordering,
                inputs=law,
                sources=sources,
                record=list(record),
                on_step=lambda t: report(f"t = {t - sim.start_time:.3g} / {total:g} s"),
            )
        except ParameterError as exc:
            raise sc.error(("cosim", KEY_OF.get(exc.name, exc.name)), describe(exc)) from None
    return _output(sc, parts, connections, sources, result, step, ordering, law, compare)


def _label(p: Part) -> str:
    """What a participant is: ``muscle (n = 3, full) as FMU``, ``pid as FMU``, ..."""
    what = {"fmu": f"FMU file {p.fmu}", "scene": f"scene {p.spec.get('scene')} as FMU"}
    if p.kind == "muscle":
        label = f"muscle (n = {p.spec.get('n', 3)}, {p.spec.get('fidelity', 'full')})"
    else:
        label = what.get(p.kind, p.kind)
    return label if p.kind in what else f"{label} {'native' if p.native else 'as FMU'}"


def _output(sc, parts, connections, sources, result, step, ordering, law, compare) -> RunOutput:
    """Metrics and results of a system run."""
    metrics, extra = {}, {"participants": {p.name: p.kind for p in parts}}
    signals, units = dict(result.signals), dict(result.units)
    for p in (p for p in parts if p.kind == "pid"):
        target = f"{p.name}.measurement"
        measured = next((c.source for c in connections if c.target == target), None)
        ref = sources.get(f"{p.name}.reference")
        if measured is None or ref is None or measured not in signals:
            continue
        unit = units[measured]
        r = np.array([float(ref(t)) for t in result.index])
        signals["reference"], units["reference"] = r, unit
        err = signals[measured] - r
        metrics[f"{p.name}_tracking_rmse_{unit}"] = float(np.sqrt(np.mean(err**2)))
    results = {"cosim": dataclasses.replace(result, signals=signals, units=units)}
    if compare:
        loop, mu, ctl = _compare(sc, parts, connections, sources, sc.simulation.stop_time, step)
        pid = ctl.pid
        names = {
            pid.output: f"{mu.name}.{pid.output}",
            pid.input: f"{ctl.name}.command",
            "reference": "reference",
            "regulator.p_out": f"{mu.name}.regulator.p_out",
        }
        mono = Result(
            "time",
            "s",
            loop.index,
            {new: loop[old] for old, new in names.items()},
            {new: loop.units[old] for old, new in names.items()},
        )
        rows = np.rint((loop.index - result.index[0]) / step).astype(int)
        unit = loop.units[pid.output]
        co = signals[names[pid.output]][rows]
        metrics[f"max_error_vs_monolithic_loop_{unit}"] = float(
            np.max(np.abs(co - loop[pid.output]))
        )
        extra["command_max_error_vs_monolithic_loop_Pa"] = float(
            np.max(np.abs(signals[names[pid.input]][rows + 1] - loop[pid.input]))
        )
        extra[f"tracking_rmse_at_samples_{unit}"] = {
            "cosim": float(np.sqrt(np.mean((co - loop["reference"]) ** 2))),
            "monolithic": float(np.sqrt(np.mean((loop[pid.output] - loop["reference"]) ** 2))),
        }
        extra["compared"] = (
            f"{names[pid.output]} of the co-simulation against {pid.output} of the monolithic "
            f"model (muscle and load in one model) in controllers.loop.run_closed_loop with "
            f"the same PID, at its {pid.dt:g} s samples"
        )
        results["monolithic"] = mono
    return RunOutput(
        sc.name,
        ", ".join(f"{p.name}: {_label(p)}" for p in parts),
        f"co-simulation of {len(parts)} participants ({ordering}, {law}, step {step:g} s)",
        metrics=metrics,
        results=results,
        extra=extra,
    )
