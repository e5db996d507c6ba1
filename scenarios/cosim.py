"""Scenario kind "cosim": the scene's model as a Co-Simulation FMU in the co-simulation
master, against the native simulation of the same scene; or, with ``[cosim.participants]``,
a system of several participants (:mod:`.cosim_system`).

``[model]``, ``[parameters]``, ``[inputs]``, ``[simulation]`` and ``[solver]`` as kind
"transient" (the native run; the FMU is exported from the same model, parameters and
start inputs). ``[simulation] output_interval`` is the communication step. ``[cosim]``:

- ``fmu``: an FMU file (relative to the scene file) of this scene's model, checked against
  it (:func:`model_differences`: the same states, inputs, outputs and parameters by name,
  and the parameters the scene does not set with the same values; anything else is refused
  naming what differs); default: the model exported during the run into a temporary
  folder (a few seconds of gcc), removed afterwards;
- ``fmi``: 2 or 3, the FMI version of that export (default 2); with ``fmu``, that file's
  version (another is refused);
- ``ordering``: "jacobi" or "gauss-seidel" (default "jacobi"), ``inputs``: "hold" or
  "extrapolate" (default "hold"), see :mod:`sarcomere.fmu.cosim`.

The scene's input signals drive the FMU's inputs, sampled at each communication step's
start and held over it (a step at a communication point is exact).

Metric: ``max_rel_error_vs_native``, the largest over the recorded signals (the driven
inputs excepted) of ``max |y_fmu - y_native| / max |y_native|``; each signal's value is in
``summary.json`` (``extra.rel_error_vs_native``). Two results: ``native`` and ``cosim``
(whose driven inputs are the scene's signals at the communication points).
"""

from __future__ import annotations

import dataclasses
import math
import tempfile
from collections.abc import Iterable, Mapping
from pathlib import Path

import numpy as np

from sarcomere.dynamics.modeling.model import Model
from sarcomere.fmu.archive import open_fmu
from sarcomere.fmu.cosim import INPUT_LAWS, ORDERINGS, cosimulate
from sarcomere.fmu.export import FMI_VERSIONS, export_fmu
from sarcomere.fmu.participants import FmuParticipant

from .binding import scene_inputs
from .cosim_system import choice, run_system
from .export_fmu import scenario_setup
from .output import RunOutput
from .runner import register_runner
from .spec import Scenario, unknown_key
from .transient import run_transient

KEYS = ("fmu", "fmi", "ordering", "inputs")
NAME = "muscle"
"""The FMU's participant name."""


PARAM_RTOL = 1e-12
"""Relative tolerance of an FMU's parameter start value against the scene's model [-]
(the export writes each value with all its digits)."""


def _listed(names: Iterable[str], most: int = 3) -> str:
    names = sorted(names)
    more = f" (+{len(names) - most} more)" if len(names) > most else ""
    return ", ".join(names[:most]) + more


def model_differences(description, model: Model, p: np.ndarray, set_by_scene: Mapping) -> list:
    """What differs between an FMU's model description (fmpy's) and ``model``: the states,
    inputs, outputs and parameters by name, and the start value of each parameter the scene
    does not set (``set_by_scene``) against ``p`` [SI]. Empty if the FMU is the model."""
    variables = description.modelVariables
    fmu = {
        "states": {v.derivative.name for v in variables if v.derivative is not None},
        "inputs": {v.name for v in variables if v.causality == "input"},
        "outputs": {v.name for v in variables if v.causality == "output"},
        "parameters": {v.name for v in variables if v.causality == "parameter"},
    }
    ours = {
        "states": set(model.state_names),
        "inputs": set(model.input_names),
        "outputs": set(model.output_names),
        "parameters": set(model.param_names),
    }
    out = []
    for kind, names in fmu.items():
        extra, missing = names - ours[kind], ours[kind] - names
        if extra or missing:
            out.append(
                f"{kind}: {len(names)} in the FMU, {len(ours[kind])} in the scene's model"
                + (f"; only in the FMU: {_listed(extra)}" if extra else "")
                + (f"; only in the scene's model: {_listed(missing)}" if missing else "")
            )
    starts = {v.name: v.start for v in variables if v.causality == "parameter"}
    for i, name in enumerate(model.param_names):
        if name in set_by_scene or starts.get(name) is None:
            continue
        given = float(starts[name])
        if not math.isclose(given, float(p[i]), rel_tol=PARAM_RTOL, abs_tol=1e-300):
            unit = model.variables[name].unit
            out.append(f"{name} = {given:.9g} {unit} in the FMU, {p[i]:.9g} {unit} in the scene")
    return out


def _check_fmu(sc: Scenario, path: Path, model: Model, p: np.ndarray, set_by_scene) -> None:
    """Refuses an ``fmu`` that is not the scene's model, naming what differs, or that is
    not of the FMI version ``fmi`` names (when given)."""
    with open_fmu(path) as fmu:
        differences = model_differences(fmu.description, model, p, set_by_scene)
        name, version = fmu.description.modelName, fmu.fmi_version
    if sc.cosim.get("fmi", version) != version:
        raise sc.error(
            ("cosim", "fmi"),
            f"{sc.cosim['fmi']!r}, but {path.name} is an FMI {version}.0 FMU (fmi is the "
            f"version of the run's own export: remove it, or give {version})",
        )
    if differences:
        raise sc.error(
            ("cosim", "fmu"),
            f"{path.name} (model '{name}') is not this scene's model '{model.name}': "
            + "; ".join(differences),
        )


def run_cosim(sc: Scenario, out_dir: Path) -> RunOutput:
    """Co-simulate the scene's FMU and compare it with the native run (or run a system of
    participants, :func:`~.cosim_system.run_system`)."""
    if "participants" in sc.cosim:
        return run_system(sc, out_dir)
    for key in sc.cosim:
        if key not in KEYS:
            raise sc.error(("cosim", key), unknown_key(key, KEYS))
    fmi = choice(sc, sc.cosim, ("cosim",), "fmi", FMI_VERSIONS, 2)
    ordering = choice(sc, sc.cosim, ("cosim",), "ordering", ORDERINGS, "jacobi")
    law = choice(sc, sc.cosim, ("cosim",), "inputs", INPUT_LAWS, "hold")
    transient = dataclasses.replace(sc, kind="transient", cosim={})
    model, params, start, experiment = scenario_setup(transient)
    p = model.parameters(params)
    si_params = {n: float(p[model.param_names.index(n)]) for n in params}
    if "fmu" in sc.cosim:  # checked before anything is computed
        _check_fmu(sc, sc.base_dir / str(sc.cosim["fmu"]), model, p, si_params)
    native_run = run_transient(transient, out_dir)
    native = native_run.results["main"]
    sim = sc.simulation
    step = sim.output_interval or (sim.stop_time - sim.start_time)
    sources = {f"{NAME}.{k}": sig for k, sig in scene_inputs(sc, model).items()}
    with tempfile.TemporaryDirectory(prefix="sarcomere-cosim-") as tmp:
        if "fmu" in sc.cosim:
            path = sc.base_dir / str(sc.cosim["fmu"])
        else:
            path = export_fmu(model, Path(tmp) / f"{sc.name}.fmu", fmi, params, start, experiment)
        with open_fmu(path) as fmu:
            participant = FmuParticipant(fmu, NAME, si_params)
            names = [n for n in native.names if n in participant.units]
            result = cosimulate(
                [participant],
                stop_time=sim.stop_time,
                start_time=sim.start_time,
                step=step,
                ordering=ordering,
                inputs=law,
                sources=sources,
                record=[f"{NAME}.{n}" for n in names],
            )
    if result.index.shape != native.index.shape or not np.allclose(
        result.index, native.index, rtol=0, atol=1e-9 * step
    ):
        raise sc.error(
            ("simulation", "output_interval"), "the native and co-simulation grids differ"
        )
    signals = {n: result[f"{NAME}.{n}"] for n in names}
    driven = {n for n in names if f"{NAME}.{n}" in sources}
    for n in driven:  # what applies from each point on, as the native table shows
        signals[n] = np.array([float(sources[f"{NAME}.{n}"](t)) for t in result.index])
    cosim = dataclasses.replace(result, signals=signals, units={n: native.units[n] for n in names})
    errors = {
        n: float(np.max(np.abs(cosim[n] - native[n])) / max(np.max(np.abs(native[n])), 1e-300))
        for n in names
        if n not in driven
    }
    worst = max(errors, key=errors.get)
    return RunOutput(
        sc.name,
        native_run.fidelity,
        f"co-simulation of an FMI {fmu.fmi_version}.0 FMU ({ordering}, {law}, "
        f"step {step:g} s) vs {native_run.solver}",
        metrics={"max_rel_error_vs_native": errors[worst]},
        results={"native": native.select(names), "cosim": cosim},
        extra={"rel_error_vs_native": errors, "worst_signal": worst, "fmu": str(path)},
    )


register_runner("cosim", run_cosim)
