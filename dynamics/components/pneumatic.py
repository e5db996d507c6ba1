"""Pneumatic components: sources, the regulator, the ISO 6358 restriction, chambers.

Ports carry absolute pressure ``p`` [Pa] and mass flow ``m_flow`` [kg/s], positive into
the component. Air is an ideal gas (R = 287.05 J/(kg K)); flow temperatures are taken
at the reference temperature (see docs/model.md for that and the other assumptions).
"""

from __future__ import annotations

import casadi as cs

from ..modeling.component import Builder, Component
from ..modeling.ports import FLANGE, PNEUMATIC

R_AIR = 287.05  # J/(kg K), specific gas constant of dry air
P_AMB = 101325.0  # Pa, standard atmosphere (ISO 2533)
T_REF = 293.15  # K, ISO 6358-1 reference temperature (20 degC)
RHO0_ISO = 1.185  # kg/m^3, ISO 6358-1 reference density (20 degC, 100 kPa, 65 % RH)


class PressureSource(Component):
    """An ideal source of absolute pressure ``p_amb + p_gauge`` [Pa].

    With ``as_input=True`` the gauge pressure is the model input ``p_gauge`` [Pa];
    otherwise it is a parameter.
    """

    def __init__(
        self, name: str, p_gauge: float = 0.0, p_amb: float = P_AMB, as_input: bool = False
    ) -> None:
        super().__init__(name)
        self.p_gauge, self.p_amb, self.as_input = p_gauge, p_amb, as_input

    def build(self, b: Builder) -> None:
        p_amb = b.parameter("p_amb", self.p_amb, "Pa", "ambient pressure", low=0.0)
        if self.as_input:
            pg = b.input("p_gauge", "Pa", "gauge pressure", self.p_gauge, low=-self.p_amb)
        else:
            pg = b.parameter("p_gauge", self.p_gauge, "Pa", "gauge pressure", low=-self.p_amb)
        b.equation(b.port("port", PNEUMATIC).p, p_amb + pg)


class Regulator(Component):
    """Proportional pressure regulator: commanded gauge pressure, first-order lag, clamp.

    Input ``p_cmd`` [Pa gauge]. The set pressure ``p_set`` follows
    ``tau dp_set/dt = clamp(p_cmd, 0, p_max) - p_set``, and the outlet is an ideal
    pressure source ``p_amb + p_set`` that also vents (negative flow) to ambient.
    Defaults: Festo VPPE-3-1-1/8-6-010-E1, 6 bar variant (data sheet: range 0.06..6 bar,
    800 l/min); the lag ``tau`` is an estimate (the data sheet gives no response time).
    """

    def __init__(
        self, name: str, tau: float = 0.05, p_max: float = 6e5, p_amb: float = P_AMB
    ) -> None:
        super().__init__(name)
        self.tau, self.p_max, self.p_amb = tau, p_max, p_amb

    def build(self, b: Builder) -> None:
        tau = b.parameter(
            "tau", self.tau, "s", "first-order lag", low=1e-6, source="estimate (50-100 ms)"
        )
        p_max = b.parameter(
            "p_max",
            self.p_max,
            "Pa",
            "upper end of the regulating range (gauge)",
            low=0.0,
            source="Festo VPPE-3-1-1/8-6-010-E1 data sheet: 6 bar",
        )
        p_amb = b.parameter("p_amb", self.p_amb, "Pa", "ambient pressure", low=0.0)
        p_cmd = b.input(
            "p_cmd",
            "Pa",
            "commanded gauge pressure (below -p_amb is below vacuum)",
            0.0,
            low=-self.p_amb,
        )
        p_set = b.state("p_set", 0.0, "Pa", "set gauge pressure after the lag")
        b.der(p_set, (cs.fmin(cs.fmax(p_cmd, 0.0), p_max) - p_set) / tau)
        port = b.port("port", PNEUMATIC)
        b.equation(port.p, p_amb + p_set)
        b.output("p_out", p_set, "Pa", "outlet gauge pressure")


def iso6358_flow(
    p_a: cs.SX,
    p_b: cs.SX,
    C: cs.SX,
    b_crit: cs.SX,
    r_lam: cs.SX,
    rho0: cs.SX,
    smooth: bool = False,
) -> cs.SX:
    """Mass flow [kg/s] from side a to side b through an ISO 6358 restriction.

    ``q = C rho0 p_up Psi(r)``, ``r = p_down/p_up``: choked (``Psi = 1``) for ``r <= b``,
    subsonic ``Psi = sqrt(1 - ((r - b)/(1 - b))^2)``, and near ``r = 1`` (above
    ``r_lam``) a laminar join: linear in the pressure drop (``smooth=False``, the plant
    law) or a cubic in ``1 - r`` matching value and slope at ``r_lam`` (``smooth=True``,
    C1 everywhere, for optimisers). Written as ``C rho0 (p_a - p_b) Psi/(1 - r)`` so that
    the flow reverses without ``sign()`` and its slope at zero drop stays finite.

    Parameters: pressures [Pa], ``C`` sonic conductance [m^3/(s Pa)], ``b_crit`` critical
    pressure ratio [1], ``r_lam`` start of the laminar region [1], ``rho0`` reference
    density [kg/m^3].
    """
    p_up = cs.fmax(p_a, p_b)
    r = cs.fmin(p_a, p_b) / p_up
    x = 1.0 - r  # relative pressure drop, >= 0
    w = (r - b_crit) / (1.0 - b_crit)
    psi_sub = cs.sqrt(cs.fmax(1.0 - w**2, 0.0))
    # subsonic branch at the laminar threshold: value and slope d Psi / d x
    x_l = 1.0 - r_lam
    w_l = (r_lam - b_crit) / (1.0 - b_crit)
    psi_l = cs.sqrt(1.0 - w_l**2)
    if smooth:
        dpsi_l = w_l / ((1.0 - b_crit) * psi_l)
        a = (3.0 * psi_l - dpsi_l * x_l) / (2.0 * x_l)
        c3 = (dpsi_l * x_l - psi_l) / (2.0 * x_l**3)
        g_lam = a + c3 * x**2
    else:
        g_lam = psi_l / x_l
    g = cs.if_else(x >= x_l, cs.if_else(r <= b_crit, 1.0, psi_sub) / cs.fmax(x, x_l), g_lam)
    return C * rho0 * (p_a - p_b) * g


class Restriction(Component):
    """ISO 6358 restriction (orifice, tube, fitting) between ``port_a`` and ``port_b``.

    Parameters: sonic conductance ``C`` [m^3/(s Pa)], critical ratio ``b`` [1],
    laminar threshold ``r_lam`` [1]. Output ``m_flow`` [kg/s], positive from a to b.
    """

    def __init__(
        self,
        name: str,
        C: float = 1.0e-9,
        b: float = 0.3,
        r_lam: float = 0.999,
        smooth: bool = False,
    ) -> None:
        super().__init__(name)
        self.C, self.b, self.r_lam, self.smooth = C, b, r_lam, smooth

    def build(self, b: Builder) -> None:
        C = b.parameter(
            "C",
            self.C,
            "m^3/(s*Pa)",
            "sonic conductance",
            low=0.0,
            source="estimate: tube + push-in fitting, 0.1-0.5 l/(s bar)",
        )
        bc = b.parameter("b", self.b, "1", "critical pressure ratio", 0.0, 0.999, "ISO 6358-1")
        rl = b.parameter("r_lam", self.r_lam, "1", "laminar threshold ratio", 0.5, 0.99999)
        rho0 = b.parameter("rho0", RHO0_ISO, "kg/m^3", "ISO 6358 reference density", low=0.0)
        pa, pb = b.port("port_a", PNEUMATIC), b.port("port_b", PNEUMATIC)
        q = iso6358_flow(pa.p, pb.p, C, bc, rl, rho0, smooth=self.smooth)
        b.equation(pa.m_flow, q)
        b.equation(pb.m_flow, -q)
        b.output("m_flow", q, "kg/s", "mass flow from port_a to port_b")


class Chamber(Component):
    """Air in a volume ``V = V0 + A s`` [m^3] whose wall is the flange (position ``s``).

    State: the air mass ``m_air`` [kg]. Pressure from the polytropic law
    ``p = p_amb (rho / rho_amb)^n_poly`` with ``rho = m_air / V`` and
    ``rho_amb = p_amb / (R T)``: ``n_poly = 1`` is isothermal, 1.4 isentropic.
    The wall force is exactly ``(p - p_amb) dV/ds`` (virtual work), so gas, wall and
    ambient exchange energy without loss.
    """

    def __init__(
        self,
        name: str,
        V0: float,
        A: float,
        p_start: float = P_AMB,
        n_poly: float = 1.0,
        T: float = T_REF,
        p_amb: float = P_AMB,
    ) -> None:
        super().__init__(name)
        self.V0, self.A, self.p_start, self.n_poly, self.T, self.p_amb = (
            V0,
            A,
            p_start,
            n_poly,
            T,
            p_amb,
        )

    def build(self, b: Builder) -> None:
        V0 = b.parameter("V0", self.V0, "m^3", "volume at s = 0", low=1e-15)
        A = b.parameter("A", self.A, "m^2", "effective area dV/ds of the moving wall", low=0.0)
        T = b.parameter("T", self.T, "K", "temperature at the reference state", low=1.0)
        p_amb = b.parameter("p_amb", self.p_amb, "Pa", "ambient pressure", low=1.0)
        R = b.parameter("R", R_AIR, "J/(kg*K)", "specific gas constant of air", low=1.0)
        rho_amb = p_amb / (R * T)
        # start mass from the start pressure at s = 0 (the same polytropic law)
        rho0 = self.p_amb / (R_AIR * self.T) * (self.p_start / self.p_amb) ** (1 / self.n_poly)
        m = b.state("m_air", self.V0 * rho0, "kg", "air mass in the chamber", low=0.0)
        port, wall = b.port("port", PNEUMATIC), b.port("flange", FLANGE)
        V = V0 + A * wall.s
        rho = m / V
        if self.n_poly == 1.0:  # isothermal: a structural choice, not a parameter value
            p = rho * R * T
            e_gas = m * R * T * (cs.log(rho / rho_amb) - 1.0)
        else:
            n = b.parameter("n_poly", self.n_poly, "1", "polytropic exponent", 1.0001, 1.67)
            p = p_amb * (rho / rho_amb) ** n
            e_gas = p * V / (n - 1.0)
        b.der(m, port.m_flow)
        b.equation(port.p, p)
        b.equation(wall.f, -(p - p_amb) * A)
        b.output("p", p, "Pa", "absolute pressure", low=0.0)
        b.output("p_gauge", p - p_amb, "Pa", "gauge pressure")
        b.output("V", V, "m^3", "volume")
        b.energy("gas", e_gas + p_amb * V)


class Cap(Component):
    """A closed pneumatic port: no mass flow."""

    def build(self, b: Builder) -> None:
        b.equation(b.port("port", PNEUMATIC).m_flow, 0.0)


class SealedVolume(Component):
    """A :class:`Chamber` behind a :class:`Cap`: a gas spring on the flange (position s).

    Parameters as :class:`Chamber`; the air mass is constant, so an isothermal volume
    keeps ``p V`` constant and a polytropic one ``p V^n``.
    """

    def __init__(
        self, name: str, V0: float, A: float, p_start: float = P_AMB, n_poly: float = 1.0
    ) -> None:
        super().__init__(name)
        self.V0, self.A, self.p_start, self.n_poly = V0, A, p_start, n_poly

    def build(self, b: Builder) -> None:
        ch = b.add(Chamber("chamber", self.V0, self.A, self.p_start, self.n_poly))
        b.connect(ch.port, b.add(Cap("cap")).port)
        b.expose("flange", ch.flange)
