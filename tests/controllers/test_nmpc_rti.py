"""The NMPC's soft tension bounds (exact penalty: the hard solution whenever it exists),
its terminal weight, and the compiled real-time iteration (generated C equal to the
CasADi Functions it comes from)."""

import numpy as np
import pytest

from sarcomere.controllers.nmpc import NMPCSettings, NonlinearMPC
from sarcomere.dynamics import Simulator, hanging_load, solve_equilibrium
from sarcomere.dynamics.errors import ParameterError

P = "regulator.p_cmd"
L = "myofibril.length"


def venting(settings: NMPCSettings, samples: int) -> tuple[list[float], NonlinearMPC]:
    """Vent from 0.1 MPa towards the longest length with every thread >= 0.2 N (the
    bound is active: the lowest thread carries 0.206 N at rest) on the exact-law plant."""
    plant = hanging_load(1, load_kg=0.02)
    pred = hanging_load(1, load_kg=0.02, flow_law="smooth", saturate=False)
    eq = solve_equilibrium(plant, {P: 1e5})
    mpc = NonlinearMPC(pred, eq.u, 0.01, settings)
    sim = Simulator(plant)
    sim.reset(x0=eq.x)
    commands = []
    for _ in range(samples):
        y = sim.signals(mpc.outputs)
        commands.append(mpc.checked(sim.t, y, {L: mpc.clip.high})[P])
        sim.step({P: commands[-1]}, 0.01)
    return commands, mpc


@pytest.mark.parametrize(("solver", "samples", "rtol"), [("rti", 15, 1e-9), ("ipopt", 3, 1e-5)])
def test_soft_bounds_give_the_hard_solution_when_it_is_feasible(solver, samples, rtol):
    """The L1 weight (1e6 1/N) is above the bounds' multipliers, so the exact penalty
    puts no slack where the hard problem is feasible: the same commands, slack 0."""
    common = {"solver": solver, "tension_min": 0.2, "integral_gain": 0.0}
    hard, h = venting(NMPCSettings(soft_constraints=False, **common), samples)
    soft, s = venting(NMPCSettings(**common), samples)
    assert h.stats.fallbacks == s.stats.fallbacks == 0
    assert np.ptp(hard) > 5e3  # the bound shaped a real manoeuvre
    assert np.allclose(soft, hard, rtol=rtol, atol=1e-5)  # atol: 1e-10 of the range
    if solver == "rti":
        assert s.slack == 0.0


def test_an_infeasible_bound_softened_gives_a_finite_command_without_fallback():
    """5 N on every thread cannot be met: the hard RTI and NLP fall back (hold); soft,
    both move and report the slack."""
    for solver in ("rti", "ipopt"):
        hard, h = venting(NMPCSettings(solver=solver, tension_min=5.0, soft_constraints=False), 2)
        soft, s = venting(NMPCSettings(solver=solver, tension_min=5.0), 2)
        assert h.stats.fallbacks == 2 and hard == [1e5, 1e5]
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
        ({"compiled": True, "solver": "ipopt"}, "nmpc.compiled"),
        ({"linear_solver": "lu"}, "nmpc.linear_solver"),
        ({"tension_l1": 0.0}, "nmpc.tension_l1"),
        ({"terminal_weight": -1.0}, "nmpc.terminal_weight"),
        ({"soft_constraints": 1}, "nmpc.soft_constraints"),
    ],
)
def test_bad_new_settings_name_the_setting(kwargs, name):
    with pytest.raises(ParameterError, match=name):
        NMPCSettings(**kwargs)


@pytest.fixture(scope="module")
def compiled_pair():
    """One compiled build per session (cached on disk) and its CasADi twin (both with
    LAPACK's LU for the lifted solves, which the compiled RTI calls too)."""
    model = hanging_load(1, load_kg=0.02, flow_law="smooth", saturate=False)
    eq = solve_equilibrium(model, {P: 5e4})
    s = NMPCSettings(horizon=10, tension_min=0.19, integral_gain=0.0)  # 10: a shorter build
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
    assert "external" in compiled.engine.calls["feedback"].function.class_name().lower()


@pytest.mark.slow
def test_the_law_with_the_qr_solver_generates_self_contained_c(tmp_path):
    """With ``linear_solver = "qr"`` the whole law generates C (LAPACK has none) and
    compiles; it calls DAQP, linked statically from the casadi wheel."""
    import casadi as cs

    from sarcomere.controllers.rti_compiled import compiled_functions

    model = hanging_load(1, load_kg=0.02, flow_law="smooth", saturate=False)
    eq = solve_equilibrium(model, {P: 5e4})
    s = NMPCSettings(horizon=5, linear_solver="qr", integral_gain=0.0)  # 5: a shorter build
    mpc = NonlinearMPC(model, eq.u, 0.01, s)
    law = compiled_functions([mpc.law_function()], "nmpc_law_test")["nmpc_law"]
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
