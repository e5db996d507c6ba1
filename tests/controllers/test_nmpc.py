"""Nonlinear MPC: the steady input at a matched equilibrium (every solver), one Radau
interval against the matrix exponential, a raised minimum thread tension held in closed
loop on the exact-flow-law plant, fallbacks and bad settings."""

import casadi as cs
import numpy as np
import pytest
import scipy.linalg

from sarcomere.controllers import make_controller
from sarcomere.controllers.loop import run_closed_loop
from sarcomere.controllers.nmpc import NMPCSettings, NonlinearMPC
from sarcomere.controllers.receding import TENSIONS
from sarcomere.controllers.rti import radau_residual
from sarcomere.dynamics import Simulator, hanging_load, isometric, solve_equilibrium
from sarcomere.dynamics.errors import ParameterError
from sarcomere.scenarios.studies.mpc_nlp import ConvergedNMPC

P = "regulator.p_cmd"
L = "myofibril.length"


@pytest.fixture(scope="module")
def prediction():
    model = hanging_load(1, load_kg=0.02, flow_law="smooth", saturate=False)
    return model, solve_equilibrium(model, {P: 5e4})


@pytest.mark.parametrize("solver", ["rti", "ipopt", "fatrop"])
def test_matched_equilibrium_gives_the_steady_input(prediction, solver):
    model, eq = prediction
    if solver == "rti":
        mpc = NonlinearMPC(model, eq.u, 0.01)
    else:
        mpc = ConvergedNMPC(model, eq.u, 0.01, solver=solver)
    y = {n: eq[n] for n in mpc.outputs}
    for k in range(3):  # and stays there on the warm-started samples
        u = mpc.checked(0.01 * k, y, {L: eq[L]})
        assert u[P] == pytest.approx(5e4, abs=0.5)
    assert np.allclose(mpc._plan, 5e4, atol=0.5) and mpc.stats.fallbacks == 0
    mpc.reset(eq.u)
    assert mpc.checked(0.0, y, {L: eq[L] - 2e-4})[P] > 5e4 + 100  # shorter: more pressure


def radau_end(A, B, x0, u, h, degree):
    """The end of one Radau IIA interval of dx/dt = A x + B u (the equations are linear)."""
    nx = len(x0)
    xs, us = cs.SX.sym("x", nx), cs.SX.sym("u", B.shape[1])
    f = cs.Function("f", [xs, us], [cs.mtimes(A, xs) + cs.mtimes(B, us)])
    res = radau_residual(f, nx, B.shape[1], degree)
    V = cs.SX.sym("V", nx * degree)
    r = res(x0, V, u, h)
    J = cs.Function("J", [V], [cs.jacobian(r, V), r])
    Jv, r0 = (np.array(M) for M in J(np.zeros(nx * degree)))
    return np.linalg.solve(Jv, -r0).ravel()[-nx:]


def exact_end(A, B, x0, u, h):
    nx, nu = B.shape
    M = np.zeros((nx + nu, nx + nu))
    M[:nx, :nx], M[:nx, nx:] = A, B
    return (scipy.linalg.expm(M * h) @ np.concatenate([x0, u]))[:nx]


def test_one_radau_interval_matches_the_matrix_exponential():
    A = np.array([[-1.0, 2.0, 0.0], [-2.0, -1.0, 0.0], [0.0, 1.0, -3.0]])
    B = np.array([[0.0], [1.0], [2.0]])
    x0, u = np.array([1.0, -0.5, 0.3]), np.array([0.7])
    err = {
        h: np.max(np.abs(radau_end(A, B, x0, u, h, 3) - exact_end(A, B, x0, u, h)))
        for h in (0.1, 0.05)
    }
    assert err[0.05] < 1e-8
    assert 2**5 < err[0.1] / err[0.05] < 2**7  # local error O(h^6) (order 5)
    # a stiff mode far beyond the step (z = lambda h = -50): Radau IIA's stability function
    # R(z) = (1 + 2z/5 + z^2/20) / (1 - 3z/5 + 3z^2/20 - z^3/60), damped (|R| < 0.05)
    z = -50.0
    end = radau_end(np.array([[-5000.0]]), np.zeros((1, 1)), np.ones(1), np.zeros(1), 0.01, 3)
    R = (1 + 2 * z / 5 + z**2 / 20) / (1 - 3 * z / 5 + 3 * z**2 / 20 - z**3 / 60)
    assert end[0] == pytest.approx(R, rel=1e-10) and abs(R) < 0.05


def closed_loop_min_tension(tension_min):
    """Vent from 0.1 MPa towards the longest length on the exact-law plant; the smallest
    thread tension seen at the samples."""
    plant = hanging_load(1, load_kg=0.02)
    pred = hanging_load(1, load_kg=0.02, flow_law="smooth", saturate=False)
    eq = solve_equilibrium(plant, {P: 1e5})
    mpc = NonlinearMPC(pred, eq.u, 0.01, NMPCSettings(soft_min=((TENSIONS, tension_min),)))
    tensions = [n for n in plant.signal_names if n.startswith("myofibril.actin")]
    tensions = [n for n in tensions if n.endswith(".T")]
    sim = Simulator(plant)
    sim.reset(x0=eq.x)
    lowest = np.inf
    for _ in range(40):
        y = sim.signals([*mpc.outputs, *tensions])
        lowest = min(lowest, *(y[n] for n in tensions))
        sim.step(mpc.checked(sim.t, y, {L: mpc.clip.high}), 0.01)
    assert mpc.stats.fallbacks == 0
    return lowest, y[L]


def test_raised_minimum_tension_holds_in_closed_loop():
    free, _ = closed_loop_min_tension(0.0)
    held, length = closed_loop_min_tension(0.2)
    assert free < 0.195  # venting at full speed slackens the lower thread
    assert held >= 0.2 - 1e-4  # the constraint holds on the plant
    assert length > 57.5e-3  # and the chain still got long (0.4 s)


def test_failed_qp_falls_back_to_the_shifted_plan(prediction):
    """An unreachable hard tension bound (5 N): the law's if_else reproduces
    RecedingHorizon.apply: the previous plan shifted, else the input held; the guess is
    dropped. Softened, the same bound gives a finite command with a slack, no fallback."""
    model, eq = prediction
    good = NonlinearMPC(model, eq.u, 0.01)
    y = {n: eq[n] for n in good.outputs}
    good.checked(0.0, y, {L: eq[L] - 2e-4})
    plan, memory = good._plan.copy(), good.memory
    hard = NonlinearMPC(model, eq.u, 0.01, NMPCSettings(soft_min=((TENSIONS, 5.0, np.inf),)))
    law, x = hard.law_function(), np.array([eq[n] for n in model.state_names])
    ref, p = np.full(20, eq[L] - 2e-4), hard.parameters.values()
    mem, u, viol, fallback, _ = (np.array(v).ravel() for v in law(memory, x, plan[0], ref, list(p)))
    sl = hard.engine.slices
    assert fallback[0] == 1 and viol[0] > 1e-6
    assert u[0] == plan[1, 0]  # the previous plan, one sample on
    assert np.array_equal(mem[sl["plan"]], np.append(plan[1:, 0], plan[-1, 0]))
    assert mem[sl["has_guess"]][0] == 0 and mem[sl["has_plan"]][0] == 1
    assert hard.checked(0.0, y, {L: eq[L]})[P] == eq.u[0]  # no plan yet: hold
    assert hard.stats.fallbacks == 1
    soft = NonlinearMPC(model, eq.u, 0.01, NMPCSettings(soft_min=((TENSIONS, 5.0),)))
    u = soft.checked(0.0, y, {L: eq[L]})[P]
    assert np.isfinite(u) and soft.stats.fallbacks == 0 and soft.slack > 1.0


def test_the_law_function_called_by_hand_gives_the_controllers_commands():
    """The Python controller runs exactly the one CasADi law: replayed from zero memory
    with the same measurements, it gives the same commands to 1e-12 (relative). (No
    integral action here: the reference shift is the controller's, outside the law.)"""
    plant = hanging_load(1, load_kg=0.02)
    pred = hanging_load(1, load_kg=0.02, flow_law="smooth", saturate=False)
    eq = solve_equilibrium(plant, {P: 5e4})
    s = NMPCSettings(soft_min=((TENSIONS, 0.19),), integral_gain=0.0)
    mpc = NonlinearMPC(pred, eq.u, 0.01, s)
    sim = Simulator(plant)
    sim.reset(x0=eq.x)
    calls, commands = [], []
    for k in range(30):
        y = sim.signals(mpc.outputs)
        r = eq[L] + (1.2e-3 if k >= 3 else 0.0)
        x, u_prev = np.array([y[n] for n in pred.state_names]), mpc._u.copy()
        commands.append(mpc.checked(sim.t, y, {L: r})[P])
        calls.append((x, u_prev, np.full(20, min(r, mpc.clip.high)), mpc._p.copy()))
        sim.step({P: commands[-1]}, 0.01)
    assert len(set(commands)) > 10  # it moved
    law, memory, replay = mpc.law_function(), np.zeros(mpc.engine.n_memory), []
    for x, u_prev, ref, p in calls:
        memory, u, *_ = (np.array(v).ravel() for v in law(memory, x, u_prev, ref, p))
        replay.append(u[0])
    assert np.allclose(replay, commands, rtol=1e-12, atol=0)
    assert law.name_in() == ["memory", "x", "u_prev", "ref", "p"]


@pytest.mark.parametrize(
    ("kwargs", "name"),
    [
        ({"weight_y": -1.0}, "nmpc.weight_y"),
        ({"horizon": 0}, "nmpc.horizon"),
        ({"soft_min": (("x", 1.0, 0.0),)}, "nmpc.soft_min"),
        ({"soft_min": "x"}, "nmpc.soft_min"),
        ({"backoff": -1.0}, "nmpc.backoff"),
        ({"degree": 0}, "nmpc.degree"),
    ],
)
def test_bad_settings_name_the_setting(kwargs, name):
    with pytest.raises(ParameterError, match=name):
        NMPCSettings(**kwargs)


def test_too_short_sample_time_is_refused(prediction):
    model, eq = prediction
    with pytest.raises(ParameterError, match="nmpc.dt"):
        NonlinearMPC(model, eq.u, 1e-3)


TASK = {"output": L, "input": P, "u_min": 0.0, "u_max": 1e5}


def test_registry_factory_predicts_with_the_plants_parameters():
    plant = hanging_load(2, load_kg=0.05)
    eq = solve_equilibrium(plant, {P: 5e4})
    mpc = make_controller("nmpc", plant, eq, 0.01, {**TASK, "fidelity": "quasi_static"})
    pred = mpc.model
    assert pred.name == "hanging_n2_quasi_static"
    assert mpc.clip.ends[0].p[pred.param_names.index("load.m")] == pytest.approx(0.051)
    y = {n: eq[n] for n in mpc.outputs}  # the plant's equilibrium is the prediction's too
    assert mpc.checked(0.0, y, {L: eq[L]})[P] == pytest.approx(5e4, abs=1.0)
    with pytest.raises(ParameterError, match="nmpc.horizn"):
        make_controller("nmpc", plant, eq, 0.01, {**TASK, "horizn": 10})
    bare = hanging_load(1, load_kg=0.02)
    bare.setup = None  # as a System flattened by hand: no set-up to rebuild
    with pytest.raises(ParameterError, match="nmpc.model.*set-up"):
        make_controller("nmpc", bare, solve_equilibrium(bare, {P: 5e4}), 0.01, TASK)


def test_registry_factory_rebuilds_the_set_up_the_plant_records():
    """A sprung fixture (which the former guess from state names refused) is predicted by
    its own set-up: the same spring, at the prediction's fidelity and flow law."""
    plant = isometric(1, fixture_stiffness=500.0, regulator_tau=0.06)
    assert plant.setup.arguments["fixture_stiffness"] == 500.0
    eq = solve_equilibrium(plant, {P: 5e4})
    task = {**TASK, "output": "sensor.f", "fidelity": "quasi_static"}
    mpc = make_controller("nmpc", plant, eq, 0.01, task)
    pred = mpc.model
    assert pred.name == "isometric_n1_quasi_static"
    p = dict(zip(pred.param_names, pred.parameters(), strict=True))
    assert p["fixture_spring.c"] == 500.0 and p["regulator.tau"] == 0.06
    y = {n: eq[n] for n in mpc.outputs}  # the plant's equilibrium is the prediction's too
    assert mpc.checked(0.0, y, {"sensor.f": eq["sensor.f"]})[P] == pytest.approx(5e4, abs=5.0)


def test_registry_factory_on_the_rigid_isometric_fixture():
    plant = isometric(1)
    eq = solve_equilibrium(plant, {P: 5e4})
    task = {**TASK, "output": "sensor.f"}
    mpc = make_controller("nmpc", plant, eq, 0.01, task)
    assert mpc.model.name == "isometric_n1_full"
    y = {n: eq[n] for n in mpc.outputs}
    assert mpc.checked(0.0, y, {"sensor.f": eq["sensor.f"]})[P] == pytest.approx(5e4, abs=5.0)
    mpc.reset({P: 5e4})
    assert mpc.checked(0.0, y, {"sensor.f": eq["sensor.f"] + 0.01})[P] > 5e4 + 100


def test_on_an_ekf_it_reads_only_the_measured_signals():
    plant = hanging_load(1, load_kg=0.02)
    eq = solve_equilibrium(plant, {P: 5e4})
    mpc = make_controller("nmpc", plant, eq, 0.01, {**TASK, "estimator": "ekf"})
    assert mpc.outputs == [L, "regulator.p_out"]
    sim = Simulator(plant)
    sim.reset(x0=eq.x)
    for _ in range(30):
        y = sim.signals(mpc.outputs)
        sim.step(mpc.checked(sim.t, y, {L: eq[L] - 2e-4}), 0.01)
    assert sim.signal(L) == pytest.approx(eq[L] - 2e-4, abs=3e-5)


def steady_error(integral_gain):
    """Hold a length on a plant 10 g heavier than the prediction: the error after 1 s."""
    plant = hanging_load(1, load_kg=0.03)
    pred = hanging_load(1, load_kg=0.02, flow_law="smooth", saturate=False)
    eq = solve_equilibrium(plant, {P: 5e4})
    mpc = NonlinearMPC(pred, eq.u, 0.01, NMPCSettings(integral_gain=integral_gain))
    sim = Simulator(plant)
    sim.reset(x0=eq.x)
    for _ in range(100):
        y = sim.signals(mpc.outputs)
        sim.step(mpc.checked(sim.t, y, {L: eq[L]}), 0.01)
    return abs(sim.signal(L) - eq[L])


def test_integral_action_removes_the_offset_of_an_unknown_load():
    assert steady_error(0.0) > 3e-4  # 0.6 mm: the prediction's 20 g equilibrium is elsewhere
    assert steady_error(5.0) < 0.05 * steady_error(0.0)


def test_a_scenes_build_model_makes_the_prediction():
    plant = hanging_load(1, load_kg=0.02)
    eq = solve_equilibrium(plant, {P: 5e4})
    calls = []

    def build_model(**kwargs):
        calls.append(kwargs)
        return hanging_load(1, load_kg=0.02, **kwargs)

    task = {**TASK, "build_model": build_model, "fidelity": "symmetric"}
    mpc = make_controller("nmpc", plant, eq, 0.01, task)
    assert calls == [{"fidelity": "symmetric", "flow_law": "smooth", "saturate": False}]
    assert mpc.model.name == "hanging_n1_symmetric"


def test_the_rti_gets_one_reference_per_node(prediction, monkeypatch):
    model, eq = prediction
    mpc = NonlinearMPC(model, eq.u, 0.01, NMPCSettings(horizon=5, integral_gain=0.0))
    y = {n: eq[n] for n in mpc.outputs}
    seen, step = [], mpc.engine.calls["feedback"]  # every output
    monkeypatch.setitem(
        mpc.engine.calls, "feedback", lambda *a: seen.append(np.array(a[4])) or step(*a)
    )
    ahead = eq[L] - np.array([0.0, 0.0, 1e-4, 2e-4, 3e-4])
    mpc.set_preview({L: ahead})
    mpc.checked(0.0, y, {L: eq[L]})
    mpc.checked(0.01, y, {L: eq[L]})  # the preview is for one sample only
    assert np.allclose(seen[0], ahead) and np.allclose(seen[1], eq[L])
    with pytest.raises(ParameterError, match="nmpc.preview"):
        mpc.set_preview({L: ahead[:4]})


def preview_error(reference, stop, preview, since=0.0):
    """RMS tracking error [m] of the RTI NMPC on the exact-law plant (no integral action)
    from ``since``, and the command [Pa] at every sample."""
    plant = hanging_load(1, load_kg=0.02)
    pred = hanging_load(1, load_kg=0.02, flow_law="smooth", saturate=False)
    eq = solve_equilibrium(plant, {P: 5e4})
    mpc = NonlinearMPC(pred, eq.u, 0.01, NMPCSettings(integral_gain=0.0))
    ref = lambda t: eq[L] + reference(t)  # noqa: E731
    run = run_closed_loop(plant, mpc, eq, ref, stop, output=L, preview=preview)
    keep = run.result.index >= since
    err = (run.result[L] - run.result["reference"])[keep]
    assert mpc.stats.fallbacks == 0
    return float(np.sqrt(np.mean(err**2))), run.result[P]


def test_preview_tracks_a_sine_better():
    sine = lambda t: 0.5e-3 * np.sin(2 * np.pi * 3.0 * t)  # noqa: E731
    blind, _ = preview_error(sine, 1.0, False, since=0.3)
    ahead, _ = preview_error(sine, 1.0, True, since=0.3)
    assert blind > 0.3e-3  # 0.38 mm: r(t) held over the horizon lags the sine
    assert ahead < 0.05e-3  # 0.023 mm with the sine known over the horizon


def test_preview_moves_before_a_known_step():
    step = lambda t: -1e-3 if t >= 0.3 else 0.0  # noqa: E731
    blind, u_blind = preview_error(step, 0.6, False)
    ahead, u_ahead = preview_error(step, 0.6, True)
    assert np.allclose(u_blind[:30], 5e4, atol=1.0)  # waits for the step
    assert u_ahead[25] > 6e4  # 80 kPa at 0.25 s: pressurises ahead of it
    assert ahead < 0.5 * blind  # 0.11 mm against 0.30 mm RMS


def test_on_an_ekf_the_bounds_are_raised_by_the_estimates_standard_deviation():
    """``make_nmpc`` on an EKF: ``backoff`` 1 (``EKF_BACKOFF``), and every sample the EKF
    feeds each bounded tension's standard deviation, ``sqrt(J P J^T)`` (here with ``J``
    by central differences over the EKF's states and its load), which the prediction
    subtracts from the tension (the bound raised by it); without an EKF no back-off."""
    plant = hanging_load(1, load_kg=0.02)
    eq = solve_equilibrium(plant, {P: 5e4})
    task = {**TASK, "estimator": "ekf", "noise_std": {L: 2e-5, "regulator.p_out": 200.0}}
    ctl = make_controller("nmpc", plant, eq, 0.01, task)
    mpc, ekf = ctl.inner, ctl.ekf
    threads = ["myofibril.actin0.T", "myofibril.actin1.T"]
    assert mpc.settings.backoff == 1.0 and mpc.uncertain_signals == threads
    y = {n: eq[n] for n in ctl.outputs}
    for k in range(3):
        ctl.checked(0.01 * k, {**y, L: eq[L] + 1e-4 * k}, {L: eq[L] - 1e-3})
    sig = plant.signals_function(threads)
    nx, k_m = plant.nx, plant.param_names.index("load.m")

    def tensions(xa):  # at the estimated state and load
        p = eq.p.copy()
        p[k_m] = xa[nx]
        return np.array(sig(xa[:nx], np.zeros(0), ctl._u, p)).ravel()

    xa = ekf.xa.copy()
    J = np.zeros((2, len(xa)))
    for j in range(len(xa)):
        h = 1e-7 * max(abs(xa[j]), 1e-6)
        up, down = xa.copy(), xa.copy()
        up[j] += h
        down[j] -= h
        J[:, j] = (tensions(up) - tensions(down)) / (2 * h)
    std = np.sqrt(np.diag(J @ ekf.P @ J.T))
    fed = [mpc.parameters[f"backoff.{n}"] for n in threads]
    assert np.all(std > 0) and fed == pytest.approx(std, rel=1e-4)
    pb, xi = mpc.problem, xa[:nx] / mpc.problem.xs  # the same states
    bare = mpc._p.copy()
    bare[-2:] = 0.0  # the two back-offs, last
    raised = np.array(pb.T(xi, mpc._p)).ravel()
    assert raised == pytest.approx(np.array(pb.T(xi, bare)).ravel() - np.array(fed), rel=1e-12)
    plain = make_controller("nmpc", plant, eq, 0.01, TASK)
    assert plain.settings.backoff == 0.0 and plain.uncertain_signals == []
    assert not any(n.startswith("backoff.") for n in plain.runtime_parameters)


def test_an_nmpc_without_bounds_on_signals_moves_as_with_inactive_ones(prediction):
    """``soft_min = ()`` (no bound rows in the QP at all) gives the command of the default
    thread-tension bounds at 0 N, which are far from active here."""
    model, eq = prediction
    y = {n: eq[n] for n in NonlinearMPC(model, eq.u, 0.01).outputs}
    u = [
        NonlinearMPC(model, eq.u, 0.01, NMPCSettings(soft_min=s)).checked(0.0, y, {L: eq[L] - 1e-4})
        for s in ((), NMPCSettings().soft_min)
    ]
    assert u[0][P] > 5e4 + 100 and u[0][P] == pytest.approx(u[1][P], rel=1e-9)
