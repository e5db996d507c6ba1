"""Pneumatic components against closed forms: ISO 6358 flow, chamber filling, gas spring."""

import math

import casadi as cs
import numpy as np
import pytest

from sarcomere.dynamics.components.environment import Environment
from sarcomere.dynamics.components.mechanical import Fixed, Mass
from sarcomere.dynamics.components.pneumatic import (
    RHO0_ISO,
    Chamber,
    Regulator,
    Restriction,
    iso6358_flow,
)
from sarcomere.dynamics.errors import ModelError
from sarcomere.dynamics.modeling.component import Builder, Component, System
from sarcomere.dynamics.modeling.ports import PNEUMATIC
from sarcomere.dynamics.params.ambient import Ambient
from sarcomere.dynamics.simulation.simulate import SolverSettings, simulate

C, B, RL = 2e-9, 0.3, 0.999
AMB = Ambient()
P_AMB, R_AIR, T_REF, GAMMA = AMB.p_amb, AMB.R_air, AMB.T_amb, AMB.kappa


class PressureSource(Component):
    """An ideal source of absolute pressure ``p`` [Pa] (a parameter)."""

    def __init__(self, name: str, p: float) -> None:
        super().__init__(name)
        self.p = p

    def build(self, b: Builder) -> None:
        p = b.parameter("p", self.p, "Pa", "absolute pressure", low=0.0)
        b.equation(b.port("port", PNEUMATIC).p, p)


class Cap(Component):
    """A closed pneumatic port: no mass flow."""

    def build(self, b: Builder) -> None:
        b.equation(b.port("port", PNEUMATIC).m_flow, 0.0)


class SealedVolume(Component):
    """A :class:`Chamber` behind a :class:`Cap`: a gas spring on the flange (position s)."""

    def __init__(self, name: str, V0: float, A: float, p_start_gauge: float, thermal="isothermal"):
        super().__init__(name)
        self.chamber = Chamber("chamber", V0, A, p_start_gauge, thermal)

    def build(self, b: Builder) -> None:
        ch = b.add(self.chamber)
        b.connect(ch.port, b.add(Cap("cap")).port)
        b.expose("flange", ch.flange)


def system(name):
    """A System with the shared environment declared first."""
    sys = System(name)
    sys.add(Environment())
    return sys


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


def filling_system(V=5e-6, p_supply=5e5, thermal="isothermal", p_start_gauge=0.0):
    sys = system("filling")
    src = sys.add(PressureSource("src", p=p_supply))
    gas = Chamber("chamber", V0=V, A=0.0, p_start_gauge=p_start_gauge, thermal=thermal)
    ch = sys.add(gas)
    tube = sys.add(Restriction("tube", C=C, b=B, r_lam=RL, T_b=gas.temperature))
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
    for thermal, n_poly in (("isothermal", 1.0), ("adiabatic", GAMMA)):
        sys = system("gas_spring")
        vol = sys.add(
            SealedVolume("vol", V0=1e-4, A=1e-3, p_start_gauge=2e5 - P_AMB, thermal=thermal)
        )
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
    sys = system("gas_spring")
    vol = sys.add(SealedVolume("vol", V0=1e-4, A=1e-3, p_start_gauge=2e5 - P_AMB))
    piston = sys.add(Mass("piston", m=0.5, g=0.0, v_start=2.0))
    sys.connect(vol.flange, piston.flange_a)
    res = simulate(sys.flatten(), 0.2, settings=SolverSettings(rtol=1e-10, atol=1e-14))
    pv = res["vol.chamber.p"] * res["vol.chamber.V"]
    assert np.ptp(res["vol.chamber.V"]) > 0.3 * 1e-4  # a large stroke
    assert np.ptp(pv) < 1e-12 * pv[0] * 1e3
    assert pv[0] == pytest.approx(2e5 * 1e-4, rel=1e-12)


def test_regulator_lag_and_published_range():
    sys = system("reg")
    reg = sys.add(Regulator("regulator", tau=0.05))
    sys.connect(reg.port, sys.add(Cap("cap")).port)
    model = sys.flatten()
    var = model.variables["regulator.p_cmd"]
    assert (var.low, var.high) == (0.0, 6e5)  # the regulating range, gauge
    res = simulate(
        model, 0.2, inputs={"regulator.p_cmd": 1e5}, settings=SolverSettings(rtol=1e-10, atol=1e-8)
    )
    t = res.index
    assert np.allclose(res["regulator.p_out"], 1e5 * (1 - np.exp(-t / 0.05)), atol=1e-3)


@pytest.mark.parametrize("saturate", [True, False])
def test_regulator_saturation_is_optional(saturate):
    """A plant clamps a command beyond p_max; an optimiser's model passes it (and relies on
    the input's bounds), so its gradient is not zero there."""
    sys = system("reg")
    reg = sys.add(Regulator("regulator", tau=0.05, saturate=saturate))
    sys.connect(reg.port, sys.add(Cap("cap")).port)
    m = sys.flatten()
    u = cs.SX.sym("u")
    rate = m.function("ode")(x=[0.0], z=[], u=u, p=m.parameters())["ode"]
    f = cs.Function("f", [u], [rate, cs.jacobian(rate, u)])
    value, slope = (float(v) for v in f(9e5))
    assert value == pytest.approx((6e5 if saturate else 9e5) / 0.05)
    assert slope == (0.0 if saturate else pytest.approx(1 / 0.05))


def test_components_need_the_environment():
    with pytest.raises(ModelError, match="environment 'ambient'.*not declared"):
        System("bare").add(Regulator("regulator"))


def test_adiabatic_filling_of_a_rigid_vessel_matches_the_textbook():
    """Choked inflow at the supply temperature T_s into a rigid adiabatic vessel: the mass
    flow is constant, so ``dp/dt = gamma R T_s mdot / V`` (p rises linearly), and the
    energy balance ``d(m c_v T) = c_p T_s dm`` gives
    ``T = (m0 T_s + gamma T_s (m - m0)) / m``, which tends to ``gamma T_s`` from vacuum.
    A polytropic law at the chamber's own temperature rises 12-22 % too fast."""
    V, ps, p0 = 5e-6, 5e5, 1e3
    model = filling_system(V, ps, "adiabatic", p_start_gauge=p0 - P_AMB)
    mdot = C * RHO0_ISO * ps  # choked, supply at the ISO reference temperature
    rate = GAMMA * R_AIR * T_REF * mdot / V
    t_end = (0.9 * B * ps - p0) / rate  # still choked
    t = np.linspace(0, t_end, 50)
    res = simulate(model, t_end, t_out=t, settings=SolverSettings(rtol=1e-11, atol=1e-16))
    np.testing.assert_allclose(res["chamber.p"], p0 + rate * t, rtol=1e-7)
    m0 = p0 * V / (R_AIR * T_REF)
    m = res["chamber.m_air"]
    np.testing.assert_allclose(m, m0 + mdot * t, rtol=1e-7)
    exact_T = (m0 * T_REF + GAMMA * T_REF * (m - m0)) / m
    np.testing.assert_allclose(res["chamber.T"], exact_T, rtol=1e-7)
    assert res.final("chamber.T") == pytest.approx(GAMMA * T_REF, rel=0.01)  # from near vacuum


def test_venting_flow_uses_the_upstream_chamber_temperature():
    """Choked outflow from a cold chamber: ``q = C rho0 p sqrt(T0 / T_chamber)``."""
    model = filling_system(5e-6, P_AMB, "adiabatic", p_start_gauge=5e5 - P_AMB)
    x = model.x0()
    x[model.state_names.index("chamber.theta")] *= 250.0 / T_REF  # T at x0 is T_REF
    p_ch = x[model.state_names.index("chamber.m_air")] * R_AIR * 250.0 / 5e-6
    y = np.array(model.function("y")(x=x, z=[], u=[], p=model.parameters())["y"]).ravel()
    q = y[model.output_names.index("tube.m_flow")]
    assert y[model.output_names.index("chamber.T")] == pytest.approx(250.0, rel=1e-12)
    assert q == pytest.approx(-C * RHO0_ISO * p_ch * math.sqrt(T_REF / 250.0), rel=1e-12)
