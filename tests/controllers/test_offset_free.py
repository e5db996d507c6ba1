"""Offset-free MPC: the prediction's parameters are run-time inputs of the NMPC's solver
Function, and on an EKF the estimated load is fed to them, so a load step leaves no steady
offset without integral action (with the nominal load baked in it leaves millimetres); the
LMPC re-linearises at a parameter fed to it."""

import numpy as np
import pytest

from sarcomere.controllers import make_controller, operating_point
from sarcomere.controllers.base import Controller
from sarcomere.controllers.lmpc import LinearMPC, LMPCSettings
from sarcomere.controllers.nmpc import NMPCSettings, NonlinearMPC
from sarcomere.controllers.qp import zoh
from sarcomere.dynamics import Simulator, hanging_load, solve_equilibrium
from sarcomere.dynamics.errors import ParameterError
from sarcomere.scenarios.studies.mpc_nlp import ConvergedNMPC

P = "regulator.p_cmd"
L = "myofibril.length"
M = "load.m"


@pytest.fixture(scope="module")
def prediction():
    model = hanging_load(1, load_kg=0.02, flow_law="smooth", saturate=False)
    return model, solve_equilibrium(model, {P: 5e4})


@pytest.mark.parametrize("solver", ["rti", "ipopt"])
def test_a_parameter_set_at_run_time_is_the_one_predicted_with(prediction, solver):
    """Built at 20 g, told 50 g more: at the 70 g equilibrium of 0.15 MPa (solved
    independently) it holds that input; with the 20 g it was built with it does not."""
    model, eq = prediction
    heavy_load = eq.p[model.param_names.index(M)] + 0.05
    heavy = solve_equilibrium(model, {P: 1.5e5}, {M: heavy_load})
    settings = NMPCSettings(u_max=3e5, integral_gain=0.0)
    cls = NonlinearMPC if solver == "rti" else ConvergedNMPC
    mpc = cls(model, heavy.u, 0.01, settings)
    y = {n: heavy[n] for n in mpc.outputs}
    nominal = mpc.checked(0.0, y, {L: heavy[L]})[P]
    assert nominal < 1.5e5 - 1e3  # the 20 g prediction wants less pressure
    mpc.reset(heavy.u)
    mpc.set_parameters({M: heavy_load})
    assert mpc.parameters[M] == heavy_load
    for k in range(3):
        assert mpc.checked(0.01 * k, y, {L: heavy[L]})[P] == pytest.approx(1.5e5, abs=1.0)
    mpc.reset(heavy.u)  # reset restores the construction's values
    assert mpc.parameters[M] == eq.p[model.param_names.index(M)]


def test_the_rti_functions_parameter_input_is_the_value_given(prediction):
    model, eq = prediction
    mpc = NonlinearMPC(model, eq.u, 0.01, NMPCSettings())
    F = mpc.engine.calls["prepare"]  # the preparation takes the parameters
    i = F.function.name_in().index("p")
    # the model's parameters, then the input and output disturbances
    assert F.function.nnz_in(i) == len(model.param_names) + 2
    assert mpc.runtime_parameters[-2:] == ("disturbance.input", "disturbance.output")
    mpc.set_parameters({M: 0.0567, "disturbance.input": 123.0})
    mpc.checked(0.0, {n: eq[n] for n in mpc.outputs}, {L: eq[L]})
    passed = F.args[i]
    assert passed[model.param_names.index(M)] == 0.0567
    expected = np.array(model.parameters({M: 0.0567}), dtype=float).ravel()
    assert np.array_equal(passed, [*expected, 123.0, 0.0])


@pytest.mark.parametrize("offset", ["disturbance.input", "disturbance.output"])
def test_an_offset_fed_to_the_nmpc_is_the_one_predicted_with(prediction, offset):
    """Told the plant adds 10 kPa to its command (or 0.2 mm to its measured length), the
    NMPC holds the steady state that has the output on the reference with it: 10 kPa
    less (or the equilibrium 0.2 mm longer, solved independently)."""
    model, eq = prediction
    settings = NMPCSettings(u_max=3e5, integral_gain=0.0)
    if offset == "disturbance.input":
        value, state = 1e4, eq
        u_hold = eq.u[0] - 1e4
    else:  # the true length is 0.2 mm shorter than measured: the target is that length
        value = 2e-4
        state = operating_point(model, {P: 5e4}, target=(L, eq[L] - 2e-4), tol=1e-12)
        u_hold = state.u[0]
    mpc = NonlinearMPC(model, np.array([u_hold]), 0.01, settings)
    mpc.set_parameters({offset: value})
    y = {n: state[n] for n in mpc.outputs}
    for k in range(3):
        u = mpc.checked(0.01 * k, y, {L: eq[L]})[P]
        assert u == pytest.approx(u_hold, abs=1.0)


def test_bad_parameters_are_refused(prediction):
    model, eq = prediction
    mpc = NonlinearMPC(model, eq.u, 0.01)
    with pytest.raises(ParameterError, match="nmpc.parameters.load.mass"):
        mpc.set_parameters({"load.mass": 0.05})
    with pytest.raises(ParameterError, match="nmpc.parameters.load.m"):
        mpc.set_parameters({M: float("nan")})

    class Hold(Controller):
        def update(self, t, y, r):
            return {P: 5e4}

    hold = Hold(0.01, [P], [L], {P: 0.0}, {P: 1e5})
    assert hold.runtime_parameters == ()  # the default: no model, nothing to set
    hold.set_parameters({})
    with pytest.raises(ParameterError, match="controller.parameters"):
        hold.set_parameters({M: 0.05})


TASK = {"output": L, "input": P, "u_min": 0.0, "u_max": 3e5, "estimator": "ekf"}


def _late_error(plant, eq, mpc, samples: int, k_load: int) -> float:
    """10 ms samples of ``mpc`` holding the length from ``eq``, +50 g at sample
    ``k_load``: the largest length error over the last 30 samples [m]."""
    sim = Simulator(plant)
    sim.reset(x0=eq.x)
    sim.p = eq.p.copy()
    errors = []
    for k in range(samples):
        if k == k_load:
            p = sim.p.copy()
            p[plant.param_names.index(M)] += 0.05
            sim.p = p
        y = sim.signals(mpc.outputs)
        sim.step(mpc.checked(sim.t, y, {L: eq[L]}), 0.01)
        errors.append(sim.signal(L) - eq[L])
    return float(np.max(np.abs(errors[-30:])))


def load_step_offset(extra, feed=True):
    """+50 g at 0.2 s on the exact-law plant (1 APS, 20 g), NMPC on the EKF holding the
    length; the largest error over the last 0.3 s of 2 s [m], and the controller."""
    plant = hanging_load(1, load_kg=0.02)
    eq = solve_equilibrium(plant, {P: 5e4})
    mpc = make_controller("nmpc", plant, eq, 0.01, {**TASK, **extra})
    if not feed:  # the former formulation: the prediction keeps the nominal load
        mpc.fed = []
    return _late_error(plant, eq, mpc, 200, 20), mpc, plant, eq


@pytest.mark.slow  # over 0.8 s: the fast loop leaves it to the full suite
def test_the_ekfs_load_estimate_removes_the_offset_without_integral():
    offset, mpc, plant, eq = load_step_offset({})
    assert mpc.fed == [M] and mpc.inner.settings.integral_gain == 0.0  # the default here
    assert offset < 1e-6  # the prediction carries the estimated 70 g: no steady offset
    # the estimate passed is the EKF's, and it is the plant's load
    assert mpc.inner.parameters[M] == mpc.ekf.parameters[M]
    assert mpc.ekf.parameters[M] == pytest.approx(eq.p[plant.param_names.index(M)] + 0.05, abs=1e-4)
    baked, *_ = load_step_offset({}, feed=False)
    assert baked > 1e-3  # the nominal 20 g baked in: 2.8 mm off


def test_the_integral_stays_an_option_on_the_ekf():
    offset, mpc, *_ = load_step_offset({"integral_gain": 5.0})
    assert mpc.inner.settings.integral_gain == 5.0 and offset < 1e-6


def test_the_lmpc_relinearises_at_a_parameter_set_at_run_time():
    """A parameter fed from outside (an EKF's load; the LMPC's own filter off) moved past
    ``relinearize_rel``: the QP's model becomes the linearisation at the steady state
    for the reference at the new load (solved independently by ``operating_point``)."""
    plant = hanging_load(1, load_kg=0.02)
    eq = solve_equilibrium(plant, {P: 5e4})
    mpc = LinearMPC(plant, eq.x, eq.u, 0.01, LMPCSettings(u_max=3e5, disturbance="none"))
    y = {n: eq[n] for n in mpc.outputs}
    mpc.checked(0.0, y, {L: eq[L]})
    assert mpc.relinearizations == 1
    m0 = eq.p[plant.param_names.index(M)]
    mpc.set_parameters({M: m0 * 1.04})  # within relinearize_rel (5 %): kept
    mpc.checked(0.01, y, {L: eq[L]})
    assert mpc.relinearizations == 1
    mpc.set_parameters({M: m0 + 0.05})
    mpc.checked(0.02, y, {L: eq[L]})
    assert mpc.relinearizations == 2 and mpc.parameters[M] == m0 + 0.05
    heavy = operating_point(plant, {P: 5e4}, {M: m0 + 0.05}, target=(L, eq[L]), tol=1e-12)
    x_l, u_l, _ = mpc._lin_point
    assert u_l[0] == pytest.approx(heavy.u[0], rel=1e-8)
    lin = plant.linearization([L])
    A, B, *_ = (np.array(X) for X in lin(heavy.x, np.zeros(0), heavy.u, heavy.p))
    A0, *_ = (np.array(X) for X in lin(eq.x, np.zeros(0), eq.u, eq.p))
    Ad, _ = zoh(A, B, 0.01)
    assert np.allclose(mpc._qp.Ad, Ad, rtol=1e-6, atol=1e-9)
    assert not np.allclose(A, A0, rtol=1e-3)


def lmpc_load_step_residual(feed):
    """+50 g at 0.5 s, LMPC on the EKF holding the length (3 APS, 20 g): the largest error
    over the last 0.3 s of 3 s [m]."""
    plant = hanging_load(3, load_kg=0.02)
    eq = solve_equilibrium(plant, {P: 5e4})
    # the move weight the values below were measured with (the tuned default 3e-7 closes
    # the nominal model's gap faster: 3.5 um instead of 0.19 mm)
    mpc = make_controller("lmpc", plant, eq, 0.01, {**TASK, "weight_du": 1e-7})
    assert mpc.fed == [M]
    if not feed:
        mpc.fed = []
    return _late_error(plant, eq, mpc, 300, 50)


@pytest.mark.slow  # over 0.8 s: the fast loop leaves it to the full suite
def test_the_lmpc_on_the_ekfs_load_settles_faster():
    """The velocity form is offset-free either way; linearised at the nominal 20 g it is
    still 0.19 mm off 2.5 s after the step, at the estimated 70 g a few micrometres."""
    fed, nominal = lmpc_load_step_residual(True), lmpc_load_step_residual(False)
    assert fed < 2e-5 and nominal > 1e-4


def test_the_integral_does_not_wind_up_while_the_command_moves_at_the_rate_limit(prediction):
    """A 2 mm step with 2 kPa per sample: the command ramps at the rate limit for many
    samples, far from its bounds; the integral of the error is frozen on each of them
    (it grew on every one before), and integrates again once the command is free."""
    model, eq = prediction
    s = NMPCSettings(u_max=3e5, rate_max=2e5, integral_gain=5.0)
    mpc = NonlinearMPC(model, eq.u, 0.01, s)
    sim = Simulator(model)
    sim.reset(x0=eq.x)
    ramp, free = 0, 0
    for k in range(60):
        before, u_prev = mpc._offset, mpc._u[0]
        u = mpc.checked(0.01 * k, sim.signals(mpc.outputs), {L: eq[L] - 2e-3})[P]
        assert 0.0 < u < 3e5  # never at a bound
        if abs(u - u_prev) >= 2e3 * (1 - 1e-6):
            ramp += 1
            assert mpc._offset == before
        elif mpc._offset != before:
            free += 1
        sim.step({P: u}, 0.01)
    assert ramp >= 10 and free >= 10
