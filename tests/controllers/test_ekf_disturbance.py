"""The EKF's input and output disturbances (augmented random walks that are not model
parameters), the NMPC's disturbance models fed from them, and the EKF's refusal of the
DAE fidelity level."""

import pytest

from sarcomere.controllers import make_controller
from sarcomere.controllers.ekf import EKF, make_ekf
from sarcomere.dynamics import Simulator, hanging_load, solve_equilibrium
from sarcomere.dynamics.errors import ParameterError

P = "regulator.p_cmd"
L = "myofibril.length"
MEASURED = [L, "regulator.p_out"]
STD = {L: 2e-5, "regulator.p_out": 200.0}


@pytest.fixture(scope="module")
def plant():
    model = hanging_load(1, load_kg=0.02)
    return model, solve_equilibrium(model, {P: 5e4})


def run_ekf(model, eq, ekf, samples, d_in=0.0, d_out=0.0):
    """The plant held at the 50 kPa command plus ``d_in`` [Pa], the length measured
    ``d_out`` [m] long, noise-free; the EKF told the command alone."""
    sim = Simulator(model)
    sim.reset(x0=eq.x)
    for _ in range(samples):
        sim.step({P: 5e4 + d_in}, 0.01)
        y = sim.signals(MEASURED)
        y[L] += d_out
        ekf.estimate(y, 5e4)
    return sim


@pytest.mark.parametrize(
    ("name", "value", "std"),
    [("disturbance.input", 1e4, 2e3), ("disturbance.output", 2e-4, 1e-4)],
)
def test_an_injected_offset_is_the_ekfs_steady_estimate(plant, name, value, std):
    """At steady state the only augmented state explaining the measurements exactly is
    the injected constant (the model is the plant's): 10 kPa on the command, 0.2 mm on the
    measured length."""
    model, eq = plant
    ekf = EKF(model, eq, 0.01, MEASURED, STD, disturbance_std={name: std})
    injected = {("d_in" if name.endswith("input") else "d_out"): value}
    sim = run_ekf(model, eq, ekf, 300, **injected)
    assert ekf.parameters[name] == pytest.approx(value, rel=2e-3)
    assert ekf.xa[: model.nx] == pytest.approx(sim.x, rel=1e-4, abs=1e-7)


def test_bad_offset_settings_are_refused(plant):
    model, eq = plant
    with pytest.raises(ParameterError, match="ekf.disturbance_std"):
        EKF(model, eq, 0.01, MEASURED, STD, disturbance_std={"disturbance.wind": 1.0})
    with pytest.raises(ParameterError, match="ekf.output"):
        EKF(model, eq, 0.01, MEASURED, STD, output="myofibril.actin0.T")


def test_the_dae_level_is_refused_naming_the_level_and_the_allowed_ones():
    model = hanging_load(2, load_kg=0.02, fidelity="static_chain")
    assert model.nz > 0
    eq = solve_equilibrium(model, {P: 5e4})
    with pytest.raises(ParameterError, match="ekf.fidelity") as info:
        make_ekf(model, eq, 0.01, MEASURED, STD, {})
    message = str(info.value)
    assert "'static_chain'" in message and "'full'" in message and "'quasi_static'" in message
    assert "static_chain'," not in message.split("allowed:")[1]  # not among the allowed


def test_the_nmpc_on_the_ekfs_input_disturbance_holds_the_reference(plant):
    """10 kPa added to every command: the NMPC with the input disturbance model (no
    integral) ends on the reference, with the EKF's estimate fed to its prediction."""
    model, eq = plant
    task = {"output": L, "input": P, "u_min": 0.0, "u_max": 3e5, "estimator": "ekf"}
    mpc = make_controller("nmpc", model, eq, 0.01, {**task, "disturbance": "input"})
    assert mpc.fed == ["disturbance.input"] and mpc.inner.settings.integral_gain == 0.0
    sim = Simulator(model)
    sim.reset(x0=eq.x)
    for _ in range(300):
        u = mpc.checked(sim.t, sim.signals(mpc.outputs), {L: eq[L]})
        sim.step({P: u[P] + 1e4}, 0.01)
    # the estimate's time constant is about 0.5 s: 10 nm and 0.5 Pa left after 3 s
    assert sim.signal(L) == pytest.approx(eq[L], abs=1e-7)
    assert mpc.inner.parameters["disturbance.input"] == pytest.approx(1e4, rel=1e-3)
    assert u[P] == pytest.approx(4e4, rel=1e-4)
