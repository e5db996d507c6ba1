"""The antagonistic joint and the bundle: energy balance, symmetry, stiffness, refusals."""

from fnmatch import fnmatch

import casadi as cs
import numpy as np
import pytest

from sarcomere.dynamics.equilibrium import solve_equilibrium
from sarcomere.dynamics.errors import ParameterError
from sarcomere.dynamics.robots import antagonistic_joint, bundle

FLEX, EXT = "flexor_regulator.p_cmd", "extensor_regulator.p_cmd"
SEALED = "*.tube*.C"


def _balance(m, u: dict, over: dict, x0, t_final: float) -> tuple[float, float, np.ndarray]:
    """Stored energy change plus the dissipated energy [J] from ``x0`` over ``t_final``
    [s] (CVODES at rtol 1e-13, the dissipation as a quadrature), and the final state."""
    p = m.parameters(over)
    uu = np.array([u.get(k, 0.0) for k in m.input_names])
    z = cs.DM(0, 1)
    E, D = m.function("energy")(m.x, z, uu, p)[:2]
    dae = {"x": m.x, "ode": m.function("ode")(m.x, z, uu, p), "quad": D}
    opts = {"abstol": 1e-14, "reltol": 1e-13}
    r = cs.integrator("balance", "cvodes", dae, 0.0, t_final, opts)(x0=x0)
    energy = m.function("energy")
    dE = float(energy(r["xf"], z, uu, p)[0]) - float(energy(x0, z, uu, p)[0])
    return dE, float(r["qf"]), np.array(r["xf"]).ravel()


def _sealed(m) -> dict:
    return {n: 0.0 for n in m.param_names if fnmatch(n, SEALED)}


def test_joint_energy_balance_closes_to_1e_9_of_the_work_of_a_load_torque_step():
    m = antagonistic_joint(2, m_arm=0.02)  # the gravity arm too
    u = {FLEX: 0.1e6, EXT: 0.05e6}
    eq = solve_equilibrium(m, u)
    tau = 3e-3
    dE, dissipated, xf = _balance(m, u, {**_sealed(m), "joint.tau_load": tau}, eq.x, 0.5)
    # the load torque's potential -tau theta is part of E: what the load did is its drop
    work = tau * (xf[m.state_names.index("joint.theta")] - eq["joint.theta"])
    assert work > 1e-4 and dissipated > 0.3 * work
    assert abs(dE + dissipated) < 1e-9 * work


@pytest.mark.parametrize("setup", ["hanging", "isometric"])
def test_bundle_energy_balance_closes_to_1e_9_of_the_kick(setup):
    m = bundle(2, 2, setup=setup, load_kg=0.02 if setup == "hanging" else 0.0)
    u = {"regulator1.p_cmd": 0.1e6, "regulator2.p_cmd": 0.03e6}
    eq = solve_equilibrium(m, u)
    x0 = eq.x.copy()
    kicked = "load.v" if setup == "hanging" else "fibre1.aps1.body.v"
    x0[m.state_names.index(kicked)] = 0.05
    work = 0.5 * m.variables[kicked.replace(".v", ".m")].value * 0.05**2
    dE, dissipated, _ = _balance(m, u, _sealed(m), x0, 0.3)
    assert dissipated > 0.5 * work
    assert abs(dE + dissipated) < 1e-9 * work  # E(0) holds the kick


LEVELS = ["full", "quasi_static", "static_chain", "symmetric", "instant_pneumatics"]


@pytest.mark.parametrize("fidelity", LEVELS)
def test_symmetric_pair_at_rest_gives_zero_torque_and_the_stiffness_of_small_load_steps(
    fidelity,
):
    m = antagonistic_joint(3, fidelity=fidelity)
    u = {FLEX: 0.1e6, EXT: 0.1e6}
    eq = solve_equilibrium(m, u)
    assert abs(eq["joint.tau"]) < 1e-12
    assert abs(eq["joint.theta"]) < 1e-12
    assert eq["flexor_tendon.T"] == pytest.approx(eq["extensor_tendon.T"], abs=1e-12)
    # independent: equilibria under load torques +-d (central difference, O(d^2))
    d = 1e-5
    th = [
        solve_equilibrium(m, u, {"joint.tau_load": s * d}, guess=eq)["joint.theta"] for s in (-1, 1)
    ]
    assert eq["stiffness.K"] == pytest.approx(2 * d / (th[1] - th[0]), rel=1e-5)


def test_random_pairs_stiffness_signal_matches_load_steps_and_torque_balances():
    rng = np.random.default_rng(26)
    for _ in range(3):
        nf, ne = (int(v) for v in rng.integers(1, 4, 2))
        r = float(rng.uniform(5e-3, 15e-3))
        m = antagonistic_joint(nf, ne, fidelity="symmetric", r=r, m_arm=0.01)
        u = {FLEX: float(rng.uniform(0.02e6, 0.2e6)), EXT: float(rng.uniform(0.02e6, 0.2e6))}
        eq = solve_equilibrium(m, u)
        # statics: the tendons' torque holds the gravity arm (10 g at 0.1 m)
        arm = 0.01 * m.variables["ambient.g"].value * 0.1 * np.sin(eq["joint.theta"])
        assert eq["joint.tau"] == pytest.approx(arm, abs=1e-10)  # Newton's tolerance
        assert eq["joint.tau"] == pytest.approx(
            r * (eq["flexor_tendon.T"] - eq["extensor_tendon.T"]), abs=1e-12
        )
        d = 1e-6
        th = [
            solve_equilibrium(m, u, {"joint.tau_load": s * d}, guess=eq)["joint.theta"]
            for s in (-1, 1)
        ]
        assert eq["stiffness.K"] == pytest.approx(2 * d / (th[1] - th[0]), rel=1e-5)


def test_co_contraction_raises_the_stiffness_at_the_same_angle():
    m = antagonistic_joint(2, fidelity="symmetric")
    K = [solve_equilibrium(m, {FLEX: p, EXT: p})["stiffness.K"] for p in (0.0, 0.4e6)]
    assert K[1] > 1.5 * K[0]


def test_bundle_fibres_share_the_load_and_recruiting_one_raises_the_force():
    m = bundle(3, 2, setup="isometric", fidelity="symmetric")
    f = [
        solve_equilibrium(m, {f"regulator{i}.p_cmd": 0.1e6 for i in range(1, k + 1)})["sensor.f"]
        for k in (0, 1, 2, 3)
    ]
    assert abs(f[0]) < 1e-9  # the fixture sits where the bundle hangs at 0 Pa
    assert np.all(np.diff(f) > 0.1)


@pytest.mark.parametrize(
    ("build", "name"),
    [
        (lambda: antagonistic_joint(2, supply="valve_pwm", regulator_p_max=5e5), "regulator_p_max"),
        (lambda: antagonistic_joint(2, supply="pump"), "supply"),
        (lambda: antagonistic_joint(2, fidelity="linear"), "fidelity"),
        (lambda: antagonistic_joint(2, fidelity="paper"), "fidelity"),
        (lambda: antagonistic_joint(0), "n_flexor"),
        (lambda: antagonistic_joint(2, 3.5), "n_extensor"),
        (lambda: antagonistic_joint(2, tendon_length=0.0), "tendon_length"),
        (lambda: antagonistic_joint(2, radius=0.01), "joint"),
        (lambda: bundle(0), "k_fibres"),
        (lambda: bundle(13), "k_fibres"),
        (lambda: bundle(2, setup="spring"), "setup"),
        (lambda: bundle(2, setup="isometric", load_kg=0.05), "load_kg"),
        (lambda: bundle(2, fidelity="equilibrium_path"), "fidelity"),
    ],
)
def test_bad_settings_are_refused_naming_the_argument(build, name):
    with pytest.raises(ParameterError) as exc:
        build()
    assert exc.value.name == name


@pytest.mark.parametrize("fidelity", ["full", "symmetric"])
def test_a_bundle_of_one_fibre_is_the_chain_set_up(fidelity):
    from sarcomere.dynamics.assemblies import hanging_load, isometric

    u = {"regulator1.p_cmd": 0.15e6}
    hung = solve_equilibrium(bundle(1, 2, fidelity=fidelity, load_kg=0.03), u)
    ref = solve_equilibrium(
        hanging_load(2, load_kg=0.03, fidelity=fidelity), {"regulator.p_cmd": 0.15e6}
    )
    assert hung["load.s"] == pytest.approx(ref["load.s"], rel=1e-9)
    held = solve_equilibrium(bundle(1, 2, fidelity=fidelity, setup="isometric"), u)
    ref = solve_equilibrium(isometric(2, fidelity=fidelity), {"regulator.p_cmd": 0.15e6})
    assert held["sensor.f"] == pytest.approx(ref["sensor.f"], rel=1e-9)


@pytest.mark.slow
def test_joint_on_pwm_valves_energy_balance_closes_to_1e_9_of_the_supply_work():
    """The switched valves' supply work = the stored energy's change + the dissipated
    energy, through 5 PWM periods from rest (quadratures between the PWM edges)."""
    from sarcomere.dynamics.signals import Step

    m = antagonistic_joint(2, supply="valve_pwm", m_arm=0.02)  # full: every unit
    names = ["flexor_valve.cmd", "extensor_valve.cmd"]
    assert m.input_names == names and set(m.modulators) == set(names)
    x0 = solve_equilibrium(m, dict.fromkeys(names, 0.0)).x  # at rest, vented
    duty = {"flexor_valve.cmd": 0.6, "extensor_valve.cmd": 0.3}
    trains = {
        n: m.modulators[n].law(Step(final=d, unit="1"), Step(final=d, unit="1"), 0.0)
        for n, d in duty.items()
    }
    t_end = 0.1
    edges = sorted({0.0, t_end, *(e for tr in trains.values() for e in tr.breakpoints(0.0, t_end))})
    f, en, sig = m.function("ode"), m.function("energy"), m.function("signals")
    x, u = cs.SX.sym("x", m.nx), cs.SX.sym("u", 2)
    p, z = m.parameters({"joint.m_arm": 0.02}), cs.SX(0, 1)
    rows = [m.signal_names.index(f"{n.split('.')[0]}_source.power") for n in names]
    power = cs.sum1(sig(x, z, u, p)[rows])
    ode = {
        "x": cs.vertcat(x, cs.SX.sym("q", 2)),
        "p": u,
        "ode": cs.vertcat(f(x, z, u, p), en(x, z, u, p)[1], power),
    }
    opts = {"reltol": 1e-12, "abstol": 1e-15, "max_num_steps": 200_000}
    w = np.concatenate([x0, [0.0, 0.0]])
    for a, b in zip(edges[:-1], edges[1:], strict=True):
        held = [float(trains[n](0.5 * (a + b))) for n in names]
        w = np.array(cs.integrator("seg", "cvodes", ode, 0.0, b - a, opts)(x0=w, p=held)["xf"])
        w = w.ravel()
    E = [float(en(s, np.zeros(0), np.zeros(2), p)[0]) for s in (x0, w[: m.nx])]
    work = w[m.nx + 1]
    assert work > 1e-3
    assert abs(E[1] - E[0] + w[m.nx] - work) < 1e-9 * work
    assert w[m.state_names.index("joint.theta")] > 0.01  # the flexor's longer pulses win
