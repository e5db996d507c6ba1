"""The NMPC's soft tension bounds (exact penalty: the hard solution whenever it exists),
its terminal weight, and the compiled real-time iteration (generated C equal to the
CasADi Functions it comes from)."""

import numpy as np
import pytest

from sarcomere.controllers.nmpc import NMPCSettings, NonlinearMPC
from sarcomere.controllers.receding import TENSIONS
from sarcomere.dynamics import Simulator, hanging_load, solve_equilibrium
from sarcomere.dynamics.errors import ParameterError
from sarcomere.scenarios.studies.mpc_nlp import ConvergedNMPC

P = "regulator.p_cmd"
L = "myofibril.length"


def venting(
    settings: NMPCSettings, samples: int, solver: str = "rti"
) -> tuple[list[float], NonlinearMPC]:
    """Vent from 0.1 MPa towards the longest length with every thread >= 0.2 N (the
    bound is active: the lowest thread carries 0.206 N at rest) on the exact-law plant."""
    plant = hanging_load(1, load_kg=0.02)
    pred = hanging_load(1, load_kg=0.02, flow_law="smooth", saturate=False)
    eq = solve_equilibrium(plant, {P: 1e5})
    if solver == "rti":
        mpc = NonlinearMPC(pred, eq.u, 0.01, settings)
    else:
        mpc = ConvergedNMPC(pred, eq.u, 0.01, settings, solver=solver)
    sim = Simulator(plant)
    sim.reset(x0=eq.x)
    commands = []
    for _ in range(samples):
        y = sim.signals(mpc.outputs)
        commands.append(mpc.checked(sim.t, y, {L: mpc.clip.high})[P])
        sim.step({P: commands[-1]}, 0.01)
    return commands, mpc


@pytest.mark.parametrize(("solver", "samples", "rtol"), [("rti", 15, 1e-9), ("ipopt", 3, 1e-5)])
@pytest.mark.slow  # over 0.8 s: the fast loop leaves it to the full suite
def test_soft_bounds_give_the_hard_solution_when_it_is_feasible(solver, samples, rtol):
    """The L1 weight (1e6 1/N) is above the bounds' multipliers, so the exact penalty
    puts no slack where the hard problem is feasible: the same commands, slack 0."""
    hard, h = venting(NMPCSettings(soft_min=((TENSIONS, 0.2, np.inf),), integral_gain=0.0),
                      samples, solver)  # fmt: skip
    soft, s = venting(NMPCSettings(soft_min=((TENSIONS, 0.2),), integral_gain=0.0), samples, solver)
    assert h.stats.fallbacks == s.stats.fallbacks == 0
    assert np.ptp(hard) > 5e3  # the bound shaped a real manoeuvre
    assert np.allclose(soft, hard, rtol=rtol, atol=1e-5)  # atol: 1e-10 of the range
    if solver == "rti":
        assert s.slack == 0.0


@pytest.mark.slow  # over 0.8 s: the fast loop leaves it to the full suite
def test_an_infeasible_bound_softened_gives_a_finite_command_without_fallback():
    """5 N on every thread cannot be met: the hard RTI and NLP fall back (hold); soft,
    both move and report the slack."""
    for solver in ("rti", "ipopt"):
        hard, h = venting(NMPCSettings(soft_min=((TENSIONS, 5.0, np.inf),)), 2, solver)
        soft, s = venting(NMPCSettings(soft_min=((TENSIONS, 5.0),)), 2, solver)
        assert h.stats.fallbacks == 2 and hard == [1e5, 1e5]
        assert h.stats.fallback_fraction == 1.0 and s.stats.fallback_fraction == 0.0
        assert s.stats.fallbacks == 0 and np.all(np.isfinite(soft))
        assert s.slack > 4.0  # N: the plan's largest predicted shortfall of the 5 N


def terminal_error(weight: float) -> float:
    """The RTI's predicted output error at the horizon's end [m] after one sample of a
    0.2 mm step, horizon 5 (0.05 s, shorter than the chain's settling)."""
    model = hanging_load(1, load_kg=0.02, flow_law="smooth", saturate=False)
    eq = solve_equilibrium(model, {P: 5e4})
    s = NMPCSettings(horizon=5, terminal_weight=weight, integral_gain=0.0)
    mpc = NonlinearMPC(model, eq.u, 0.01, s)
    r = eq[L] + 2e-4
    mpc.checked(0.0, {n: eq[n] for n in mpc.outputs}, {L: r})
    eng = mpc.engine
    X = eng.memory[eng.slices["Xb"]].reshape(-1, model.nx)  # shifted: row N-1 = node N
    return abs(float(eng.pb.y(X[-2], mpc._p)) - r)


def test_the_terminal_weight_pulls_the_last_node_to_the_reference():
    free = terminal_error(0.0)
    assert free > 1e-4  # 5 samples are too few to get there on the stage costs alone
    assert terminal_error(1e9) < 0.02 * free


@pytest.mark.parametrize(
    ("kwargs", "name"),
    [
        ({"compiled": 1}, "nmpc.compiled"),
        ({"linear_solver": "lapackqr"}, "nmpc.linear_solver"),
        ({"soft_penalty": 0.0}, "nmpc.soft_penalty"),
        ({"terminal_weight": -1.0}, "nmpc.terminal_weight"),
        ({"qp_solver": "hpipm"}, "nmpc.qp_solver"),
    ],
)
def test_bad_new_settings_name_the_setting(kwargs, name):
    with pytest.raises(ParameterError, match=name):
        NMPCSettings(**kwargs)


@pytest.fixture(scope="module")
def compiled_pair():
    """One compiled build per session (cached on disk; "auto": the kept sparse LU) and its
    CasADi twin ("auto": LAPACK's LU of every sensitivity): two lifts, one law."""
    model = hanging_load(1, load_kg=0.02, flow_law="smooth", saturate=False)
    eq = solve_equilibrium(model, {P: 5e4})
    # horizon 10: a shorter build
    s = NMPCSettings(horizon=10, soft_min=((TENSIONS, 0.19),), integral_gain=0.0)
    c = NonlinearMPC(model, eq.u, 0.01, NMPCSettings(**{**s.__dict__, "compiled": True}))
    py = NonlinearMPC(model, eq.u, 0.01, s)
    return c, py


@pytest.mark.slow
def test_the_compiled_rti_gives_the_casadi_functions_commands(compiled_pair):
    compiled, python = compiled_pair
    plant = hanging_load(1, load_kg=0.02)
    eq = solve_equilibrium(plant, {P: 5e4})
    sim = Simulator(plant)
    sim.reset(x0=eq.x)
    for k in range(25):
        y = sim.signals(compiled.outputs)
        r = {L: eq[L] + (1e-3 if k >= 2 else 0.0)}
        a, b = compiled.checked(sim.t, y, r)[P], python.checked(sim.t, y, r)[P]
        assert a == pytest.approx(b, rel=1e-9, abs=1e-6)
        sim.step({P: a}, 0.01)
    assert compiled.stats.fallbacks == 0
    assert "external" in compiled.engine.calls["update"].function.class_name().lower()


@pytest.mark.slow
@pytest.mark.parametrize("linear_solver", ["qr", "sparse_lu"])
def test_the_law_with_a_generated_solver_generates_self_contained_c(linear_solver):
    """With ``linear_solver = "qr"`` or ``"sparse_lu"`` the whole law generates C (LAPACK
    has none) and compiles; it calls DAQP, linked statically from the casadi wheel."""
    import casadi as cs

    from sarcomere.controllers.rti_compiled import compiled_functions

    model = hanging_load(1, load_kg=0.02, flow_law="smooth", saturate=False)
    eq = solve_equilibrium(model, {P: 5e4})
    s = NMPCSettings(horizon=5, linear_solver=linear_solver, integral_gain=0.0)  # 5: short
    mpc = NonlinearMPC(model, eq.u, 0.01, s)
    law = compiled_functions([mpc.law_function()], f"nmpc_law_{linear_solver}")["nmpc_law"]
    y = {n: eq[n] for n in mpc.outputs}
    x = np.array([eq[n] for n in model.state_names])
    memory = np.zeros(mpc.engine.n_memory)
    for k in range(3):
        ref = np.full(5, eq[L] - 2e-4)
        u_prev = mpc._u.copy()
        expected = mpc.checked(0.01 * k, y, {L: eq[L] - 2e-4})[P]
        memory, u, *_ = (np.array(v).ravel() for v in law(memory, x, u_prev, ref, mpc._p))
        assert u[0] == pytest.approx(expected, rel=1e-12)
    assert isinstance(law, cs.Function)


def test_the_sparse_lu_solves_like_a_dense_lu():
    """The SX sparse LU (no pivoting, block minimum-degree order), factorised once and
    solved per column, against numpy's dense LU with pivoting: on a random sparse system
    with a dominant diagonal, and on the Radau collocation Jacobian of the 3-APS model
    (54 x 54, degree 3) at a perturbed state, where the lifted sensitivities' entries span
    1e-6 to 1e3 (the dense lift's LAPACK solve as the reference)."""
    import casadi as cs

    from sarcomere.dynamics.simulation import sparse_lu

    rng = np.random.default_rng(3)
    A = np.where(rng.random((12, 12)) < 0.3, rng.normal(size=(12, 12)), 0.0) + 5 * np.eye(12)
    B = rng.normal(size=(12, 4))
    Asx = cs.SX.sym("A", cs.DM(A).sparsity())
    order = sparse_lu.block_order(A != 0, 4, 3)
    assert sorted(order) == list(range(12))
    lu = sparse_lu.Factors(Asx, order)
    values = cs.Function("v", [Asx], [lu.values])(cs.DM(A))
    got = np.array(lu.solve_function().map(4)(values, B))
    assert np.allclose(got, np.linalg.solve(A, B), rtol=1e-12, atol=1e-12)

    model = hanging_load(3, load_kg=0.02, flow_law="smooth", saturate=False)
    eq = solve_equilibrium(model, {P: 5e4})
    eng = NonlinearMPC(model, eq.u, 0.01, NMPCSettings(linear_solver="lapacklu")).engine
    xs = np.asarray(eq.x) / eng.pb.xs
    xi = xs * (1 + 0.01 * rng.normal(size=xs.size))
    V, u, p = np.tile(xs, 3), np.array([0.7]), np.asarray(NonlinearMPC(model, eq.u, 0.01)._p)
    RV, RB = (np.array(cs.DM(m)) for m in eng.lift.lin.call([V, xi, u, p])[:2])
    expected = -np.linalg.solve(RV[:, :54], RB[:, : RB.shape[1] // eng.N])
    lift = NonlinearMPC(model, eq.u, 0.01, NMPCSettings(linear_solver="sparse_lu")).engine.lift
    F, R, RX, RU = (np.array(cs.DM(m))[:, 0] for m in lift.lin.call([V, xi, u, p]))
    rhs = np.hstack([R[:, None], cs.DM(lift.spx, RX).full(), cs.DM(lift.spu, RU).full()])
    got = -np.array(lift.solve.map(rhs.shape[1])(F, rhs))
    assert np.allclose(got, expected, rtol=1e-9, atol=1e-9 * np.abs(expected).max())


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"max_iter": 10**9}, r"'nmpc\.max_iter' = 1000000000.*integer in \[1, 1000\]"),
        ({"max_iter": 0}, r"'nmpc\.max_iter' = 0.*integer in \[1, 1000\]"),
        ({"solver": "rti"}, "nmpc.solver"),
        ({"tol": 0.0}, "nmpc.tol"),
    ],
)
def test_the_converged_nmpcs_settings_are_checked(kwargs, match):
    model = hanging_load(1, load_kg=0.02, flow_law="smooth", saturate=False)
    eq = solve_equilibrium(model, {P: 5e4})
    with pytest.raises(ParameterError, match=match):
        ConvergedNMPC(model, eq.u, 0.01, **kwargs)


@pytest.mark.slow
@pytest.mark.parametrize("n", [3, 10])
def test_the_factored_lift_gives_the_dense_lifts_law(n):
    """The law with the kept sparse factors (``linear_solver = "sparse_lu"``: the moves'
    directions carried forward, one solve per interval in the feedback and the update)
    against the law with LAPACK's solves of every sensitivity (``"lapacklu"``, the law
    before): the same inputs (fixed seed: states around random equilibria, random
    references, the dense law's memory fed to both) give commands within 1e-6 of the
    input range and the same next guess."""
    model = hanging_load(n, load_kg=0.02, flow_law="smooth", saturate=False)
    rng = np.random.default_rng(27)
    s = NMPCSettings(soft_min=((TENSIONS, 0.19),), integral_gain=0.0)
    eq = solve_equilibrium(model, {P: 5e4})
    dense = NonlinearMPC(
        model, eq.u, 0.01, NMPCSettings(**{**s.__dict__, "linear_solver": "lapacklu"})
    )
    factored = NonlinearMPC(
        model, eq.u, 0.01, NMPCSettings(**{**s.__dict__, "linear_solver": "sparse_lu"})
    )
    old, new = dense.law_function(), factored.law_function()
    memory, u_prev, p = np.zeros(dense.engine.n_memory), eq.u.copy(), dense._p
    xs, span = dense.problem.xs, dense.clip.high - dense.clip.low
    for _ in range(8):
        at = solve_equilibrium(model, {P: rng.uniform(2e4, 8e4)})
        x = np.asarray(at.x) + 2e-3 * xs * rng.normal(size=model.nx)
        ref = dense.clip.low + span * rng.uniform(0.2, 0.8) + np.zeros(s.horizon)
        a = [np.array(v).ravel() for v in old(memory, x, u_prev, ref, p)]
        b = [np.array(v).ravel() for v in new(memory, x, u_prev, ref, p)]
        assert a[3][0] == b[3][0] == 0  # no fallback in either
        assert b[1][0] == pytest.approx(a[1][0], abs=1e-6 * (s.u_max - s.u_min))
        assert np.allclose(b[0], a[0], rtol=1e-6, atol=1e-8)
        memory, u_prev = a[0], a[1]
