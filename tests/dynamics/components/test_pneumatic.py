"""Pneumatic components against closed forms: ISO 6358 flow, chamber filling, gas spring."""

import math

import casadi as cs
import numpy as np
import pytest

from sarcomere.dynamics.components.mechanical import Fixed, Mass
from sarcomere.dynamics.components.pneumatic import (
    P_AMB,
    R_AIR,
    RHO0_ISO,
    T_REF,
    Cap,
    Chamber,
    PressureSource,
    Regulator,
    Restriction,
    SealedVolume,
    iso6358_flow,
)
from sarcomere.dynamics.modeling.component import System
from sarcomere.dynamics.simulation.simulate import SolverSettings, simulate

C, B, RL = 2e-9, 0.3, 0.999


def flow(pa, pb, smooth=False):
    return float(iso6358_flow(pa, pb, C, B, RL, RHO0_ISO, smooth=smooth))


def test_choked_flow_equals_c_rho0_p_up():
    assert flow(5e5, 1e5) == pytest.approx(C * RHO0_ISO * 5e5, rel=1e-14)
    assert flow(1e5, 5e5) == pytest.approx(-C * RHO0_ISO * 5e5, rel=1e-14)  # reverses


def test_subsonic_flow_matches_iso6358():
    pa, pb = 2e5, 1.5e5
    r = pb / pa
    expected = C * RHO0_ISO * pa * math.sqrt(1 - ((r - B) / (1 - B)) ** 2)
    assert flow(pa, pb) == pytest.approx(expected, rel=1e-12)


@pytest.mark.parametrize("smooth", [False, True])
def test_laminar_slope_at_zero_drop(smooth):
    w_l = (RL - B) / (1 - B)
    slope = C * RHO0_ISO * math.sqrt(1 - w_l**2) / (1 - RL)
    if smooth:  # cubic join: the linear coefficient a of a x + c x^3
        psi_l = math.sqrt(1 - w_l**2)
        dpsi = w_l / ((1 - B) * psi_l)
        slope = C * RHO0_ISO * (3 * psi_l - dpsi * (1 - RL)) / (2 * (1 - RL))
    pa = cs.SX.sym("pa")
    q = iso6358_flow(pa, 3e5, C, B, RL, RHO0_ISO, smooth=smooth)
    dq = float(cs.Function("d", [pa], [cs.jacobian(q, pa)])(3e5))
    assert dq == pytest.approx(slope, rel=1e-9)
    assert dq > 0  # no spurious zero slope at equilibrium (no sign())


def test_smooth_law_is_c1_and_close_to_exact():
    pa = cs.SX.sym("pa")
    q = iso6358_flow(pa, 1e5, C, B, RL, RHO0_ISO, smooth=True)
    f = cs.Function("f", [pa], [q, cs.jacobian(q, pa)])
    x_l = 1e5 / RL  # the laminar threshold r = RL
    below, above = f(x_l * (1 - 1e-9)), f(x_l * (1 + 1e-9))
    assert float(above[1]) == pytest.approx(float(below[1]), rel=1e-5)  # slope continuous
    for p_up in (1.01e5, 1.2e5, 3e5):
        assert flow(p_up, 1e5, smooth=True) == pytest.approx(flow(p_up, 1e5), rel=1e-12)


def filling_system(V=5e-6, p_supply=5e5):
    sys = System("filling")
    src = sys.add(PressureSource("src", p_gauge=p_supply - P_AMB))
    tube = sys.add(Restriction("tube", C=C, b=B, r_lam=RL))
    ch = sys.add(Chamber("chamber", V0=V, A=0.0))
    wall = sys.add(Fixed("wall"))
    sys.connect(src.port, tube.port_a)
    sys.connect(tube.port_b, ch.port)
    sys.connect(ch.flange, wall.flange)
    return sys.flatten()


def test_isothermal_filling_follows_analytic_curve():
    """Choked: linear rise; subsonic: w = (r - b)/(1 - b) = sin(k (t - t_b)/(1 - b))."""
    V, ps = 5e-6, 5e5
    model = filling_system(V, ps)
    k = R_AIR * T_REF * C * RHO0_ISO / V  # 1/s, dr/dt in the choked phase
    r0 = P_AMB / ps
    t_b = (B - r0) / k
    t = np.linspace(0, 0.5 * t_b + (1 - B) * math.asin(0.99) / k, 400)
    res = simulate(model, float(t[-1]), t_out=t, settings=SolverSettings(rtol=1e-11, atol=1e-16))
    w = np.sin(np.clip(k * (t - t_b) / (1 - B), -np.inf, np.pi / 2))
    exact = np.where(t < t_b, r0 + k * t, B + (1 - B) * w) * ps
    assert np.max(np.abs(res["chamber.p"] - exact)) / ps < 1e-7


def test_gas_spring_frequency_isothermal_and_adiabatic():
    for n_poly in (1.0, 1.4):
        sys = System("gas_spring")
        vol = sys.add(SealedVolume("vol", V0=1e-4, A=1e-3, p_start=2e5, n_poly=n_poly))
        piston = sys.add(Mass("piston", m=0.5, g=0.0))
        sys.connect(vol.flange, piston.flange_a)
        model = sys.flatten()
        # equilibrium: gas force balances nothing but ambient; linearise about s where p = p_amb
        s_eq = 1e-4 * ((2e5 / P_AMB) ** (1 / n_poly) - 1) / 1e-3
        x = model.x0()
        x[model.state_names.index("piston.s")] = s_eq
        A = np.array(model.function("jac")(x=x, z=[], u=[], p=model.parameters())["A"])
        w = np.abs(np.linalg.eigvals(A)).max()
        V_eq = 1e-4 + 1e-3 * s_eq
        k = n_poly * P_AMB * 1e-3**2 / V_eq
        assert w == pytest.approx(math.sqrt(k / 0.5), rel=1e-9)


def test_isothermal_sealed_volume_keeps_pv_constant_at_large_amplitude():
    sys = System("gas_spring")
    vol = sys.add(SealedVolume("vol", V0=1e-4, A=1e-3, p_start=2e5))
    piston = sys.add(Mass("piston", m=0.5, g=0.0, v_start=2.0))
    sys.connect(vol.flange, piston.flange_a)
    res = simulate(sys.flatten(), 0.2, settings=SolverSettings(rtol=1e-10, atol=1e-14))
    pv = res["vol.chamber.p"] * res["vol.chamber.V"]
    assert np.ptp(res["vol.chamber.V"]) > 0.3 * 1e-4  # a large stroke
    assert np.ptp(pv) < 1e-12 * pv[0] * 1e3
    assert pv[0] == pytest.approx(2e5 * 1e-4, rel=1e-12)


def test_regulator_lag_and_clamp():
    sys = System("reg")
    reg = sys.add(Regulator("regulator", tau=0.05))
    sys.connect(reg.port, sys.add(Cap("cap")).port)
    model = sys.flatten()
    res = simulate(
        model, 0.2, inputs={"regulator.p_cmd": 1e5}, settings=SolverSettings(rtol=1e-10, atol=1e-8)
    )
    t = res.index
    assert np.allclose(res["regulator.p_out"], 1e5 * (1 - np.exp(-t / 0.05)), atol=1e-3)
    res = simulate(model, 0.5, inputs={"regulator.p_cmd": 9e5})
    assert res.final("regulator.p_out") == pytest.approx(6e5, rel=1e-4)  # clamped at 6 bar
