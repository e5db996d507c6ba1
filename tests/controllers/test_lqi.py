"""LQI: the design against an independent Riccati solution, its steady states against the
model's equilibria, and the closed loop on the nonlinear plant and with interconnect."""

import control as ct
import numpy as np
import pytest
import scipy.linalg as sla

from sarcomere.controllers import make_controller, operating_point
from sarcomere.controllers.linearize import linearize
from sarcomere.controllers.loop import run_closed_loop
from sarcomere.controllers.lqi import LQI
from sarcomere.dynamics import hanging_load, solve_equilibrium
from sarcomere.dynamics.errors import ParameterError

DT = 0.01
L, P = "myofibril.length", "regulator.p_cmd"
TASK = {"output": L, "input": P, "u_min": 0.0, "u_max": 1e5}


@pytest.fixture(scope="module")
def setup():
    m = hanging_load(1, load_kg=0.02)
    op = operating_point(m, {P: 5e4})
    return m, op, make_controller("lqi", m, op, DT, TASK)


def test_gains_solve_the_discrete_riccati_equation(setup):
    """Kx, Ki from scipy's DARE on the augmented model built here by hand."""
    m, op, c = setup
    w, n = c.weights, m.nx
    d = linearize(m, op, [L], dt=DT)
    Aa = np.block([[d.A, np.zeros((n, 1))], [DT * d.C, np.ones((1, 1))]])
    Ba = np.vstack([d.B, DT * d.D])
    Q = sla.block_diag(w.q_y / w.y_scale**2 * d.C.T @ d.C, [[w.q_i / w.y_scale**2]])
    R = np.array([[w.r_u / w.u_scale**2]])
    S = sla.solve_discrete_are(Aa, Ba, Q, R)
    K = np.linalg.solve(R + Ba.T @ S @ Ba, Ba.T @ S @ Aa)
    np.testing.assert_allclose(np.append(c.Kx, c.Ki), K[0], rtol=1e-6)
    assert np.all(np.abs(np.linalg.eigvals(Aa - Ba @ K)) < 1)


def test_matching_reference_gives_the_steady_input(setup):
    m, op, c = setup
    for ff in ("equilibria", "linear"):
        lqi = make_controller("lqi", m, op, DT, {**TASK, "feedforward": ff})
        lqi.reset({P: float(op.u[0])})
        y = {n: float(v) for n, v in zip(m.state_names, op.x, strict=True)} | {L: op[L]}
        for k in range(3):
            assert lqi.checked(k * DT, y, {L: op[L]})[P] == pytest.approx(op.u[0], rel=1e-8)


def test_steady_state_targets(setup):
    """Linear map: a steady state of the sampled linearisation with the reference's
    output. Equilibria map: the input that the equilibrium solver puts at that length."""
    m, op, c = setup
    d = linearize(m, op, [L], dt=DT)
    dr = -5e-4
    x_lin, u_lin = c.Nx * dr, c.Nu * dr
    np.testing.assert_allclose(d.A @ x_lin + d.B[:, 0] * u_lin, x_lin, atol=1e-12)
    assert float((d.C @ x_lin)[0] + d.D[0, 0] * u_lin) == pytest.approx(dr, rel=1e-9)
    dx, du = c.target(dr)
    again = solve_equilibrium(m, {P: float(op.u[0] + du)}, guess=op)
    assert again[L] - op[L] == pytest.approx(dr, rel=2e-3)  # grid interpolation
    assert abs(du - u_lin) > 1e-3 * abs(u_lin)  # the two maps do differ


def test_nonlinear_closed_loop_step(setup):
    """With the linear feed-forward (some 9 % off for this step) the integral removes
    the error on the nonlinear plant."""
    m, op, _ = setup
    c = make_controller("lqi", m, op, DT, {**TASK, "feedforward": "linear"})
    target = op[L] - 1.5e-3
    run = run_closed_loop(m, c, op, lambda t: target, 1.5, output=L)
    y = run.result[L]
    assert y[-1] == pytest.approx(target, abs=2e-5)
    assert run.result[P].max() <= 1e5 and run.result[P].min() >= 0


def test_as_iosystem_with_the_linear_plant(setup):
    m, op, c = setup
    plant = linearize(m, op, [*m.state_names, L], dt=DT)
    loop = ct.interconnect(
        [plant, c.as_iosystem()], inplist=["reference"], outlist=["myofibril__length"]
    )
    t = np.arange(200) * DT
    resp = ct.input_output_response(loop, t, np.full(len(t), -1e-3))
    assert resp.outputs[-1] == pytest.approx(-1e-3, rel=1e-3)
    assert abs(resp.outputs[15]) > 0.9e-3  # within 0.15 s, not through the integral


@pytest.mark.parametrize(
    ("key", "value"),
    [("q_i", -1.0), ("r_u", 0.0), ("estimator", "kalman"), ("feedforward", "x"), ("qq", 1)],
)
def test_bad_settings_name_the_setting(setup, key, value):
    m, op, _ = setup
    with pytest.raises(ParameterError, match=rf"'lqi\.{key}'"):
        make_controller("lqi", m, op, DT, {**TASK, key: value})


def test_anti_windup_holds_the_integral_while_saturated(setup):
    """A reference the input cannot reach, with the measurement held at the operating
    point: the command sits at u_max and the integral does not move (it would grow by
    dt * 3 mm every sample). Back on a reachable reference, the command returns to the
    operating input at once; a wound-up integral would keep it at the bound."""
    m, op, _ = setup
    u_max = 6e4  # above the operating 50 kPa, far below what 3 mm shorter needs
    c = make_controller("lqi", m, op, DT, {**TASK, "u_max": u_max, "feedforward": "linear"})
    c.reset({P: float(op.u[0])})
    y = {n: float(v) for n, v in zip(m.state_names, op.x, strict=True)} | {L: op[L]}
    far = op[L] - 3e-3
    assert c.u_op - c.Nu * 3e-3 > u_max  # the linear steady state is beyond the bound
    for k in range(50):
        assert c.checked(k * DT, y, {L: far})[P] == u_max
        assert c.xi == 0.0  # held: integrating would push further past u_max
    u = c.checked(0.5, y, {L: op[L]})[P]
    assert u == pytest.approx(op.u[0], rel=1e-12)  # no windup to unwind
    # unwinding is not blocked: a wound integral (set by hand) moves back while saturated
    c.reset({P: float(op.u[0])})
    wound = -1e-3 * np.sign(c.Ki)  # -Ki xi = |Ki| 1e-3 Pa above the operating input
    assert abs(c.Ki) * 1e-3 > 2 * (u_max - c.u_op)
    c.xi = wound
    assert c.checked(0.0, y, {L: op[L] + 1e-4})[P] == u_max  # still saturated
    assert c.xi == pytest.approx(wound + DT * (0.0 - 1e-4), rel=1e-12)  # unwinding: allowed


def test_the_class_itself_refuses_bounds_that_cannot_hold_the_operating_point(setup):
    m, op, c = setup
    with pytest.raises(ParameterError, match=r"'lqi\.u_max' = 1\.0.*\[50000, 600000\] Pa"):
        LQI(DT, m, op, L, P, 0.0, 1.0, c.weights)


def test_rate_limit_clamps_the_command_and_holds_the_integral(setup):
    """rate_max 1 MPa/s at 10 ms (10 kPa per sample), the bounds far away, a reference
    3 mm shorter with the measurement held at the operating point: the command ramps by
    exactly 10 kPa a sample and the integral does not move while the rate holds it (it
    would grow by dt * 3 mm every sample). Back on the operating reference, the command
    comes down from where the ramp stopped, at the rate limit, with nothing to unwind."""
    m, op, _ = setup
    du = 1e6 * DT
    c = make_controller(
        "lqi", m, op, DT, {**TASK, "u_max": 5e5, "feedforward": "linear", "rate_max": 1e6}
    )
    assert c.du_max == pytest.approx(du)
    c.reset({P: float(op.u[0])})
    y = {n: float(v) for n, v in zip(m.state_names, op.x, strict=True)} | {L: op[L]}
    far = op[L] - 3e-3
    assert c.u_op - c.Nu * 3e-3 > c.u_op + 5 * du  # the law asks more than 5 moves
    for k in range(5):
        u = c.checked(k * DT, y, {L: far})[P]
        assert u == pytest.approx(op.u[0] + (k + 1) * du, rel=1e-12)
        assert c.xi == 0.0  # held by the rate: integrating would push further
    back = c.checked(0.05, y, {L: op[L]})[P]
    assert back == pytest.approx(u - du, rel=1e-12)  # the law wants u_op: one move down
    assert c.xi == 0.0


def test_rate_limit_is_refused_unless_positive_and_in_the_io_system(setup):
    m, op, _ = setup
    with pytest.raises(ParameterError, match=r"'lqi\.rate_max'"):
        make_controller("lqi", m, op, DT, {**TASK, "rate_max": -1.0})
    c = make_controller("lqi", m, op, DT, {**TASK, "rate_max": 2e6})
    with pytest.raises(ParameterError, match=r"'lqi\.rate_max'.*no rate limit"):
        c.as_iosystem()


def test_rate_design_gains_solve_the_riccati_equation_of_the_move(setup):
    """``rate_weight``: the move per sample is the input, the held command a state; the
    gains are scipy's DARE on that model built here by hand, the loop is stable, and the
    law's command is ``u_prev - K z`` (a move, clamped to the rate limit)."""
    m, op, _ = setup
    c = make_controller("lqi", m, op, DT, {**TASK, "rate_max": 2e6, "rate_weight": 10.0})
    w, n, du = c.weights, m.nx, 2e6 * DT
    d = linearize(m, op, [L], dt=DT)
    Aa = sla.block_diag(np.block([[d.A, d.B], [np.zeros((1, n)), np.ones((1, 1))]]), [[1.0]])
    Aa[n + 1, :n], Aa[n + 1, n] = DT * d.C[0], DT * d.D[0, 0]
    Ba = np.vstack([d.B, [[1.0]], DT * d.D])
    Q = sla.block_diag(
        w.q_y / w.y_scale**2 * d.C.T @ d.C, [[w.r_u / w.u_scale**2]], [[w.q_i / w.y_scale**2]]
    )
    R = np.array([[10.0 / du**2]])
    S = sla.solve_discrete_are(Aa, Ba, Q, R)
    K = np.linalg.solve(R + Ba.T @ S @ Ba, Ba.T @ S @ Aa)
    np.testing.assert_allclose(np.concatenate([c.Kx, [c.Ku, c.Ki]]), K[0], rtol=1e-6)
    assert np.all(np.abs(np.linalg.eigvals(Aa - Ba @ K)) < 1)
    u_prev, dx = c.u_op + 3e3, np.full(n, 1e-6)
    xi, u = c.law(2e-5, dx, 0.0, 0.0, u_prev, linear=True)  # target: the op itself
    move = -(c.Kx @ dx + c.Ku * 3e3 + c.Ki * 2e-5)
    assert u == pytest.approx(np.clip(u_prev + move, u_prev - du, u_prev + du), rel=1e-12)
