"""Pneumatic components: sources, the regulator, the ISO 6358 restriction, chambers.

Ports carry absolute pressure ``p`` [Pa] and mass flow ``m_flow`` [kg/s], positive into
the component. Air is an ideal gas; its gas constant, ratio of specific heats and the
ambient pressure and temperature come from the model's one environment
(:class:`~sarcomere.dynamics.components.environment.Environment`, ``Builder.outer``).
Air flowing into a chamber arrives at the ambient temperature (the supply and the tube are
at room temperature); air leaving it has the chamber's temperature. See docs/model.md.
"""

from __future__ import annotations

import math

import casadi as cs

from ..errors import ParameterError
from ..modeling import laws
from ..modeling.component import Builder, Component
from ..modeling.ports import FLANGE, PNEUMATIC
from .environment import ENVIRONMENT

RHO0_ISO = 1.185  # kg/m^3, ISO 6358-1 reference density (20 degC, 100 kPa, 65 % RH)
T0_ISO = 293.15  # K, ISO 6358-1 reference temperature (20 degC)
THERMAL = ("isothermal", "adiabatic")
"""Chamber thermal models: the air at ambient temperature, or the energy balance of an
adiabatic (insulated) chamber."""


class Regulator(Component):
    """Proportional pressure regulator: commanded gauge pressure, first-order lag.

    Input ``p_cmd`` [Pa gauge], published range ``[0, p_max]`` (the regulating range).
    The set pressure ``p_set`` follows ``tau dp_set/dt = u - p_set`` with
    ``u = clamp(p_cmd, 0, p_max)`` (``saturate=True``, for plants) or ``u = p_cmd``
    (``saturate=False``, for optimisers, which need the input's bounds and a non-zero
    gradient, not a clamp). The outlet is an ideal pressure source ``p_amb + p_set`` that
    also vents (negative flow) to ambient, ``p_amb`` from the environment.
    Defaults: Festo VPPE-3-1-1/8-6-010-E1, 6 bar variant (data sheet: range 0.06..6 bar,
    800 l/min); the lag ``tau`` is an estimate (the data sheet gives no response time).
    """

    def __init__(
        self, name: str, tau: float = 0.05, p_max: float = 6e5, saturate: bool = True
    ) -> None:
        super().__init__(name)
        if not isinstance(saturate, bool):
            raise ParameterError("saturate", saturate, "True or False")
        self.tau, self.p_max, self.saturate = tau, p_max, saturate

    def build(self, b: Builder) -> None:
        p_amb = b.outer(ENVIRONMENT)["p"]
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
        p_cmd = b.input(
            "p_cmd",
            "Pa",
            "commanded gauge pressure (the regulating range)",
            0.0,
            low=0.0,
            high=self.p_max,
        )
        p_set = b.state("p_set", 0.0, "Pa", "set gauge pressure after the lag")
        u = cs.fmin(cs.fmax(p_cmd, 0.0), p_max) if self.saturate else p_cmd
        b.der(p_set, (u - p_set) / tau)
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
    laminar threshold ``r_lam`` [1]. The flow is ISO 6358's ``q sqrt(T0/T_up)`` with the
    upstream temperature: the ambient temperature when ``port_a`` (the supply side) is
    upstream, ``T_b`` [K] when ``port_b`` is (a CasADi expression of the model's
    variables, e.g. a chamber's temperature; None: the ambient temperature). ``smooth``
    selects the C1 laminar join (see :func:`iso6358_flow`). Output ``m_flow`` [kg/s],
    positive from a to b. Between two sides at the ambient temperature (``T_b`` None or
    the ambient temperature: isothermal air) it declares its throttling dissipation
    ``q R T ln(p_a/p_b)`` [W], the flow exergy it destroys (>= 0).
    """

    def __init__(
        self,
        name: str,
        C: float = 1.0e-9,
        b: float = 0.3,
        r_lam: float = 0.999,
        smooth: bool = False,
        T_b: cs.SX | None = None,
    ) -> None:
        super().__init__(name)
        self.C, self.b, self.r_lam, self.smooth, self.T_b = C, b, r_lam, smooth, T_b

    def build(self, b: Builder) -> None:
        T_amb = b.outer(ENVIRONMENT)["T"]
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
        rho0 = b.parameter(
            "rho0", RHO0_ISO, "kg/m^3", "ISO 6358 reference density", 0.0, source="ISO 6358-1"
        )
        T0 = b.parameter(
            "T0", T0_ISO, "K", "ISO 6358 reference temperature", 1.0, source="ISO 6358-1"
        )
        pa, pb = b.port("port_a", PNEUMATIC), b.port("port_b", PNEUMATIC)
        T_b = T_amb if self.T_b is None else self.T_b
        args = [pa.p, pb.p, C, bc, rl, rho0, T0, T_amb, T_b]
        (q,) = laws.apply(_restriction_flow, args, smooth=self.smooth)
        if self.T_b is None or cs.is_equal(self.T_b, T_amb):  # isothermal: throttling exergy
            R = b.outer(ENVIRONMENT)["R"]
            b.dissipation("throttling", q * R * T_amb * (cs.log(pa.p) - cs.log(pb.p)))
        b.equation(pa.m_flow, q)
        b.equation(pb.m_flow, -q)
        b.output("m_flow", q, "kg/s", "mass flow from port_a to port_b")


def _restriction_flow(p_a, p_b, C, b_crit, r_lam, rho0, T0, T_amb, T_b, smooth: bool) -> list:
    """:func:`iso6358_flow` [kg/s] times ``sqrt(T0 / T_up)``, the upstream temperature
    ``T_amb`` (side a upstream) or ``T_b`` (see :class:`Restriction`)."""
    T_up = cs.if_else(p_a >= p_b, T_amb, T_b)
    return [iso6358_flow(p_a, p_b, C, b_crit, r_lam, rho0, smooth=smooth) * cs.sqrt(T0 / T_up)]


class Chamber(Component):
    """Air in a volume ``V = V0 + A s`` [m^3] whose wall is the flange (position ``s``).

    States: the air mass ``m_air`` [kg] and, for ``thermal="adiabatic"``, the potential
    temperature ``theta`` [K]; ``p = m_air R T / V``. Isothermal: ``T`` is the ambient
    temperature.
    Adiabatic (no heat through the wall), the energy balance of the open volume:
    ``d(m c_v T)/dt = c_p T_up m_flow - p dV/dt`` with ``T_up`` the ambient temperature
    while filling and ``T`` while venting, plus the wall heat ``m c_v (T_amb - T)/tau_heat``
    (default ``tau_heat = inf``: none; a finite value makes the equilibrium unique, at the
    ambient temperature; the energy function does not count that heat). The wall force
    is exactly ``(p - p_amb) dV/ds`` (virtual work). Starts at ``p_amb + p_start_gauge``
    and the ambient temperature (the start mass is an expression of ``V0`` and the
    environment). After building,
    ``temperature`` is the air temperature (a symbol or expression, for a restriction).
    """

    def __init__(
        self,
        name: str,
        V0: float,
        A: float,
        p_start_gauge: float = 0.0,
        thermal: str = "isothermal",
        tau_heat: float = math.inf,
    ) -> None:
        super().__init__(name)
        if thermal not in THERMAL:
            raise ParameterError("thermal", thermal, f"one of {THERMAL}")
        if not tau_heat > 0:
            raise ParameterError("tau_heat", tau_heat, "(0, inf] s")
        self.V0, self.A, self.p_start_gauge, self.thermal = V0, A, p_start_gauge, thermal
        self.tau_heat = tau_heat

    def build(self, b: Builder) -> None:
        env = b.outer(ENVIRONMENT)
        p_amb, T_amb, R, gamma = env["p"], env["T"], env["R"], env["gamma"]
        V0 = b.parameter("V0", self.V0, "m^3", "volume at s = 0", low=1e-15)
        A = b.parameter("A", self.A, "m^2", "effective area dV/ds of the moving wall", low=0.0)
        m = b.state("m_air", 0.0, "kg", "air mass in the chamber", low=0.0)
        b.set_start(m, V0 * (p_amb + self.p_start_gauge) / (R * T_amb))
        port, wall = b.port("port", PNEUMATIC), b.port("flange", FLANGE)
        if self.thermal == "isothermal":
            T = T_amb
            self.temperature = T
            V, p, e_gas = laws.apply(_isothermal_air, [m, wall.s, V0, A, R, T, p_amb])
        else:
            V = V0 + A * wall.s
            # state: the potential temperature theta = T (rho_amb / rho)^(gamma - 1) [K], the
            # temperature at the ambient density after an isentropic change; it is constant
            # while the air only expands, is compressed or vents, and the energy balance
            # d(m c_v T)/dt = c_p T_up m_flow - p dV/dt becomes (with T_up = T_amb, filling)
            # dtheta/dt = gamma theta max(m_flow, 0) (T_amb - T) / (m T): no dV/dt needed.
            rho_amb = p_amb / (R * T_amb)
            rho_start = (p_amb + self.p_start_gauge) / (R * T_amb)
            theta = b.state(
                "theta", 0.0, "K", "potential temperature (at the ambient density)", low=0.0
            )
            b.set_start(theta, T_amb * (rho_amb / rho_start) ** (gamma - 1.0))
            T = theta * (m / (V * rho_amb)) ** (gamma - 1.0)
            self.temperature = T
            p = m * R * T / V
            tau = b.parameter(
                "tau_heat",
                self.tau_heat,
                "s",
                "time constant of the heat exchange with the wall (inf: none)",
                low=1e-9,
                source="estimate",
            )
            mdot_in = cs.fmax(port.m_flow, 0.0)
            # the wall heat m c_v (T_amb - T) / tau changes theta by theta/T of dT/dt
            b.der(theta, theta * (T_amb - T) / T * (gamma * mdot_in / m + 1.0 / tau))
            e_gas = m * R * T / (gamma - 1.0)
            b.output("T", T, "K", "air temperature", low=0.0)
        b.der(m, port.m_flow)
        b.equation(port.p, p)
        b.energy("gas", _pressed_wall(b, wall, p, V, e_gas, p_amb, A))


def _isothermal_air(m, s, V0, A, R, T, p_amb) -> list:
    """Volume ``V0 + A s`` [m^3], pressure ``m R T / V`` [Pa] and the gas energy
    ``m R T (ln(p / p_amb) - 1)`` [J] of air at the temperature ``T``."""
    V = V0 + A * s
    p = m * R * T / V
    return [V, p, m * R * T * (cs.log(p / p_amb) - 1.0)]


def _wall(p, V, e_gas, p_amb, A) -> list:
    """The force on the chamber's wall flange ``-(p - p_amb) A`` [N] (virtual work), the
    gauge pressure [Pa] and the stored energy ``e_gas + p_amb V`` [J]."""
    return [-(p - p_amb) * A, p - p_amb, e_gas + p_amb * V]


def _pressed_wall(b: Builder, wall, p, V, e_gas, p_amb, A) -> cs.SX:
    """The wall force of a chamber at pressure ``p`` [Pa] with volume ``V`` [m^3], gas
    energy ``e_gas`` [J] and ``A = dV/ds`` [m^2] on ``wall`` (:func:`_wall`), and its
    outputs ``p``, ``p_gauge``, ``V``; returns the stored energy [J]."""
    force, p_gauge, energy = laws.apply(_wall, [p, V, e_gas, p_amb, A])
    b.equation(wall.f, force)
    b.output("p", p, "Pa", "absolute pressure", low=0.0)
    b.output("p_gauge", p_gauge, "Pa", "gauge pressure")
    b.output("V", V, "m^3", "volume")
    return energy


class InstantChamber(Component):
    """A chamber whose air follows its supply at once: no storage, no air-mass state.

    The limit of :class:`Chamber` fed through a tube whose filling time constant
    ``V / (R T dm_flow/dp)`` (0.37 ms for the APS) is short against everything else: the
    pressure ``p`` is the port's pressure (the supply's, e.g. the regulator's outlet
    ``p_amb + p_out``), the wall force and the outputs ``p``, ``p_gauge``, ``V`` as
    :class:`Chamber`'s. The mass flow is not modelled: the port draws none, so the tube
    before it carries none and is left out. No temperature (the force depends on the
    pressure only); :attr:`temperature` is the ambient one. Stored energy ``-(p - p_amb) V``
    [J]: the potential of the supply's constant gauge pressure on the wall, so the energy
    balance holds while the supply pressure is constant; a change ``dp`` of the supply
    pressure changes it by ``-V dp``, work of the supply that the dissipation does not
    count (in :class:`Chamber` the supply's work arrives with the air through the tube).
    """

    def __init__(self, name: str, V0: float, A: float) -> None:
        super().__init__(name)
        self.V0, self.A = V0, A

    def build(self, b: Builder) -> None:
        env = b.outer(ENVIRONMENT)
        p_amb = env["p"]
        self.temperature = env["T"]
        V0 = b.parameter("V0", self.V0, "m^3", "volume at s = 0", low=1e-15)
        A = b.parameter("A", self.A, "m^2", "effective area dV/ds of the moving wall", low=0.0)
        port, wall = b.port("port", PNEUMATIC), b.port("flange", FLANGE)
        V = V0 + A * wall.s
        p = port.p
        b.equation(port.m_flow, 0.0)
        # no air: the stored energy e_gas + p_amb V of the wall law is -(p - p_amb) V
        b.energy("gas", _pressed_wall(b, wall, p, V, -p * V, p_amb, A))
