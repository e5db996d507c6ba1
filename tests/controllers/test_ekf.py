"""The EKF: its prediction against the plant's own integrator and central differences,
its estimates of unmeasured states from noisy length and pressure, LQI on its estimate."""

import numpy as np
import pytest

from sarcomere.controllers import make_controller, operating_point
from sarcomere.controllers.ekf import EKF
from sarcomere.controllers.loop import run_closed_loop
from sarcomere.dynamics import Simulator, hanging_load
from sarcomere.dynamics.errors import ParameterError

DT = 0.01
L, P, POUT = "myofibril.length", "regulator.p_cmd", "regulator.p_out"
STD = {L: 2e-5, POUT: 200.0}


@pytest.fixture(scope="module")
def plant():
    m = hanging_load(1, load_kg=0.02)
    return m, operating_point(m, {P: 5e4})


def test_prediction_matches_cvodes_and_its_jacobian_central_differences(plant):
    """The augmented state is [x; load.m]: the prediction of x against CVODES at the
    same load, the Jacobian's columns (a state, the load) against central differences."""
    m, op = plant
    ekf = EKF(m, op, DT, [L, POUT], STD, disturbance_std={"load.m": 0.02})
    load = op.p[m.param_names.index("load.m")]
    xa, u = np.append(op.x, load), np.array([6e4])
    xf, F = (np.array(v) for v in ekf._predict(xa, u, op.p))
    assert xf[-1, 0] == load  # a random walk predicts no change
    sim = Simulator(m)
    sim.reset(x0=op.x)
    sim.step({P: 6e4}, DT)
    change = np.abs(sim.x - op.x)
    assert np.all(np.abs(xf[: m.nx, 0] - sim.x) <= 0.03 * change + 1e-15)
    for i, h in ((m.state_names.index("myofibril.aps1.expansion.s"), 1e-7), (m.nx, 1e-5)):
        plus, minus = xa.copy(), xa.copy()
        plus[i] += h
        minus[i] -= h
        fd = np.array(ekf._predict(plus, u, op.p)[0]) - np.array(ekf._predict(minus, u, op.p)[0])
        np.testing.assert_allclose(F[:, i], fd.ravel() / (2 * h), rtol=1e-5, atol=1e-9)
    assert np.any(np.abs(F[: m.nx, m.nx]) > 1e-3)  # the load does move the states


def test_estimates_unmeasured_states_from_noisy_measurements(plant):
    """Open loop, a pressure staircase, and 30 g hung on the plant at t = 0 unknown to the
    filter: from the noisy length and regulator pressure alone it finds the load, the
    length (filtered below the noise) and the chamber's air mass."""
    m, op = plant
    ekf = EKF(m, op, DT, [L, POUT], STD, disturbance_std={"load.m": 0.002})
    sim = Simulator(m)
    heavy = operating_point(m, {P: 5e4}, load_kg=0.05)
    sim.reset(x0=op.x)
    sim.p = heavy.p
    rng = np.random.default_rng(3)
    mair = m.state_names.index("myofibril.aps1.chamber.m_air")
    errs, excursion, len_err = [], [], []
    u_prev = 5e4  # held before the first sample
    for k in range(150):
        u = 5e4 + (2e4 if (k // 40) % 2 else 0.0)
        s = sim.signals([L, POUT])
        y = {n: s[n] + STD[n] * rng.standard_normal() for n in (L, POUT)}
        est = ekf.estimate(y, u_prev)  # the input held over the last sample
        if k >= 50:  # after the 30 g drop
            errs.append(est[mair] - sim.x[mair])
            excursion.append(sim.x[mair] - op.x[mair])
            len_err.append(np.array(ekf._measure(ekf.xa, [u], op.p)[0]).ravel()[0] - s[L])
        sim.step({P: u}, DT)
        u_prev = u
    assert np.sqrt(np.mean(np.square(errs))) < 0.05 * np.ptp(excursion)
    assert np.sqrt(np.mean(np.square(len_err))) < 0.7 * STD[L]  # filtered, not just copied
    assert ekf.parameters["load.m"] == pytest.approx(
        heavy.p[m.param_names.index("load.m")], rel=0.03
    )


def test_bad_settings_name_the_setting(plant):
    m, op = plant
    with pytest.raises(ParameterError, match="ekf.noise_std.myofibril.length"):
        EKF(m, op, DT, [L], {L: 0.0})
    with pytest.raises(ParameterError, match="ekf.substeps"):
        EKF(m, op, DT, [L], STD, substeps=0)
    task = {"output": L, "input": P, "u_min": 0.0, "u_max": 1e5, "estimator": "ekf"}
    with pytest.raises(ParameterError, match="'ekf.input_sd'"):
        make_controller("lqi", m, op, DT, {**task, "ekf": {"input_sd": 1.0}})


def test_lqi_on_the_estimate_tracks_a_step(plant):
    m, op = plant
    task = {"output": L, "input": P, "u_min": 0.0, "u_max": 1e5, "noise_std": STD}
    c = make_controller("lqi", m, op, DT, {**task, "estimator": "ekf"})
    assert c.outputs == [L, POUT]  # reads only what is measured
    target = op[L] - 1e-3
    run = run_closed_loop(m, c, op, lambda t: target, 1.0, output=L, noise_std=STD, seed=2)
    assert np.mean(run.result[L][-20:]) == pytest.approx(target, abs=3 * STD[L])
