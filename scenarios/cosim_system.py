"""Scenario kind "cosim" with ``[cosim.participants]``: a system of several participants
(FMUs and native models) co-simulated by :func:`~sarcomere.fmu.cosim.cosimulate`.

The schema (participants by ``fmu``, ``scene`` or ``build``: ``muscle``, ``load`` and the
controller FMUs ``pid``, ``nmpc``, ``lmpc``; ``connections``, ``sources``, ``ordering``,
``inputs``, ``record``, ``compare = "monolithic-loop"``) is docs/scenarios.md's (section
``cosim``); the runs are docs/cosim.md's. A controller's command range (``u_min``,
``u_max``) must lie inside its plant's input range and hold the start command, checked
before anything is exported (:func:`~sarcomere.controllers.registry.check_input_bounds`,
as the ``closed_loop`` kind). ``lmpc`` is kept at its start linearisation
(:data:`FIXED_LINEARISATION`), so the monolithic loop runs the controller its FMU holds.

Metrics: ``<controller>_tracking_rmse_<unit>``, the RMS of measurement minus reference at
the communication points; with ``compare``, ``max_error_vs_monolithic_loop_<unit>``, the
largest difference of the controller's measured output between the co-simulation and the
loop, at its samples. Results: ``cosim`` (with the controller's references as
``reference``) and ``monolithic`` (the same names).
"""

from __future__ import annotations

import contextlib
import dataclasses
import tempfile
from collections.abc import Mapping
from pathlib import Path

import numpy as np

from sarcomere.controllers.base import Controller
from sarcomere.controllers.lmpc import LinearMPC, LMPCSettings
from sarcomere.controllers.loop import run_closed_loop
from sarcomere.controllers.nmpc import NMPCSettings, NonlinearMPC
from sarcomere.controllers.registry import check_input_bounds, make_controller
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
from sarcomere.fmu.archive import open_fmu
from sarcomere.fmu.controller import export_controller_fmu
from sarcomere.fmu.cosim import INPUT_LAWS, ORDERINGS, Connection, cosimulate
from sarcomere.fmu.export import FMI_VERSIONS, Experiment, export_fmu
from sarcomere.fmu.participants import FmuParticipant, NativeParticipant

from .binding import solver_settings
from .export_fmu import scenario_setup
from .output import RunOutput
from .progress import report
from .signals import signal_from_spec
from .spec import Scenario, describe, quantity, unknown_key

KEYS = ("participants", "connections", "sources", "ordering", "inputs", "compare", "record")
MPC_KEYS = ("plant", "load", "sample_time", "output", "input", "u_min", "u_max", "settings", "fmi")
BUILDS = {
    "muscle": ("n", "fidelity", "as", "fmi", "start"),
    "load": ("mass", "stiffness", "damping", "as", "fmi", "start"),
    "pid": ("plant", "sample_time", "output", "input", "u_min", "u_max", "gains", "fmi"),
    "nmpc": MPC_KEYS,
    "lmpc": MPC_KEYS,
}
"""Project-built participants and their own keys (besides ``build``)."""
SOURCES = {"fmu": (), "scene": ("fmi",)}
"""Participants from a file or a scene and their own keys."""
COMPARE = ("monolithic-loop",)
KEY_OF = {
    "record": "record",
    "connection source": "connections",
    "connection target": "connections",
    "source": "sources",
}
"""The ``[cosim]`` key behind each name :func:`cosimulate` refuses."""
CONTROLLERS = ("pid", "nmpc", "lmpc")
"""Builds that are controller FMUs."""
PID_DEFAULTS = {"output": "myofibril.length", "input": "regulator.p_cmd"}
PID_BOUNDS_PA = (0.0, 1e5)
"""Default command range of a controller participant [Pa]: 0 to 0.1 MPa, the control
scenes'."""


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
    controller: Controller | None = None
    states: dict = dataclasses.field(default_factory=dict)  # NMPC: state -> its owner


class _StartedNative(NativeParticipant):
    """A native participant whose start inputs, where the master gives none, are the
    scene's ``start`` values (as its exported FMU's start values would be)."""

    def __init__(self, part: Part, settings, expose=()) -> None:
        super().__init__(part.model, part.name, None, settings, expose)
        self._given = dict(part.start)

    def start(self, t0: float, inputs: Mapping[str, float]) -> None:
        super().start(t0, {**self._given, **inputs})


def choice(sc: Scenario, tbl: Mapping, path: tuple, key: str, choices: tuple, default):
    """``tbl[key]`` (at ``path``), one of ``choices``, else ``default``; refused naming the key."""
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
    return {k: quantity(sc, v, (*path, "start", k), m.unit(k)) for k, v in tbl.items()}


def _build(sc: Scenario, part: Part) -> None:
    """The model, start inputs and native flag of a built muscle or load."""
    path = ("cosim", "participants", part.name)
    spec = part.spec
    if part.kind == "muscle":
        n = spec.get("n", 3)
        if isinstance(n, bool) or not isinstance(n, int) or n < 1:
            raise sc.error((*path, "n"), f"expected an integer >= 1, got {n!r}")
        fidelity = choice(sc, spec, path, "fidelity", FIDELITIES, "full")
        try:
            part.model = force_driven(n, fidelity=fidelity)
        except ParameterError as exc:
            raise sc.error((*path, exc.name), describe(exc)) from None
    else:
        keys = (("mass", "mass_kg", "kg"), ("stiffness", "stiffness", "N/m"))
        kw = {arg: quantity(sc, spec[k], (*path, k), u, 0.0) for k, arg, u in keys if k in spec}
        if "damping" in spec:
            kw["damping"] = quantity(sc, spec["damping"], (*path, "damping"), "N*s/m", 0.0)
        try:
            part.model = spring_mass_load(**kw)
        except ParameterError as exc:
            raise sc.error((*path, exc.name), describe(exc)) from None
    part.native = choice(sc, spec, path, "as", ("fmu", "native"), "fmu") == "native"
    part.start = _start(sc, part, path)


TASK_KEYS = {"dt": "sample_time", "input": "input", "u_min": "u_min", "u_max": "u_max"}
"""A controller's settings named by the controllers' errors -> the participant's key."""


def _where(path: tuple, kind: str, name: str, own: str) -> tuple:
    """The participant's key behind a controller's error on ``name`` (``<kind>.<key>``:
    a task key, else one of its ``own`` table; anything else: the participant)."""
    key = name.removeprefix(f"{kind}.")
    if key == name:
        return path
    return (*path, TASK_KEYS[key]) if key in TASK_KEYS else (*path, own, key)


def _task(sc: Scenario, part: Part, parts: dict[str, Part]) -> tuple:
    """A controller participant's plant participant, task (output, input and bounds, SI),
    sample time [s] and the plant's start equilibrium, at which the bounds must hold the
    start command inside the plant's input range (as the closed loop's)."""
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
        given = spec[key] if key in spec else f"{default!r} {u_unit}"  # defaults are SI
        task[key] = quantity(sc, given, (*path, key), u_unit)
    if "sample_time" not in spec:
        raise sc.error((*path, "sample_time"), "a sample time is required, e.g. '10 ms'")
    dt = quantity(sc, spec["sample_time"], (*path, "sample_time"), "s", 0.0)
    op = solve_equilibrium(m, {**dict(zip(m.input_names, m.u0(), strict=True)), **plant.start})
    try:
        check_input_bounds(part.kind, m, op, task)
    except ParameterError as exc:
        raise sc.error(_where(path, part.kind, exc.name, ""), describe(exc)) from None
    return plant, task, dt, op


def _table(sc: Scenario, part: Part, key: str) -> Mapping:
    value = part.spec.get(key, {})
    if not isinstance(value, Mapping):
        raise sc.error(
            ("cosim", "participants", part.name, key), f"expected a table, got {value!r}"
        )
    return value


def _pid(sc: Scenario, part: Part, parts: dict[str, Part]) -> None:
    """The PID designed on its plant participant's start equilibrium."""
    path = ("cosim", "participants", part.name)
    plant, task, dt, op = _task(sc, part, parts)
    m = plant.model
    gains = _table(sc, part, "gains")
    try:
        part.controller = make_controller("pid", m, op, dt, {**task, **gains})
    except ParameterError as exc:  # the PID's own settings are its gains
        raise sc.error(_where(path, "pid", exc.name, "gains"), describe(exc)) from None
    part.model = m
    part.start = {"bias": float(op.u[m.input_names.index(task["input"])])}


def _load_kw(spec: Mapping) -> dict:
    """The keyword arguments of :func:`sprung_load` for a load participant's table."""
    return {
        "mass_kg": spec.get("mass", SPRING_LOAD["mass_kg"]),
        "stiffness": spec.get("stiffness", SPRING_LOAD["stiffness"]),
        "damping": spec.get("damping", SPRING_LOAD["damping"]),
    }


FIXED_LINEARISATION = {
    "relinearize_m": 1.0,
    "relinearize_x": 1e6,
    "relinearize_u": 1e6,
    "relinearize_rel": 1e6,
    "disturbance": "none",
}
"""The settings of an ``lmpc`` participant that keep it at its start linearisation (the
thresholds out of reach, no disturbance filter): what its FMU holds, so the monolithic
loop runs the same controller."""


def _mpc(sc: Scenario, part: Part, parts: dict[str, Part]) -> None:
    """An NMPC (real-time iteration, predicting with the smooth flow law and no clamp) or
    an LMPC (linearised at the start, :data:`FIXED_LINEARISATION`) on the plant muscle and
    its load in one model (:func:`sprung_load`), started at the command of the muscle's
    start; its states are read from the participants that own them."""
    path = ("cosim", "participants", part.name)
    plant, task, dt, plant_op = _task(sc, part, parts)
    load = parts.get(part.spec.get("load"))
    if load is None or load.kind != "load":
        loads = [p.name for p in parts.values() if p.kind == "load"]
        raise sc.error((*path, "load"), f"{part.spec.get('load')!r}: one of {loads}")
    own = dict(_table(sc, part, "settings"))
    cls = NMPCSettings if part.kind == "nmpc" else LMPCSettings
    fixed = ("output", "u_min", "u_max", "solver", "soft_min", *FIXED_LINEARISATION)
    allowed = [f.name for f in dataclasses.fields(cls) if f.name not in fixed]
    for key in own:
        if key not in allowed:
            raise sc.error((*path, "settings", key), unknown_key(key, allowed))
    n, fidelity = plant.spec.get("n", 3), plant.spec.get("fidelity", "full")
    smooth = {"flow_law": "smooth", "saturate": False} if part.kind == "nmpc" else {}
    pred = sprung_load(n, fidelity=fidelity, **smooth, **_load_kw(load.spec))
    bias = float(plant_op.u[plant.model.input_names.index(task["input"])])
    bounds = {"output": task["output"], "u_min": task["u_min"], "u_max": task["u_max"]}
    try:
        op = solve_equilibrium(pred, {task["input"]: bias})
        if part.kind == "nmpc":
            own = {"linear_solver": "sparse_lu", **own}  # the solver the exported law generates
            part.controller = NonlinearMPC(pred, op.u, dt, NMPCSettings(**own, **bounds))
        else:
            settings = LMPCSettings(**own, **bounds, **FIXED_LINEARISATION)
            part.controller = LinearMPC(pred, op.x, op.u, dt, settings)
    except ParameterError as exc:
        raise sc.error((*path, "settings"), describe(exc)) from None
    part.model = pred
    part.start = {"bias": bias}
    owners = {n: p for p in (plant, load) for n in p.model.state_names}
    part.states = {n: owners[n].name for n in pred.state_names}


def _state_connections(parts: list[Part]) -> list[Connection]:
    """The exact-state controllers' state inputs, each from the participant that owns it."""
    return [
        Connection(f"{owner}.{state}", f"{p.name}.{state}")
        for p in parts
        for state, owner in p.states.items()
    ]


def _export(sc: Scenario, part: Part, folder: Path, stop_time: float) -> None:
    """The FMU file of ``part`` (exported into ``folder`` unless given)."""
    path = ("cosim", "participants", part.name)
    if part.kind == "fmu":
        part.fmu = sc.base_dir / str(part.spec["fmu"])
        return
    fmi = choice(sc, part.spec, path, "fmi", FMI_VERSIONS, 2)
    out = folder / f"{part.name}.fmu"
    if part.kind == "scene":
        scene = str(part.spec["scene"])  # a file next to the scene, or a packaged name
        beside = sc.base_dir / scene
        model, params, inputs, experiment = scenario_setup(beside if beside.is_file() else scene)
        part.fmu = export_fmu(model, out, fmi, params, inputs, experiment)
    elif part.kind in CONTROLLERS:
        part.fmu = export_controller_fmu(
            part.controller, part.model, out, part.start["bias"], fmi, part.name, stop_time
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


def _io(controller: Controller) -> tuple[str, str]:
    """A controller's ``(input, output)``: the command and the tracked signal."""
    return controller.inputs[0], controller.outputs[-1]


def _wired(sc: Scenario, parts: list[Part], connections: list[Connection]) -> tuple:
    """``(muscle, load, controller)`` of a ``compare`` scene, checked before anything is
    built."""
    kinds = {k: [p for p in parts if p.kind == k] for k in ("muscle", "load")}
    kinds["controller"] = [p for p in parts if p.kind in CONTROLLERS]
    path = ("cosim", "compare")
    if any(len(v) != 1 for v in kinds.values()):
        raise sc.error(path, "needs exactly one built muscle, one load and one pid, nmpc or lmpc")
    (mu,), (lo,), (ctl,) = kinds["muscle"], kinds["load"], kinds["controller"]
    u_name, y_name = _io(ctl.controller)
    wiring = {
        (f"{ctl.name}.command", f"{mu.name}.{u_name}"),
        (f"{mu.name}.{y_name}", f"{ctl.name}.measurement"),
        (f"{lo.name}.sensor.f", f"{mu.name}.pull.f"),
        (f"{mu.name}.end.s", f"{lo.name}.drive.s"),
        *((c.source, c.target) for c in _state_connections([ctl])),
    }
    given = {(c.source, c.target) for c in connections}
    if not wiring <= given:
        missing = ", ".join(f"{a} -> {b}" for a, b in sorted(wiring - given))
        stray = ", ".join(f"{a} -> {b}" for a, b in sorted(given - wiring))
        if stray:  # most likely a typo in a connection: blame the connection
            raise sc.error(
                ("cosim", "connections"),
                f'{stray}: not a connection compare = "monolithic-loop" knows; it needs {missing}',
            )
        raise sc.error(path, f"needs the connections {sorted(wiring)}")
    ratio = ctl.controller.dt / sc.simulation.output_interval
    if abs(ratio - round(ratio)) > 1e-9 * ratio:
        raise sc.error(
            ("cosim", "participants", ctl.name, "sample_time"),
            f"{ctl.controller.dt:g} s is not a whole number of communication steps "
            f'({sc.simulation.output_interval:g} s), as compare = "monolithic-loop" needs',
        )
    if f"{ctl.name}.reference" not in sc.cosim.get("sources", {}):
        raise sc.error(path, f"needs a source for '{ctl.name}.reference'")
    return mu, lo, ctl


def _compared(mu: Part, ctl: Part) -> dict[str, str]:
    """The monolithic loop's signal -> the co-simulation's name for it."""
    u_name, y_name = _io(ctl.controller)
    return {
        y_name: f"{mu.name}.{y_name}",
        u_name: f"{ctl.name}.command",
        "reference": "reference",
        "regulator.p_out": f"{mu.name}.regulator.p_out",
    }


def _monolithic_loop(sc: Scenario, mu: Part, lo: Part, ctl: Part, reference) -> Result:
    """The same controller on :func:`sprung_load` (the scene's muscle and load in one model)
    in the project's sampled loop, its signals named as in the co-simulation."""
    u_name, y_name = _io(ctl.controller)
    kw = _load_kw(lo.spec)
    mono = sprung_load(mu.spec.get("n", 3), fidelity=mu.spec.get("fidelity", "full"), **kw)
    op = solve_equilibrium(mono, {u_name: ctl.start["bias"]})
    loop = run_closed_loop(
        mono,
        ctl.controller,
        op,
        reference,
        sc.simulation.stop_time,
        output=y_name,
        settings=solver_settings(sc, mono),
    ).result
    names = _compared(mu, ctl)
    signals = {new: loop[old] for old, new in names.items()}
    return Result("time", "s", loop.index, signals, {n: loop.units[o] for o, n in names.items()})


def run_system(sc: Scenario, out_dir: Path) -> RunOutput:
    """Co-simulate the scene's participants (see the module docstring)."""
    for key in sc.cosim:
        if key not in KEYS:
            raise sc.error(("cosim", key), unknown_key(key, KEYS))
    sc.refuse_unused("inputs", "sweep", "control")
    for section in ("model", "parameters"):
        if any(path[0] == section for path in sc.key_lines):
            raise sc.error((section,), "the participants bring their own models; remove it")
    sim = sc.simulation
    if sim is None or not sim.output_interval:
        raise sc.error(("simulation",), "needs stop_time and output_interval (the step)")
    step = sim.output_interval
    ordering = choice(sc, sc.cosim, ("cosim",), "ordering", ORDERINGS, "jacobi")
    law = choice(sc, sc.cosim, ("cosim",), "inputs", INPUT_LAWS, "hold")
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
        elif p.kind in ("nmpc", "lmpc"):
            _mpc(sc, p, by_name)
    connections = _connections(sc)
    states = _state_connections(parts)
    given = {c.target for c in connections}
    connections += [c for c in states if c.target not in given]
    exposed = {p.name: [] for p in parts}
    for c in states:
        owner, _, var = c.source.partition(".")
        exposed[owner].append(var)
    wired = _wired(sc, parts, connections) if compare else None
    total = sim.stop_time - sim.start_time
    with tempfile.TemporaryDirectory(prefix="sarcomere-cosim-") as tmp, contextlib.ExitStack() as s:
        participants = {}
        for p in parts:
            _export(sc, p, Path(tmp), sim.stop_time)
            show = exposed[p.name]
            if p.fmu is None:
                participants[p.name] = _StartedNative(p, solver_settings(sc, p.model), show)
            else:
                opened = s.enter_context(open_fmu(p.fmu))
                participants[p.name] = FmuParticipant(opened, p.name, expose=show)
        sources = _sources(sc, participants)
        record = sc.cosim.get("record", [])
        if not (isinstance(record, list) and all(isinstance(n, str) for n in record)):
            raise sc.error(("cosim", "record"), f"expected a list of names, got {record!r}")
        record = list(record) or [
            f"{n}.{v}" for n, q in participants.items() for v in (*q.inputs, *q.outputs)
        ]
        if wired:  # what the comparison reads
            read = _compared(wired[0], wired[2]).values()
            record += [n for n in read if n not in record and n != "reference"]
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
                record=record,
                on_step=lambda t: report(f"t = {t - sim.start_time:.3g} / {total:g} s"),
            )
        except ParameterError as exc:
            raise sc.error(("cosim", KEY_OF.get(exc.name, exc.name)), describe(exc)) from None
    mono = _monolithic_loop(sc, *wired, sources[f"{wired[2].name}.reference"]) if wired else None
    return _output(sc, parts, connections, sources, result, step, ordering, law, wired, mono)


def _label(p: Part) -> str:
    """What a participant is: ``muscle (n = 3, full) as FMU``, ``pid as FMU``, ..."""
    what = {"fmu": f"FMU file {p.fmu}", "scene": f"scene {p.spec.get('scene')} as FMU"}
    if p.kind == "muscle":
        label = f"muscle (n = {p.spec.get('n', 3)}, {p.spec.get('fidelity', 'full')})"
    else:
        label = what.get(p.kind, p.kind)
    return label if p.kind in what else f"{label} {'native' if p.native else 'as FMU'}"


def _output(sc, parts, connections, sources, result, step, ordering, law, wired, mono):
    """Metrics and results of a system run (``mono``: the monolithic loop's result)."""
    metrics, extra = {}, {"participants": {p.name: _label(p) for p in parts}}
    signals, units = dict(result.signals), dict(result.units)
    for p in (p for p in parts if p.kind in CONTROLLERS):
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
    if wired:
        mu, _, ctl = wired
        (u_name, y_name), names = _io(ctl.controller), _compared(mu, ctl)
        y, u = names[y_name], names[u_name]
        rows = np.rint((mono.index - result.index[0]) / step).astype(int)
        unit = mono.units[y]
        co = signals[y][rows]
        metrics[f"max_error_vs_monolithic_loop_{unit}"] = float(np.max(np.abs(co - mono[y])))
        # the command held from a sample on is read one step later
        du = np.max(np.abs(signals[u][rows + 1] - mono[u]))
        extra[f"command_max_error_vs_monolithic_loop_{mono.units[u]}"] = float(du)
        extra[f"tracking_rmse_at_samples_{unit}"] = {
            "cosim": float(np.sqrt(np.mean((co - mono["reference"]) ** 2))),
            "monolithic": float(np.sqrt(np.mean((mono[y] - mono["reference"]) ** 2))),
        }
        extra["compared"] = (
            f"{y} of the co-simulation against the monolithic model (muscle and load in one "
            f"model) in controllers.loop.run_closed_loop with the same {ctl.kind.upper()}, at "
            f"its {ctl.controller.dt:g} s samples"
        )
        results = {"monolithic": mono, **results}  # first: its signals are the plots'
    return RunOutput(
        sc.name,
        ", ".join(f"{p.name}: {_label(p)}" for p in parts),
        f"co-simulation of {len(parts)} participants ({ordering}, {law}, step {step:g} s)",
        metrics=metrics,
        results=results,
        extra=extra,
    )
