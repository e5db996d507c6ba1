"""The exact-state NMPC's own disturbance filter (controllers/disturbance.py,
StateDisturbanceFilter): on the states it reads it estimates the load (or an input or
output offset) and feeds it to the prediction's run-time parameters, so a load step
leaves no offset within a few samples where the former integral reference shift
(5 1/s) still left a millimetre after 0.5 s; the estimate is the injected constant."""

import numpy as np
import pytest

from sarcomere.controllers import make_controller
from sarcomere.controllers.nmpc import NMPCSettings, NonlinearMPC
from sarcomere.dynamics import Simulator, hanging_load, isometric, solve_equilibrium
from sarcomere.dynamics.errors import ParameterError
from sarcomere.fmu.controller import export_controller_fmu

P = "regulator.p_cmd"
L = "myofibril.length"
M = "load.m"
DT = 0.01
TASK = {"output": L, "input": P, "u_min": 0.0, "u_max": 3e5}


@pytest.fixture(scope="module")
def plant():
    """The exact-law plant, 1 APS, 20 g, at 50 kPa."""
    model = hanging_load(1, load_kg=0.02)
    return model, solve_equilibrium(model, {P: 5e4})


def hold(model, eq, mpc, samples, k_load=None, d_in=0.0, d_out=0.0):
    """``mpc`` holding the length of ``eq``: +50 g from sample ``k_load`` on, ``d_in``
    [Pa] added to every command, the length read ``d_out`` [m] long; the true length
    error per sample [m] and the estimate per sample [SI]."""
    sim = Simulator(model)
    sim.reset(x0=eq.x)
    sim.p = eq.p.copy()
    errors, estimates = [], []
    for k in range(samples):
        if k == k_load:
            p = sim.p.copy()
            p[model.param_names.index(M)] += 0.05
            sim.p = p
        y = sim.signals(mpc.outputs)
        y[L] += d_out
        u = mpc.checked(sim.t, y, {L: eq[L]})
        sim.step({P: u[P] + d_in}, DT)
        errors.append(sim.signal(L) - eq[L])
        estimates.append(mpc.disturbance_estimate)
    return np.array(errors), np.array(estimates)


@pytest.mark.slow  # over 0.8 s: the fast loop leaves it to the full suite
def test_a_load_step_leaves_no_offset_within_half_a_second(plant):
    """+50 g at 0.2 s: the default NMPC (no EKF: its own filter of the load, no integral)
    is within 2 um of the reference from 0.5 s after the step on and its estimate is the
    plant's load (nominal + 50 g) to 0.1 g; with ``disturbance = "none"`` (the former
    formulation: the integral shift) it is still 0.4 mm off a whole second later."""
    model, eq = plant
    mpc = make_controller("nmpc", model, eq, DT, TASK)
    assert mpc.disturbance == "load" and mpc.settings.integral_gain == 0.0
    errors, estimates = hold(model, eq, mpc, 150, k_load=20)
    true_load = eq.p[model.param_names.index(M)] + 0.05
    assert np.max(np.abs(errors[70:])) < 2e-6
    assert estimates[70:] == pytest.approx(true_load, abs=1e-4)
    assert estimates[:20] == pytest.approx(true_load - 0.05, abs=1e-6)  # no load step yet
    former = make_controller("nmpc", model, eq, DT, {**TASK, "disturbance": "none"})
    assert former.settings.integral_gain == 5.0
    late, _ = hold(model, eq, former, 150, k_load=20)
    assert np.max(np.abs(late[120:])) > 1e-4
    mpc.reset({P: 5e4})  # reset forgets the estimate
    assert mpc.disturbance_estimate == eq.p[model.param_names.index(M)]


@pytest.mark.parametrize(
    ("kind", "d_in", "d_out", "value"), [("input", 1e4, 0.0, 1e4), ("output", 0.0, 2e-4, 2e-4)]
)
@pytest.mark.slow  # over 0.8 s: the fast loop leaves it to the full suite
def test_an_input_or_output_offset_is_estimated_and_removed(plant, kind, d_in, d_out, value):
    """10 kPa added to every command (or the length read 0.2 mm long): the estimate is
    that constant, and the command is the 50 kPa equilibrium's minus 10 kPa (or the
    measured length is on the reference: the true one 0.2 mm short of it)."""
    model, eq = plant
    mpc = make_controller("nmpc", model, eq, DT, {**TASK, "disturbance": kind})
    assert mpc.disturbance == kind and mpc.settings.integral_gain == 0.0
    errors, estimates = hold(model, eq, mpc, 150, d_in=d_in, d_out=d_out)
    assert estimates[-1] == pytest.approx(value, rel=1e-3)
    assert errors[-1] + d_out == pytest.approx(0.0, abs=1e-7)
    if kind == "input":
        assert mpc._u[0] == pytest.approx(eq.u[0] - 1e4, abs=10.0)


def test_the_settings_are_checked_and_the_fmu_refuses_the_filter(plant, tmp_path):
    model, eq = plant
    with pytest.raises(ParameterError, match="nmpc.disturbance"):
        NMPCSettings(disturbance="wind")
    with pytest.raises(ParameterError, match="nmpc.input_std"):
        NMPCSettings(input_std=-1.0)
    fixed = isometric(1)
    fixed_eq = solve_equilibrium(fixed, {P: 5e4})
    pred = isometric(1, flow_law="smooth", saturate=False)
    with pytest.raises(ParameterError, match="nmpc.disturbance"):
        NonlinearMPC(pred, fixed_eq.u, DT, NMPCSettings(disturbance="load"))
    task = {**TASK, "output": "myofibril.actin0.T"}
    assert make_controller("nmpc", fixed, fixed_eq, DT, task).disturbance == "input"
    on_ekf = make_controller("nmpc", model, eq, DT, {**TASK, "estimator": "ekf"})
    assert on_ekf.inner.disturbance == "none" and on_ekf.fed == [M]  # one estimate, the EKF's
    mpc = make_controller("nmpc", model, eq, DT, TASK)
    with pytest.raises(ParameterError, match="disturbance 'load'"):
        export_controller_fmu(mpc, model, tmp_path / "nmpc.fmu", 5e4)


def test_the_filters_estimate_stays_out_of_the_measurement_to_command_path(plant):
    """With the filter on, each sample's command comes from the preparation made between
    samples (one preparation per sample, after the command): the estimate changes every
    sample, and re-preparing on it inside the sample would make the latency the whole
    step instead of the feedback. The command uses the last sample's estimate."""
    model, eq = plant
    mpc = make_controller("nmpc", model, eq, DT, TASK)
    eng = mpc.engine
    calls = {"prepare": 0}
    prepare = eng.calls["prepare"]

    def counted(*args):
        calls["prepare"] += 1
        return prepare(*args)

    eng.calls["prepare"] = counted
    hold(model, eq, mpc, 5, k_load=0)  # first sample: no guess yet, prepared in the sample
    calls["prepare"] = 0
    errors, estimates = hold_more(model, eq, mpc, 30)
    assert calls["prepare"] == 30  # one per sample, none in the measurement-to-command path
    assert np.ptp(estimates) > 1e-4  # the estimate did move every sample (the load step)


def hold_more(model, eq, mpc, samples):
    """``hold`` continued without a reset of the controller: +50 g on the plant."""
    sim = Simulator(model)
    sim.reset(x0=eq.x)
    p = eq.p.copy()
    p[model.param_names.index(M)] += 0.05
    sim.p = p
    errors, estimates = [], []
    for _ in range(samples):
        u = mpc.checked(sim.t, sim.signals(mpc.outputs), {L: eq[L]})
        sim.step({P: u[P]}, DT)
        errors.append(sim.signal(L) - eq[L])
        estimates.append(mpc.disturbance_estimate)
    return np.array(errors), np.array(estimates)
