"""Linear MPC: the steady input at a matched equilibrium, active bounds and rate limits,
the condensed QP against the closed-form finite-horizon LQ solution, fallbacks and bad
settings."""

import warnings

import numpy as np
import pytest

from sarcomere.controllers import make_controller
from sarcomere.controllers.lmpc import LinearMPC, LMPCSettings
from sarcomere.controllers.qp import VelocityQP, zoh
from sarcomere.dynamics import hanging_load, solve_equilibrium
from sarcomere.dynamics.errors import ParameterError

P = "regulator.p_cmd"
L = "myofibril.length"


@pytest.fixture(scope="module")
def plant():
    model = hanging_load(1, load_kg=0.02)
    return model, solve_equilibrium(model, {P: 4e4})


def measure(mpc, eq):
    return {n: eq[n] for n in mpc.outputs}


@pytest.mark.parametrize("solver", ["daqp", "qpoases"])
def test_matched_equilibrium_gives_the_steady_input(plant, solver):
    model, eq = plant
    mpc = LinearMPC(model, eq.x, eq.u, 0.01, LMPCSettings(qp_solver=solver))
    u = mpc.checked(0.0, measure(mpc, eq), {L: eq[L]})
    assert u[P] == pytest.approx(4e4, abs=1e-6)
    assert np.allclose(mpc._plan, 4e4, atol=1e-6)  # the whole plan holds it
    # a shorter reference asks for more pressure (the sign of the loop)
    mpc.reset(eq.u)
    assert mpc.checked(0.0, measure(mpc, eq), {L: eq[L] - 1e-3})[P] > 4e4 + 100


def test_rate_limit_and_bound_are_active(plant):
    model, eq = plant
    s = LMPCSettings(rate_max=5e5, u_max=5e4, weight_du=1e-9)  # moves nearly free
    mpc = LinearMPC(model, eq.x, eq.u, 0.01, s)
    y = measure(mpc, eq)
    with pytest.warns(UserWarning, match="unreachable"):  # beyond L(u_max): clipped
        u = mpc.checked(0.0, y, {L: eq[L] - 5e-3})[P]
    assert u == pytest.approx(4e4 + 5e3, rel=1e-9)  # the largest move: rate_max * dt
    for k in range(1, 5):  # the same measurement: the command climbs to u_max, not past
        u = mpc.checked(0.01 * k, y, {L: eq[L] - 5e-3})[P]
    assert u == pytest.approx(5e4, rel=1e-12)
    assert np.all(np.abs(np.diff(mpc._plan[:, 0])) <= 5e3 + 1e-6)


def test_relinearized_at_the_target_when_the_output_moved_far(plant):
    """Past ``relinearize_m`` the model is linearised at the target: the steady state with
    the output on the reference (here the 80 kPa equilibrium, solved independently)."""
    model, eq = plant
    # the state jumps (no filter) and the input stays behind (no input trigger)
    s = LMPCSettings(relinearize_m=1e-4, relinearize_u=1.0, disturbance="none")
    mpc = LinearMPC(model, eq.x, eq.u, 0.01, s)
    mpc.checked(0.0, measure(mpc, eq), {L: eq[L]})
    assert mpc.relinearizations == 1
    far = solve_equilibrium(model, {P: 8e4})  # 0.5 mm shorter
    mpc.checked(0.01, measure(mpc, far), {L: far[L]})
    x_l, u_l, y_l = mpc._lin_point
    assert mpc.relinearizations == 2 and y_l == pytest.approx(far[L], rel=1e-12)
    assert u_l[0] == pytest.approx(8e4, rel=1e-9)
    assert x_l == pytest.approx(far.x, rel=1e-8, abs=1e-12)
    mpc.checked(0.02, measure(mpc, far), {L: far[L]})
    assert mpc.relinearizations == 2  # near the new point: kept


def riccati_first_gain(Phi, Gam, Q, R, N):
    """Gain of the first move of the finite-horizon LQ problem (cost on xi_1..xi_N)."""
    P = Q
    for _ in range(N):
        K = np.linalg.solve(R + Gam.T @ P @ Gam, Gam.T @ P @ Phi)
        P = Q + Phi.T @ P @ (Phi - Gam @ K)
    return K


def test_condensed_qp_equals_closed_form_lq(velocity_law_moves):
    rng = np.random.default_rng(3)
    A = np.array([[-2.0, 1.0, 0.0], [0.0, -1.0, 0.5], [0.3, 0.0, -4.0]])
    B = np.array([[0.0], [1.0], [0.5]])
    C = np.array([[1.0, 0.0, 2.0]])
    Ad, Bd = zoh(A, B, 0.1)
    N, q, r = 12, 3.0, 0.2
    qp = VelocityQP(Ad, Bd, C, np.zeros((0, 3)), N, q, r, np.ones(0), np.ones(1))
    xi0 = rng.normal(size=4)
    big = np.full(1, 1e9)
    du, ok = velocity_law_moves(qp, xi0, np.zeros(1), -big, big, big, np.zeros(0))
    assert ok
    Phi = np.block([[Ad, np.zeros((3, 1))], [C @ Ad, np.eye(1)]])
    Gam = np.vstack([Bd, C @ Bd])
    Q = np.diag([0, 0, 0, q])
    K = riccati_first_gain(Phi, Gam, Q, np.array([[r]]), N)
    assert du[0] == pytest.approx(-K @ xi0, rel=1e-8)


def test_failed_qp_falls_back_to_the_shifted_plan(plant):
    model, eq = plant
    mpc = LinearMPC(model, eq.x, eq.u, 0.01)
    y = measure(mpc, eq)
    mpc.checked(0.0, y, {L: eq[L] - 2e-3})
    plan = mpc._plan.copy()
    mpc._p_law[0] = np.nan  # a broken Hessian: the QP's answer is not feasible
    u = mpc.checked(0.01, y, {L: eq[L] - 2e-3})
    assert u[P] == plan[1, 0] and mpc.stats.fallbacks == 1
    assert np.array_equal(mpc._plan, np.vstack([plan[1:], plan[-1:]]))


def test_unreachable_reference_is_clipped_with_a_warning(plant):
    model, eq = plant
    mpc = LinearMPC(model, eq.x, eq.u, 0.01)
    with pytest.warns(UserWarning, match="unreachable"):
        mpc.checked(0.0, measure(mpc, eq), {L: 1.0})
    assert mpc.clip.high < 0.1
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # once per run
        mpc.checked(0.01, measure(mpc, eq), {L: 1.0})


@pytest.mark.parametrize(
    ("kwargs", "name"),
    [
        ({"weight_du": -1.0}, "lmpc.weight_du"),
        ({"horizon": 0}, "lmpc.horizon"),
        ({"rate_max": 0.0}, "lmpc.rate_max"),
    ],
)
def test_bad_settings_name_the_setting(kwargs, name):
    with pytest.raises(ParameterError, match=name):
        LMPCSettings(**kwargs)


def test_too_short_sample_time_is_refused(plant):
    model, eq = plant
    with pytest.raises(ParameterError, match="lmpc.dt"):
        LinearMPC(model, eq.x, eq.u, 1e-3)  # 20 samples of 1 ms < the 50 ms regulator lag


def test_registry_factory_linearizes_the_plant_with_soft_tension_bounds():
    model = hanging_load(1, load_kg=0.05)
    eq = solve_equilibrium(model, {P: 3e4})
    task = {"output": L, "input": P, "u_min": 0.0, "u_max": 1e5, "tension_min": 0.01}
    mpc = make_controller("lmpc", model, eq, 0.01, {**task, "horizon": 10})
    assert mpc.settings.horizon == 10 and mpc.model is model
    assert mpc.settings.soft_min == (("myofibril.actin*.T", 0.01),)
    assert mpc.bounds == [("myofibril.actin0.T", 0.01, 1e4), ("myofibril.actin1.T", 0.01, 1e4)]
    assert mpc.checked(0.0, measure(mpc, eq), {L: eq[L]})[P] == pytest.approx(3e4, abs=1e-6)
    with pytest.raises(ParameterError, match="lmpc.weight"):
        make_controller("lmpc", model, eq, 0.01, {**task, "weight": 1.0})


def test_soft_lower_bound_pulls_the_signal_up_and_is_paid_for(velocity_law_moves):
    """The law the LMPC runs (:func:`velocity_law`) with a soft lower bound on a signal:
    at rest, a bound 0.5 above the signal lifts it onto the bound at the first sample and
    holds it there (the slack costs 100x the tracking); with the state moving down, the
    bound holds on the predicted signal at every node (the sign of the measured motion in
    the bound rows) and binds."""
    Ad, Bd = zoh(np.array([[-1.0]]), np.array([[1.0]]), 0.1)
    C = np.array([[1.0]])
    args = (Ad, Bd, C)
    free = VelocityQP(*args, np.zeros((0, 1)), 10, 1.0, 0.01, np.ones(0), np.ones(1))
    soft = VelocityQP(*args, C, 10, 1.0, 0.01, np.full(1, 100.0), np.ones(1))
    big = np.full(1, 1e9)
    xi0 = np.zeros(2)  # at rest on the reference
    du_free, _ = velocity_law_moves(free, xi0, np.zeros(1), -big, big, big, np.zeros(0))
    du_soft, ok = velocity_law_moves(soft, xi0, np.zeros(1), -big, big, big, np.array([0.5]))
    assert ok and np.allclose(du_free, 0.0)
    assert (Bd @ du_soft[0])[0] == pytest.approx(0.5, rel=1e-6)
    assert du_soft.sum() == pytest.approx(0.5, rel=1e-6)
    # moving down at 0.3 per sample (dx = -0.3) on the reference, bound 0.03 below the
    # signal: the tracking alone lets it sink below (to -0.069); the bound catches it
    xi0 = np.array([-0.3, 0.0])
    du_free, _ = velocity_law_moves(free, xi0, np.zeros(1), -big, big, big, np.zeros(0))
    du, ok = velocity_law_moves(soft, xi0, np.zeros(1), -big, big, big, np.array([-0.03]))

    def signal(moves):  # s_k - s_0 = x_k - x_0 along the prediction
        dx, x, out = xi0[0], 0.0, []
        for m in moves[:, 0]:
            dx = Ad[0, 0] * dx + Bd[0, 0] * m
            x += dx
            out.append(x)
        return np.array(out)

    assert ok and signal(du_free).min() < -0.03 - 0.02  # unbounded, it sinks below
    assert signal(du).min() == pytest.approx(-0.03, abs=1e-3)  # bounded: onto the bound


def test_condensed_qp_tracks_a_reference_per_node(velocity_law_moves):
    """With ``ahead`` (the reference at each node minus r(t)) the QP's moves minimise
    ``sum q (e_k - ahead_k)^2 + r du_k^2``: least squares on the simulated prediction."""
    rng = np.random.default_rng(4)
    A = np.array([[-2.0, 1.0, 0.0], [0.0, -1.0, 0.5], [0.3, 0.0, -4.0]])
    B = np.array([[0.0], [1.0], [0.5]])
    C = np.array([[1.0, 0.0, 2.0]])
    Ad, Bd = zoh(A, B, 0.1)
    N, q, r = 8, 3.0, 0.2
    qp = VelocityQP(Ad, Bd, C, np.zeros((0, 3)), N, q, r, np.ones(0), np.ones(1))
    xi0, ahead = rng.normal(size=4), rng.normal(size=N)
    big = np.full(1, 1e9)
    du, ok = velocity_law_moves(qp, xi0, np.zeros(1), -big, big, big, np.zeros(0), ahead)
    assert ok

    def errors(moves):  # e_1..e_N of xi+ = [Ad dx + Bd du; e + C (Ad dx + Bd du)]
        xi, out = xi0.copy(), []
        for m in moves:
            dx = Ad @ xi[:3] + Bd[:, 0] * m
            xi = np.concatenate([dx, [xi[3] + C[0] @ dx]])
            out.append(xi[3])
        return np.array(out)

    free = errors(np.zeros(N))
    Se = np.column_stack([errors(np.eye(N)[j]) - free for j in range(N)])
    M = np.vstack([np.sqrt(q) * Se, np.sqrt(r) * np.eye(N)])
    rhs = np.concatenate([np.sqrt(q) * (ahead - free), np.zeros(N)])
    assert du.ravel() == pytest.approx(np.linalg.lstsq(M, rhs, rcond=None)[0], rel=1e-7)


def test_preview_moves_the_lmpc_before_a_known_step(plant):
    from sarcomere.controllers.loop import run_closed_loop

    model, _ = plant
    eq = solve_equilibrium(model, {P: 5e4})
    ref = lambda t: eq[L] - (1e-3 if t >= 0.3 else 0.0)  # noqa: E731
    rms, u = {}, {}
    for preview in (False, True):
        mpc = LinearMPC(model, eq.x, eq.u, 0.01, LMPCSettings(weight_du=1e-7))  # values below
        run = run_closed_loop(model, mpc, eq, ref, 0.6, output=L, preview=preview)
        err = run.result[L] - run.result["reference"]
        rms[preview], u[preview] = float(np.sqrt(np.mean(err**2))), run.result[P]
    assert np.allclose(u[False][:30], 5e4, atol=1.0)  # waits for the step
    assert u[True][25] > 6e4  # 66 kPa at 0.25 s: pressurises ahead of it
    assert rms[True] < 0.6 * rms[False]  # 0.20 mm against 0.44 mm RMS


def test_update_is_the_law_function_and_qrqp_gives_the_same_moves(plant):
    """Each sample of :meth:`LinearMPC.update` is one evaluation of ``law_function()`` on
    ``(memory, x, u_prev, ref, law_parameters())``; the same Function built with qrqp (the
    controller FMU's, C code without an external library) gives the same command and
    memory as the DAQP one the Python loop uses."""
    model, eq = plant
    soft = (("myofibril.actin0.T", 0.0), ("myofibril.actin1.T", 0.0))
    settings = LMPCSettings(soft_min=soft, horizon=10, weight_du=1e-7)  # moves > 1 kPa
    mpc = LinearMPC(model, eq.x, eq.u, 0.01, settings)
    qrqp = mpc.law_function("qrqp")
    y = measure(mpc, eq)
    for k in range(4):
        ref = eq[L] - 1e-3 * (k + 1) / 4
        memory, u_prev = mpc.memory, mpc._u.copy()
        x = [*eq.x, y[L], *(y[n] for n, _ in soft)]
        u = mpc.checked(0.01 * k, y, {L: ref})[P]
        mem_q, u_q, ok = qrqp(memory, x, u_prev, np.full(11, ref), mpc.law_parameters())
        assert bool(ok) and mpc.stats.fallbacks == 0
        assert float(u_q) == pytest.approx(u, rel=1e-9)
        assert np.array(mem_q).ravel() == pytest.approx(mpc.memory, rel=1e-9)
    assert u > 4e4 + 1e3  # it moved


def test_relinearized_on_the_state_distance_and_on_the_input_distance(plant):
    """Each trigger alone (the others set out of reach): a jump to the 80 kPa equilibrium
    moves the chamber's air mass about 40 % of its span over 0-0.1 MPa (past a quarter);
    a reference 2 mm shorter ramps the command past 5 % of its range in a few samples."""
    model, eq = plant
    far = solve_equilibrium(model, {P: 8e4})
    only_x = LMPCSettings(relinearize_m=1.0, relinearize_u=10.0, disturbance="none")
    mpc = LinearMPC(model, eq.x, eq.u, 0.01, only_x)
    mpc.checked(0.0, measure(mpc, eq), {L: eq[L]})
    assert mpc.relinearizations == 1
    mpc.checked(0.01, measure(mpc, far), {L: far[L]})
    assert mpc.relinearizations == 2  # the state moved
    only_u = LMPCSettings(
        relinearize_m=1.0, relinearize_x=10.0, relinearize_u=0.05, disturbance="none"
    )
    mpc = LinearMPC(model, eq.x, eq.u, 0.01, only_u)
    y, held = measure(mpc, eq), [4e4]
    for k in range(10):
        held.append(mpc.checked(0.01 * k, y, {L: eq[L] - 2e-3})[P])
        if mpc.relinearizations == 2:
            break
    # re-linearised at the first sample whose held command had left the 5 kPa band
    assert mpc.relinearizations == 2
    assert abs(held[-2] - 4e4) > 5e3 and abs(held[-3] - 4e4) <= 5e3


@pytest.mark.parametrize(("slug", "penalty"), [("lmpc", 1e4), ("nmpc", 1e6)])
def test_both_mpcs_take_one_declaration_of_bounds(slug, penalty):
    """``soft_min`` as a scene file gives it (lists: signal or pattern, bound, optional
    penalty) means the same to both MPCs, followed by the scene's ``tension_min`` on every
    thread; the NMPC (one slack per node) refuses two penalties, both an unknown signal."""
    model = hanging_load(2, load_kg=0.02)
    eq = solve_equilibrium(model, {P: 4e4})
    task = {"output": L, "input": P, "u_min": 0.0, "u_max": 1e5, "tension_min": 0.01}
    declared = [["myofibril.actin2.T", 0.15], ["myofibril.length", 0.03, penalty]]
    mpc = make_controller(slug, model, eq, 0.01, {**task, "soft_min": declared})
    threads = [f"myofibril.actin{k}.T" for k in range(3)]
    assert mpc.bounds == [
        ("myofibril.actin2.T", 0.15, penalty),
        ("myofibril.length", 0.03, penalty),
        *((n, 0.01, penalty) for n in threads),
    ]
    with pytest.raises(ParameterError, match=f"{slug}.soft_min"):
        make_controller(slug, model, eq, 0.01, {**task, "soft_min": [["nope", 1.0]]})
    with pytest.raises(ParameterError, match=f"{slug}.soft_min"):
        make_controller(slug, model, eq, 0.01, {**task, "soft_min": [["myofibril.length"]]})
    if slug == "nmpc":
        with pytest.raises(ParameterError, match="nmpc.soft_min.*one penalty"):
            make_controller(slug, model, eq, 0.01, {**task, "soft_min": [[L, 0.03, 1.0]]})
