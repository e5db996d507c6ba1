"""The LQI given what the MPCs are given (issue 24, honest comparisons): the reference
ahead through the LQ-optimal preview term, and the load estimate as a feed-forward of the
target; the PID's preview."""

import numpy as np
import pytest
import scipy.linalg as sla

from sarcomere.controllers import make_controller, operating_point
from sarcomere.controllers.linearize import linearize
from sarcomere.controllers.loop import Disturbance, run_closed_loop
from sarcomere.dynamics import hanging_load
from sarcomere.dynamics.errors import ParameterError

DT = 0.01
L, P = "myofibril.length", "regulator.p_cmd"
TASK = {"output": L, "input": P, "u_min": 0.0, "u_max": 1e5}


@pytest.fixture(scope="module")
def plant():
    m = hanging_load(1, load_kg=0.02)
    return m, operating_point(m, {P: 5e4})


def test_preview_term_is_the_first_move_of_the_lq_problem_with_known_targets(plant):
    """The state on its target, the target moving ``w_j`` at known samples ahead: the
    preview move equals the first move of the finite LQ problem over 400 samples with
    the Riccati solution as terminal cost, solved here as one least-squares problem."""
    m, op = plant
    N = 20
    c = make_controller("lqi", m, op, DT, {**TASK, "preview": N, "feedforward": "linear"})
    w, n = c.weights, m.nx
    d = linearize(m, op, [L], dt=DT)
    A = np.block([[d.A, np.zeros((n, 1))], [DT * d.C, np.ones((1, 1))]])
    B = np.vstack([d.B, DT * d.D])
    Q = sla.block_diag(w.q_y / w.y_scale**2 * d.C.T @ d.C, [[w.q_i / w.y_scale**2]])
    R = np.array([[w.r_u / w.u_scale**2]])
    S = sla.solve_discrete_are(A, B, Q, R)
    refs = -1e-3 * (np.arange(N + 1) >= 7) + 4e-4 * np.sin(np.arange(N + 1))  # dr ahead
    shift = np.zeros((N, n + 1))
    shift[:, :n] = -np.outer(np.diff(refs), c.Nx)  # w_j = z_ss(r_j) - z_ss(r_j+1)
    H, na = 400, n + 1
    # e_k = A^k e_0 + sum_i A^(k-1-i) (B u_i + w_i); minimise sum e'Qe + u'Ru + e_H' S e_H
    Phi, off = np.zeros((H * na, H)), np.zeros(H * na)
    e_free, blocks = np.zeros(na), []
    for k in range(H):  # e_{k+1} in rows k
        e_free = A @ e_free + (shift[k] if k < N else 0)
        off[k * na : (k + 1) * na] = e_free
        blocks.append(np.linalg.matrix_power(A, k) @ B)
    for k in range(H):
        for i in range(k + 1):
            Phi[k * na : (k + 1) * na, i] = blocks[k - i][:, 0]
    root = sla.block_diag(np.sqrt(w.q_y) / w.y_scale * d.C, [[np.sqrt(w.q_i) / w.y_scale]])
    np.testing.assert_allclose(root.T @ root, Q)  # a factor of the stage weight
    weights = [root] * (H - 1) + [sla.cholesky(S)]
    Wq = sla.block_diag(*weights)
    lhs = np.vstack([Wq @ Phi, np.sqrt(R[0, 0]) * np.eye(H)])
    rhs = np.concatenate([-Wq @ off, np.zeros(H)])
    u0 = np.linalg.lstsq(lhs, rhs, rcond=None)[0][0]
    c.reset({P: float(op.u[0])})
    c.set_preview({L: list(op[L] + refs[1:])})
    ff = c.feedforward({L: op[L] + refs[0]}, op.x, refs[0])
    assert ff[n + 1] == pytest.approx(u0, rel=1e-6)
    # and the law adds it: the command moves before the step it sees coming
    c.reset({P: float(op.u[0])})
    y = {s: float(v) for s, v in zip(m.state_names, op.x, strict=True)} | {L: op[L]}
    c.set_preview({L: [op[L]] * 5 + [op[L] - 1e-3] * (N - 5)})
    assert c.checked(0.0, y, {L: op[L]})[P] > op.u[0] + 100  # shorter ahead: more pressure


@pytest.mark.slow  # over 0.8 s: the fast loop leaves it to the full suite
def test_load_feedforward_makes_the_lqi_offset_free_without_its_integral(plant):
    """+30 g hung on the plant at 0.2 s, unknown to the controller: with the load estimate
    as feed-forward (its own filter on the states, or the EKF's) the estimate finds the
    load and the target carries it, so the integral ends near zero (measured: 3 % of the
    plain LQI's); without, the integral alone holds the length."""
    m, op = plant
    y0 = op[L]
    ends = {}
    for key, extra in {
        "integral": {},
        "own filter": {"load_feedforward": True},
        "ekf": {"load_feedforward": True, "estimator": "ekf"},
    }.items():
        c = make_controller("lqi", m, op, DT, {**TASK, "u_max": 3e5, **extra})  # 145 kPa
        run = run_closed_loop(
            m, c, op, lambda t: y0, 3.0, output=L, disturbance=Disturbance(0.2, "load.m", 0.03)
        )
        assert abs(run.result[L][-1] - y0) < 5e-6 and run.status == "ok", key
        ends[key] = (c.xi, getattr(c, "load_estimate", None))
    m_true = op.p[m.param_names.index("load.m")] + 0.03
    for key in ("own filter", "ekf"):
        xi, m_est = ends[key]
        assert m_est == pytest.approx(m_true, rel=0.03), key
        assert abs(xi) < 0.1 * abs(ends["integral"][0]), (key, ends)


def test_load_feedforward_needs_a_load_and_its_estimate(plant):
    m, op = plant
    with pytest.raises(ParameterError, match="load_feedforward"):
        make_controller(
            "lqi",
            m,
            op,
            DT,
            {**TASK, "load_feedforward": True, "estimator": "ekf", "ekf": {"disturbance_std": {}}},
        )
    c = make_controller("lqi", m, op, DT, {**TASK, "preview": 3})
    with pytest.raises(ParameterError, match="preview"):
        c.law_function()  # the exported law takes r(t) only


def test_pid_preview_tracks_the_reference_that_far_ahead(plant):
    m, op = plant
    ahead = make_controller("pid", m, op, DT, {**TASK, "preview": 4})
    plain = make_controller("pid", m, op, DT, TASK)
    u0 = {P: float(op.u[0])}
    ahead.reset(u0)
    plain.reset(u0)
    y0 = op[L]
    for k in range(5):
        r_far = y0 - 1e-4 * k
        ahead.set_preview({L: [y0, y0, y0, r_far]})
        got = ahead.checked(k * DT, {L: y0}, {L: y0})
        assert got == plain.checked(k * DT, {L: y0}, {L: r_far})
    assert ahead.preview_samples == 4 and plain.preview_samples == 0
