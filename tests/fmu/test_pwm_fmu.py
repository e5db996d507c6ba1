"""A PWM-driven chain's FMU (issue 26): the valve switches inside the Co-Simulation's
doStep (physics.c splits it at the pulse train's edges), against the native run driven by
the same held duty (fmpy's FMU2Slave, a plain doStep loop)."""

from __future__ import annotations

import zipfile

import numpy as np
import pytest
from fmpy import read_model_description
from fmpy.fmi2 import FMU2Slave

from sarcomere.dynamics.assemblies import hanging_load
from sarcomere.dynamics.simulation.settings import SolverSettings
from sarcomere.dynamics.simulation.simulator import Simulator
from sarcomere.fmu.export import export_fmu, start_point

pytestmark = pytest.mark.slow  # a compile: some 10 s

U = "valve.cmd"
TOL = 1e-4
"""Largest error relative to each output's span over the run (issue 17's FMU target)."""


def _duties(t: np.ndarray) -> np.ndarray:
    """The held duty of each communication step: 0.4, then 0.6 from 0.1 s, 0.25 from 0.2 s."""
    return np.where(t < 0.1, 0.4, np.where(t < 0.2, 0.6, 0.25))


@pytest.mark.parametrize(
    ("level", "h"), [("switched", 0.01), ("switched", 0.0037), ("averaged", 0.01)]
)
def test_pwm_fmu_matches_the_native_run(tmp_path, level, h):
    model = hanging_load(2, load_kg=0.02, supply="valve_pwm", valve={"level": level})
    path = tmp_path / "pwm.fmu"
    export_fmu(model, path, 2, inputs={U: 0.4})
    x0, _, _ = start_point(model, None, {U: 0.4})
    t = np.arange(int(round(0.3 / h)) + 1) * h
    duty = _duties(t[:-1])
    # the native run: the same held duty, one Simulator.step per communication step
    sim = Simulator(model, SolverSettings("cvodes", 1e-11, 1e-15))
    sim.reset(x0=x0)
    names = model.output_names
    ref = [[sim.signal(n) for n in names]]
    for d in duty:
        sim.step({U: float(d)}, h)
        ref.append([sim.signal(n) for n in names])
    ref = np.array(ref)
    # the FMU
    unzipped = tmp_path / "pwm"
    with zipfile.ZipFile(path) as zf:
        zf.extractall(unzipped)
    md = read_model_description(str(path))
    vr = {v.name: v.valueReference for v in md.modelVariables}
    fmu = FMU2Slave(
        guid=md.guid,
        unzipDirectory=str(unzipped),
        modelIdentifier=md.coSimulation.modelIdentifier,
        instanceName="pwm",
    )
    fmu.instantiate()
    fmu.setupExperiment(startTime=0.0, tolerance=1e-10)
    fmu.enterInitializationMode()
    fmu.setReal([vr[U]], [0.4])
    fmu.exitInitializationMode()
    y_vr = [vr[n] for n in names]
    rows = [fmu.getReal(y_vr)]
    for k, d in enumerate(duty):
        fmu.setReal([vr[U]], [float(d)])
        fmu.doStep(t[k], h)
        rows.append(fmu.getReal(y_vr))
    fmu.terminate()
    fmu.freeInstance()
    got = np.array(rows)
    span = np.ptp(ref, axis=0)
    moving = span > 0
    err = np.max(np.abs(got[:, moving] - ref[:, moving]), axis=0) / span[moving]
    worst = names[np.flatnonzero(moving)[int(np.argmax(err))]]
    assert err.max() < TOL, (worst, err.max())
    # the switched FMU does switch: the hose pressure ripples at the communication points
    hose = got[:, names.index("valve_hose.p_gauge")]
    if level == "switched":
        assert np.ptp(np.diff(hose[5:10])) > 1e3
