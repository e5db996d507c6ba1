"""Every packaged transient scene's FMU against the native run: FMI 2.0 and 3.0,
Co-Simulation at 1, 5 and 10 ms communication steps (the adaptive Radau IIA inside, its
default rtol 1e-8) and Model Exchange under fmpy's CVode at rtol 1e-8.

The FMU receives its inputs at the communication points and holds them over each step
(FMI's Co-Simulation without input derivatives), so the reference is the native model
driven by the same zero-order hold: the scene's input signals sampled at the step grid,
held over each step by :meth:`Simulator.step` (CVODES at rtol 1e-11, atol 1e-15). For the
step scenes (step-50g, vent-0g) the held input is the scene's own signal. Model Exchange
gets the 1 ms hold as an input table (a jump at each change: an event for fmpy, which
restarts CVode there; between table rows fmpy sets inputs only at its output points
without a restart, so a smoothly interpolated table would reach the FMU late).

Error measure: ``max_t |y_fmu - y_native| / (max_t y_native - min_t y_native)`` for each
of the FMU's outputs (all of the model's outputs), at every communication point over the
scene's whole stop time; at most :data:`TOL`. Scenes at fidelity "auto" are not
exported (an FMU holds one level): a test checks they are refused.
"""

from __future__ import annotations

import zipfile
from functools import cache

import numpy as np
import pytest
from fmpy import read_model_description, simulate_fmu
from fmpy.fmi2 import FMU2Slave
from fmpy.fmi3 import FMU3Slave

from sarcomere.dynamics.errors import SarcomereError
from sarcomere.dynamics.simulation.settings import SolverSettings
from sarcomere.dynamics.simulation.simulator import Simulator
from sarcomere.fmu.export import export_fmu, start_point
from sarcomere.scenarios.binding import scene_inputs  # the input mapping export_fmu uses
from sarcomere.scenarios.export_fmu import scenario_setup
from sarcomere.scenarios.loader import load_scenario, packaged_scenarios

pytestmark = pytest.mark.slow

TOL = 1e-4
"""Largest error relative to each output's range over the run [-] (issue 17's target)."""

STEPS_S = (1e-3, 5e-3, 1e-2)
"""Co-Simulation communication steps [s]."""

ME_RTOL = 1e-8
"""fmpy's CVode relative tolerance for Model Exchange."""

REFERENCE = SolverSettings(method="cvodes", rtol=1e-11, atol=1e-15)
"""The native reference's integrator (tight: its own error is far below :data:`TOL`)."""


def _transient() -> dict[str, str]:
    """Packaged transient scenes -> their fidelity."""
    out = {}
    for name in packaged_scenarios():
        sc = load_scenario(name)
        if sc.kind == "transient":
            out[name] = sc.model.fidelity
    return out


TRANSIENT = _transient()
SCENES = sorted(n for n, fid in TRANSIENT.items() if fid != "auto")


def test_every_transient_scene_is_covered_or_refused():
    assert {"step-50g", "vent-0g", "ramp-50g", "sine-sweep-50g"} <= set(SCENES)
    for name in sorted(set(TRANSIENT) - set(SCENES)):
        with pytest.raises(SarcomereError, match="an FMU is exported at one level"):
            scenario_setup(name)


@cache
def _case(scene: str):
    """Model, parameter overrides, start state, input names and signals, stop time."""
    model, params, inputs, experiment = scenario_setup(scene)
    x0, _, _ = start_point(model, params, inputs)
    signals = scene_inputs(load_scenario(scene), model)
    names = list(model.input_names)
    return model, params, x0, names, [signals[n] for n in names], experiment.stop_time


def _held(scene: str, h: float) -> tuple[np.ndarray, np.ndarray]:
    """The communication times ``t_k = k h`` and the held inputs ``u(t_k)``."""
    *_, names, signals, stop = _case(scene)
    t = np.arange(int(round(stop / h)) + 1) * h
    return t, np.array([[float(s(tk)) for s in signals] for tk in t[:-1]])


@cache
def _reference(scene: str, h: float) -> np.ndarray:
    """The outputs at ``t_k`` of the native model under the held inputs (rows: times)."""
    model, params, x0, names, _, _ = _case(scene)
    _, U = _held(scene, h)
    sim = Simulator(model, REFERENCE, params=params)
    sim.reset(x0=x0)
    rows = [sim.signals(model.output_names)]
    for u in U:
        sim.step(dict(zip(names, u, strict=True)), h)
        rows.append(sim.signals(model.output_names))
    return np.array([[r[n] for n in model.output_names] for r in rows])


@pytest.fixture(scope="module")
def exported(tmp_path_factory):
    """``exported(scene, version)``: the scene's FMU, built once per module."""
    folder = tmp_path_factory.mktemp("accuracy")
    built = {}

    def get(scene: str, version: int):
        if (scene, version) not in built:
            model, params, inputs, experiment = scenario_setup(scene)
            path = folder / f"{scene}-fmi{version}.fmu"
            export_fmu(model, path, version, params, inputs, experiment)
            unzipped = folder / f"{scene}-fmi{version}"
            with zipfile.ZipFile(path) as zf:
                zf.extractall(unzipped)
            built[scene, version] = (path, unzipped)
        return built[scene, version]

    return get


def _cosim(scene: str, version: int, fmu, unzipped, h: float) -> np.ndarray:
    """Outputs at ``t_k`` from a plain doStep loop of ``h`` with the held inputs."""
    model = _case(scene)[0]
    md = read_model_description(fmu)
    vr = {v.name: v.valueReference for v in md.modelVariables}
    u_vr = [vr[n] for n in model.input_names]
    y_vr = [vr[n] for n in model.output_names]
    t, U = _held(scene, h)
    cls = FMU2Slave if version == 2 else FMU3Slave
    fmu = cls(
        guid=md.guid,
        unzipDirectory=str(unzipped),
        modelIdentifier=md.coSimulation.modelIdentifier,
        instanceName="accuracy",
    )
    fmu.instantiate()
    if version == 2:
        fmu.setupExperiment(startTime=0.0)
        fmu.enterInitializationMode()
    else:
        fmu.enterInitializationMode(startTime=0.0)
    set_, get = (fmu.setReal, fmu.getReal) if version == 2 else (fmu.setFloat64, fmu.getFloat64)
    set_(u_vr, list(U[0]))
    fmu.exitInitializationMode()
    rows = [get(y_vr)]
    for k, u in enumerate(U):
        set_(u_vr, list(u))
        fmu.doStep(t[k], h)
        rows.append(get(y_vr))
    fmu.terminate()
    fmu.freeInstance()
    return np.array(rows)


def _model_exchange(scene: str, fmu) -> np.ndarray:
    """Outputs at the 1 ms grid from fmpy's CVode (rtol 1e-8) with the 1 ms hold as an
    input table; at an input jump the row before the event (the held value's end)."""
    model = _case(scene)[0]
    h = STEPS_S[0]
    t, U = _held(scene, h)
    rows = [(t[0], *U[0])]
    for k in range(1, len(U)):
        if np.any(U[k] != U[k - 1]):
            rows += [(t[k], *U[k - 1]), (t[k], *U[k])]
    rows.append((t[-1], *U[-1]))
    dtype = np.dtype([("time", float)] + [(n, float) for n in model.input_names])
    r = simulate_fmu(
        str(fmu),
        fmi_type="ModelExchange",
        relative_tolerance=ME_RTOL,
        stop_time=float(t[-1]),
        output_interval=h,
        input=np.array(rows, dtype=dtype),
        output=list(model.output_names),
    )
    _, first = np.unique(r["time"], return_index=True)  # before the event at a jump
    r = r[first]
    np.testing.assert_allclose(r["time"], t, rtol=0, atol=1e-9)
    return np.array([r[n] for n in model.output_names]).T


def _error(result: np.ndarray, ref: np.ndarray, names) -> tuple[float, str]:
    """Largest error relative to each output's span; an output that does not move (a
    thread's strain off its end stop) must not move in the FMU either."""
    span = np.ptp(ref, axis=0)
    still = span == 0
    np.testing.assert_array_equal(result[:, still], ref[:, still])
    moving = np.flatnonzero(~still)
    assert len(moving) > 0.8 * len(names), [n for n, s in zip(names, still, strict=True) if s]
    err = np.max(np.abs(result[:, moving] - ref[:, moving]), axis=0) / span[moving]
    i = int(np.argmax(err))
    return float(err[i]), names[moving[i]]


def _cases():
    for scene in SCENES:
        for mode in [*(f"cs-{h * 1e3:g}ms" for h in STEPS_S), "me"]:
            for version in (2, 3):
                yield pytest.param(scene, mode, version)


@pytest.mark.parametrize(("scene", "mode", "version"), list(_cases()))
def test_fmu_matches_native(scene, mode, version, exported):
    fmu, unzipped = exported(scene, version)
    names = list(_case(scene)[0].output_names)
    if mode == "me":
        result, h = _model_exchange(scene, fmu), STEPS_S[0]
    else:
        h = float(mode[3:-2]) * 1e-3
        result = _cosim(scene, version, fmu, unzipped, h)
    ref = _reference(scene, h)
    assert result.shape == ref.shape
    err, worst = _error(result, ref, names)
    print(f"{scene} FMI {version} {mode}: {err:.2e} ({worst})")
    assert err < TOL, (err, worst)
