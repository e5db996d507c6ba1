"""The linear MPC's disturbance models: its own Kalman filter of the load, an input or an
output offset, on the states it reads; the model re-linearised at the estimate and the
target. Without an estimate of the load the 3-APS loop rings after +50 g (its model's load
mode is 1.9x too fast); with it, it settles."""

import numpy as np
import pytest

from sarcomere.controllers import make_controller
from sarcomere.controllers.disturbance import DisturbanceFilter
from sarcomere.dynamics import Simulator, hanging_load, solve_equilibrium
from sarcomere.dynamics.errors import ParameterError

P = "regulator.p_cmd"
L = "myofibril.length"
M = "load.m"
TASK = {"output": L, "input": P, "u_min": 0.0, "u_max": 3e5, "rate_max": 2e6, "tension_min": 0.0}


@pytest.fixture(scope="module")
def three():
    plant = hanging_load(3, load_kg=0.02)
    return plant, solve_equilibrium(plant, {P: 5e4})


def hold(plant, eq, mpc, samples, load_at=None, d_in=0.0, d_out=0.0):
    """10 ms samples of ``mpc`` holding the length from ``eq``; +50 g at sample
    ``load_at``, ``d_in`` [Pa] added to every command, ``d_out`` [m] to the measured
    length. Returns the length errors [m]."""
    sim = Simulator(plant)
    sim.reset(x0=eq.x)
    sim.p = eq.p.copy()
    errors = []
    for k in range(samples):
        if k == load_at:
            p = sim.p.copy()
            p[plant.param_names.index(M)] += 0.05
            sim.p = p
        y = sim.signals(mpc.outputs)
        y[L] += d_out
        u = mpc.checked(sim.t, y, {L: eq[L]})
        sim.step({P: u[P] + d_in}, 0.01)
        errors.append(sim.signal(L) - eq[L])
    return np.array(errors)


def test_the_load_filter_finds_the_load_and_stops_the_ringing(three):
    plant, eq = three
    m = eq.p[plant.param_names.index(M)]
    rms = {}
    for model in ("load", "none"):  # at the move weight the values below were measured with
        own = {**TASK, "disturbance": model, "weight_du": 1e-7}  # (3e-7 rings 0.07 mm)
        mpc = make_controller("lmpc", plant, eq, 0.01, own)
        err = hold(plant, eq, mpc, 200, load_at=20)
        rms[model] = float(np.sqrt(np.mean(err[120:] ** 2)))  # from 1 s after the step
    assert mpc.disturbance_estimate == 0.0
    mpc = make_controller("lmpc", plant, eq, 0.01, TASK)
    assert mpc.disturbance == "load"  # the default where the model has a load
    hold(plant, eq, mpc, 200, load_at=20)
    assert mpc.disturbance_estimate == pytest.approx(m + 0.05, abs=1e-4)
    assert mpc.parameters[M] == mpc.disturbance_estimate  # the prediction's load
    assert rms["load"] < 1e-5  # 2 um
    assert rms["none"] > 2e-4  # 0.57 mm: the 20 g model rings on the 70 g plant


def test_an_input_offset_is_estimated_and_an_output_offset_too(three):
    """A constant 10 kPa added to every command, or 0.1 mm to the measured length: at
    steady state the filter's estimate is that constant (all states read, the model
    exact: the one-step residual is ``E d``), and the length settles on the reference
    minus the output offset (the loop regulates what it measures)."""
    plant, eq = three
    mpc = make_controller("lmpc", plant, eq, 0.01, {**TASK, "disturbance": "input"})
    err = hold(plant, eq, mpc, 150, d_in=1e4)
    assert mpc.disturbance_estimate == pytest.approx(1e4, rel=1e-3)
    assert np.max(np.abs(err[-20:])) < 1e-6
    mpc = make_controller("lmpc", plant, eq, 0.01, {**TASK, "disturbance": "output"})
    err = hold(plant, eq, mpc, 150, d_out=1e-4)
    assert mpc.disturbance_estimate == pytest.approx(1e-4, rel=1e-3)
    assert err[-1] == pytest.approx(-1e-4, rel=1e-3)


def test_the_scalar_filter_is_the_kalman_filter():
    """The Sherman-Morrison form equals the textbook update ``K = P E^T (E P E^T + S)^-1``."""
    rng = np.random.default_rng(5)
    E, Q = rng.normal(size=4), rng.normal(size=(4, 4))
    S = Q @ Q.T + np.eye(4)
    f = DisturbanceFilter(E, S, 0.3, 2.0)
    e = rng.normal(size=4)
    P = 2.0 + 0.3
    K = P * E @ np.linalg.inv(P * np.outer(E, E) + S)
    assert f.update(e) == pytest.approx(K @ e, rel=1e-12)
    assert f.variance == pytest.approx(P - P * (K @ E), rel=1e-12)


def test_a_bad_disturbance_model_is_refused():
    plant = hanging_load(1, load_kg=0.02)
    eq = solve_equilibrium(plant, {P: 5e4})
    with pytest.raises(ParameterError, match="lmpc.disturbance"):
        make_controller("lmpc", plant, eq, 0.01, {**TASK, "disturbance": "wind"})
