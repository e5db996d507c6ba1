"""The antagonistic joint exported as an FMU (its two commands in, angle, torque,
stiffness and tendon tensions out): fmpy's Co-Simulation run against the native one."""

import numpy as np
import pytest
from fmpy import simulate_fmu

from sarcomere.dynamics.simulation.settings import SolverSettings
from sarcomere.dynamics.simulation.simulator import Simulator
from sarcomere.fmu.export import export_fmu, start_point
from sarcomere.scenarios import parse_scenario
from sarcomere.scenarios.binding import scene_inputs
from sarcomere.scenarios.export_fmu import scenario_setup

pytestmark = pytest.mark.slow

SCENE = """
[scenario]
name = "joint-fmu"
kind = "transient"

[model]
name = "joint"
fidelity = "symmetric"
n = 2

[inputs."flexor_regulator.p_cmd"]
type = "step"
unit = "Pa"
initial = "0.05 MPa"
final = "0.15 MPa"
time = "0.1 s"

[inputs."extensor_regulator.p_cmd"]
type = "step"
unit = "Pa"
initial = "0.1 MPa"
final = "0.05 MPa"
time = "0.3 s"

[simulation]
stop_time = "0.6 s"
output_interval = "1 ms"
"""

TOL = 1e-4
"""Largest error relative to each output's range (the packaged scenes' FMU target)."""

TOL_K = 2e-4
"""The same for ``stiffness.K``, the steady-state gain ``-C A^-1 B`` of the linearisation
at the present state, which carries its own evaluation noise: natively, at the state 8 ms
after the flexor's step, states perturbed by 1e-9 or by 1e-8 (relative, random) move K by
the same 1.8-1.9e-5 of its value, 1.2e-4 of its range here (a floor of the solve, not of
the state). So 1e-4 of the range is below what K itself resolves; measured FMU against
native: 0.7e-4 before RADAU5's LU reuse (issue 27), 1.06e-4 after, the states within 1e-9
of their ranges. Set at the merge of issues 26 and 27; a better-conditioned stiffness
signal is the fix (named in the issue notes)."""


def test_joint_fmu_cosimulation_matches_the_native_run(tmp_path):
    sc = parse_scenario(SCENE, "joint-fmu.toml")
    model, params, inputs, experiment = scenario_setup(sc)
    path = export_fmu(model, tmp_path / "joint.fmu", 2, params, inputs, experiment)
    h, names = 1e-3, list(model.input_names)
    signals = scene_inputs(sc, model)
    t = np.arange(601) * h
    table = np.array(
        [(tk, *(float(signals[n](tk)) for n in names)) for tk in t],
        dtype=[("time", float)] + [(n, float) for n in names],
    )
    outs = ["joint.theta", "joint.tau", "stiffness.K", "flexor_tendon.T", "extensor_tendon.T"]
    fmu = simulate_fmu(
        str(path),
        fmi_type="CoSimulation",
        stop_time=0.6,
        step_size=h,
        output_interval=h,
        input=table,
        output=outs,
    )
    x0, _, _ = start_point(model, params, inputs)
    sim = Simulator(model, SolverSettings(method="cvodes", rtol=1e-11, atol=1e-15), params=params)
    sim.reset(x0=x0)
    rows = [sim.signals(outs)]
    for tk in t[:-1]:  # the inputs held over each communication step, as the FMU gets them
        sim.step({n: float(signals[n](tk)) for n in names}, h)
        rows.append(sim.signals(outs))
    for name in outs:
        native = np.array([r[name] for r in rows])
        got = np.interp(t, fmu["time"], fmu[name])
        assert np.ptp(native) > 0, name
        tol = TOL_K if name == "stiffness.K" else TOL
        assert np.max(np.abs(got - native)) < tol * np.ptp(native), name
