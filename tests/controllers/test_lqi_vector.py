"""The LQI on vector outputs and inputs (the antagonistic joint's two commands on its
angle and stiffness): the gains against scipy's Riccati solution on an augmented model
built here, the steady-state map against its defining equations, the closed loop on the
nonlinear joint with both tendons taut, and the refusals."""

import numpy as np
import pytest
import scipy.linalg as sla

from sarcomere.controllers import make_controller
from sarcomere.controllers.linearize import linearize
from sarcomere.controllers.loop import run_closed_loop
from sarcomere.controllers.lqi import LQI, LQIWeights
from sarcomere.dynamics import antagonistic_joint, solve_equilibrium
from sarcomere.dynamics.errors import ParameterError
from sarcomere.fmu.controller import lqi_system

DT = 0.01
F, E = "flexor_regulator.p_cmd", "extensor_regulator.p_cmd"
OUT = ["joint.theta", "stiffness.K"]
TASK = {"output": OUT, "input": [F, E], "u_min": 0.0, "u_max": 4e5, "feedforward": "linear"}


@pytest.fixture(scope="module")
def joint():
    m = antagonistic_joint(3, fidelity="symmetric")
    return m, solve_equilibrium(m, {F: 1.5e5, E: 1.5e5})


@pytest.mark.parametrize("seed", [0, 1])
def test_vector_gains_solve_the_discrete_riccati_equation(joint, seed):
    """Kx, Ki from scipy's DARE on the model with both error integrals appended, built
    here by hand, for generated weights and scales; Nx, Nu solve the steady state."""
    m, op = joint
    rng = np.random.default_rng(seed)
    ys = (10 ** rng.uniform(-2, -0.5), 10 ** rng.uniform(-5, -3))
    w = LQIWeights(q_y=10 ** rng.uniform(0, 3), q_i=10 ** rng.uniform(1, 3), y_scale=ys)
    c = LQI(DT, m, op, OUT, [F, E], 0.0, 4e5, w, feedforward="linear")
    d = linearize(m, op, OUT, dt=DT, inputs=[F, E])
    n = m.nx
    Aa = np.block([[d.A, np.zeros((n, 2))], [DT * d.C, np.eye(2)]])
    Ba = np.vstack([d.B, DT * d.D])
    Wy = np.diag(1 / np.square(ys))
    Q = sla.block_diag(w.q_y * d.C.T @ Wy @ d.C, w.q_i * Wy)
    R = w.r_u / w.u_scale**2 * np.eye(2)
    S = sla.solve_discrete_are(Aa, Ba, Q, R)
    K = np.linalg.solve(R + Ba.T @ S @ Ba, Ba.T @ S @ Aa)
    np.testing.assert_allclose(np.hstack([c.Kx, c.Ki]), K, rtol=1e-5, atol=1e-9 * abs(K).max())
    assert np.all(np.abs(np.linalg.eigvals(Aa - Ba @ K)) < 1)
    np.testing.assert_allclose(
        (d.A - np.eye(n)) @ c.Nx + d.B @ c.Nu, 0, atol=1e-9 * abs(c.Nx).max()
    )
    np.testing.assert_allclose(d.C @ c.Nx + d.D @ c.Nu, np.eye(2), atol=1e-9)


@pytest.mark.slow
def test_two_input_lqi_tracks_an_angle_step_with_both_tendons_taut(joint):
    """0.2 rad step at a held stiffness on the nonlinear joint: settled to 1 mrad and 0.1 %
    of the stiffness within 1.9 s, both tendons above 0.2 N throughout, the flexor's
    command the higher (it holds the flexion)."""
    m, op = joint
    task = {**TASK, "y_scale": [0.1, 1e-4], "rate_max": 2e6}
    c = make_controller("lqi", m, op, DT, task)
    th0, K0 = op["joint.theta"], op["stiffness.K"]
    run = run_closed_loop(
        m, c, op, lambda t: (th0 + (0.2 if t >= 0.1 else 0.0), K0), 2.0, output=OUT
    )
    r = run.result
    assert run.status == "ok"
    assert abs(r["joint.theta"][-1] - th0 - 0.2) < 1e-3
    assert abs(r["stiffness.K"][-1] / K0 - 1) < 1e-3
    np.testing.assert_array_equal(r["stiffness.K.reference"], K0)
    assert min(r["flexor_tendon.T"].min(), r["extensor_tendon.T"].min()) > 0.2
    assert r[F][-1] > r[E][-1] + 1e4  # the flexor's command above the extensor's


@pytest.mark.parametrize(
    "extra, name",
    [
        ({"feedforward": "equilibria"}, "lqi.feedforward"),
        ({"estimator": "ekf"}, "lqi.estimator"),
        ({"preview": 5}, "lqi.preview"),
        ({"rate_weight": 1.0, "rate_max": 2e6}, "lqi.rate_weight"),
        ({"output": ["joint.theta"]}, "lqi.output"),
        ({"input": [F, E, F]}, "lqi.output"),
    ],
)
def test_vector_lqi_refuses_the_one_input_settings(joint, extra, name):
    m, op = joint
    with pytest.raises(ParameterError) as err:
        make_controller("lqi", m, op, DT, {**TASK, **extra})
    assert err.value.name == name


def test_one_input_controllers_and_the_loop_refuse_vectors(joint):
    m, op = joint
    with pytest.raises(ParameterError) as err:
        make_controller("pid", m, op, DT, {**TASK, "feedforward": None})
    assert err.value.name == "pid.output"
    c = make_controller("lqi", m, op, DT, TASK)
    with pytest.raises(ParameterError, match="one output"):
        c.as_iosystem()
    with pytest.raises(ParameterError, match="one output and one input"):
        lqi_system(c, m, 0.0)  # the controller FMU exports a one-input law
    one = {"output": OUT[0], "input": F, "u_min": 0.0, "u_max": 4e5, "preview": 3}
    pid = make_controller("pid", m, op, DT, one)
    with pytest.raises(ParameterError) as err:
        run_closed_loop(m, pid, op, lambda t: (0.0, 0.0), 0.1, output=OUT, preview=True)
    assert err.value.name == "preview"
