"""On/off valves and the supply they switch: a pressure source and a 2/2 or 3/2 solenoid
valve, each path an ISO 6358 restriction (:func:`~.pneumatic.iso6358_flow`).

The valve's command (input ``cmd``, 0 closed, 1 open) comes from a pulse-width modulator
(:mod:`~sarcomere.dynamics.simulation.pwm`: the simulator switches it between 0 and 1,
every edge a breakpoint) or, in the averaged model, is the PWM's duty itself. The
opening ``x`` follows the command through a first-order lag (the opening time); each
path's sonic conductance is ``C_leak + x (C_open - C_leak)`` (the exhaust path of the
3/2 valve: ``1 - x``), so the flow is linear in the opening at given pressures and the
PWM-averaged flow is the duty-weighted one (docs/model.md). Air through the valve is at
the ambient temperature (the supply, and the isothermal hose on the working side).

Every path declares its throttling dissipation ``q R T ln(p_up/p_down)`` [W] (the
isothermal flow exergy it destroys), and the source its delivered power
``q R T ln(p_s/p_amb)`` [W] as the output ``power``: with isothermal chambers the
energy balance closes, ``E(t) - E(0) + int D dt = int power dt``.
"""

from __future__ import annotations

import casadi as cs

from ..errors import ParameterError
from ..modeling.component import Builder, Component
from ..modeling.ports import PNEUMATIC
from .environment import ENVIRONMENT
from .pneumatic import RHO0_ISO, T0_ISO, iso6358_flow

WAYS = ("2/2", "3/2")
"""Valve types: 2/2 (supply to working port, or closed) and 3/2 (supply to working port,
or working port to the exhaust)."""

C_OPEN = 3.9e-9
"""Sonic conductance of an open path [m^3/(s Pa)]: a standard nominal flow of 100 l/min
(ANR, 6 -> 5 bar gauge) through ISO 6358 with ``b = 0.3``, the class of fast-switching
3/2 solenoid valves (e.g. Festo MHE2); estimate."""

C_LEAK = 7.0e-13
"""Sonic conductance of a closed path [m^3/(s Pa)]: 1 l/h (ANR) of seat leakage at
3 bar gauge, choked; estimate."""


class PressureSource(Component):
    """An ideal compressed-air supply at ``p_amb + p_supply``: it delivers any flow.

    Port ``port`` (the air leaves through it). Outputs ``m_flow`` [kg/s], the flow it
    delivers (its time integral is the air used; no state: an integrating state would
    have no equilibrium), and ``power`` [W], the isothermal flow exergy it delivers,
    ``q R T ln(p/p_amb)`` (the power it gives the system). Default ``p_supply`` 0.3 MPa gauge (above
    the 0.23 MPa that holds 170 mm with 70 g on three APS, the control-length scene;
    below a lab's 6 bar line, reduced by a filter regulator; estimate).
    """

    def __init__(self, name: str, p_supply: float = 3.0e5) -> None:
        super().__init__(name)
        self.p_supply = p_supply

    def build(self, b: Builder) -> None:
        env = b.outer(ENVIRONMENT)
        p_amb, T, R = env["p"], env["T"], env["R"]
        p_s = b.parameter(
            "p_supply",
            self.p_supply,
            "Pa",
            "supply gauge pressure",
            low=1.0,
            high=1.0e6,
            source="estimate: a 6 bar line reduced by a filter regulator",
        )
        port = b.port("port", PNEUMATIC)
        b.equation(port.p, p_amb + p_s)
        q = -port.m_flow
        b.output("m_flow", q, "kg/s", "mass flow delivered (its integral: the air used)")
        b.output("power", q * R * T * cs.log((p_amb + p_s) / p_amb), "W", "power delivered")


class SwitchingValve(Component):
    """An on/off solenoid valve, 2/2 or 3/2 (:data:`WAYS`), between the supply port
    ``port_p`` and the working port ``port_a``; the 3/2 valve exhausts ``port_a`` to the
    ambient air when closed.

    Input ``cmd`` [1], ``[0, 1]``: the command (the PWM's pulse train, or the averaged
    model's duty). State ``x`` [1]: the opening, ``tau dx/dt = cmd - x`` (the opening
    time; the switching delay is the PWM's, a delay being no ODE). Parameters: ``C_open``
    and ``C_leak`` [m^3/(s Pa)] (open and closed sonic conductance of each path), ``b``
    [1] (critical pressure ratio), ``r_lam`` [1] (laminar threshold), ``tau`` [s].
    Outputs: ``m_flow`` [kg/s] (net, into ``port_a``'s side), ``m_flow_in`` (from the
    supply), ``m_flow_exhaust`` (to the ambient air; 3/2 only).
    """

    def __init__(
        self,
        name: str,
        ways: str = "3/2",
        C_open: float = C_OPEN,
        C_leak: float = C_LEAK,
        b: float = 0.3,
        tau: float = 1.5e-3,
        r_lam: float = 0.999,
        smooth: bool = False,
    ) -> None:
        super().__init__(name)
        if ways not in WAYS:
            raise ParameterError("valve_ways", ways, f"one of {WAYS}")
        if not 0 <= C_leak < C_open:
            raise ParameterError("valve_C_leak", C_leak, f"[0, C_open = {C_open:g}) m^3/(s*Pa)")
        self.ways, self.C_open, self.C_leak, self.b = ways, C_open, C_leak, b
        self.tau, self.r_lam, self.smooth = tau, r_lam, smooth

    def build(self, b: Builder) -> None:
        env = b.outer(ENVIRONMENT)
        p_amb, T, R = env["p"], env["T"], env["R"]
        C_open = b.parameter(
            "C_open",
            self.C_open,
            "m^3/(s*Pa)",
            "sonic conductance of an open path",
            low=1e-15,
            source="estimate: 100 l/min nominal flow (fast-switching 3/2 valves), ISO 6358",
        )
        C_leak = b.parameter(
            "C_leak",
            self.C_leak,
            "m^3/(s*Pa)",
            "sonic conductance of a closed path (seat leakage)",
            low=0.0,
            source="estimate: 1 l/h (ANR) at 3 bar gauge",
        )
        bc = b.parameter("b", self.b, "1", "critical pressure ratio", 0.0, 0.999, "ISO 6358-1")
        rl = b.parameter("r_lam", self.r_lam, "1", "laminar threshold ratio", 0.5, 0.99999)
        tau = b.parameter(
            "tau",
            self.tau,
            "s",
            "opening time (first-order lag of the opening)",
            low=1e-6,
            source="estimate: fast-switching valves open in 1-3 ms",
        )
        cmd = b.input(
            "cmd", "1", "command: 1 open, 0 closed (PWM pulses, or the duty)", low=0.0, high=1.0
        )
        x = b.state("x", 0.0, "1", "opening (valve state)", nominal=1.0)
        b.der(x, (cmd - x) / tau)
        pp, pa = b.port("port_p", PNEUMATIC), b.port("port_a", PNEUMATIC)
        scale = cs.sqrt(T0_ISO / T)  # ISO 6358's sqrt(T0 / T_up), T_up = T_amb

        def path(p_up, p_down, opening):
            C = C_leak + opening * (C_open - C_leak)
            q = iso6358_flow(p_up, p_down, C, bc, rl, RHO0_ISO, self.smooth) * scale
            return q, q * R * T * (cs.log(p_up) - cs.log(p_down))

        q_in, d_in = path(pp.p, pa.p, x)
        b.equation(pp.m_flow, q_in)
        b.output("m_flow_in", q_in, "kg/s", "mass flow from the supply port")
        b.dissipation("throttling_in", d_in)
        q = q_in
        if self.ways == "3/2":
            q_ex, d_ex = path(pa.p, p_amb, 1.0 - x)
            b.dissipation("throttling_exhaust", d_ex)
            b.output("m_flow_exhaust", q_ex, "kg/s", "mass flow to the exhaust")
            q = q_in - q_ex
        b.equation(pa.m_flow, -q)
        b.output("m_flow", q, "kg/s", "net mass flow out of the working port")


__all__ = ["WAYS", "PressureSource", "SwitchingValve"]
