"""Connectors: one potential variable and one flow variable, Modelica style.

Sign convention (as in the Modelica Standard Library): the flow variable is positive
when it flows *into* the component that owns the port.

* :class:`Flange` (translational): position ``s`` [m] and force ``f`` [N]; ``f`` is the
  force the connected world exerts *on* the component, positive along +s.
* :class:`PneumaticPort`: absolute pressure ``p`` [Pa] and mass flow ``m_flow`` [kg/s],
  positive into the component.

``connect(a, b)`` states ``a.potential == b.potential`` and, for each connection set,
``sum(flows) == 0``. A port left unconnected gets ``flow == 0``.
"""

from __future__ import annotations

from dataclasses import dataclass

import casadi as cs


@dataclass(frozen=True)
class PortKind:
    """Names, units and descriptions of a connector's potential and flow variables."""

    name: str
    potential: str
    potential_unit: str
    flow: str
    flow_unit: str


FLANGE = PortKind("Flange", "s", "m", "f", "N")
PNEUMATIC = PortKind("PneumaticPort", "p", "Pa", "m_flow", "kg/s")


@dataclass(eq=False)
class Port:
    """A connector instance: its kind, full path and the two CasADi symbols."""

    kind: PortKind
    path: str
    potential: cs.SX
    flow: cs.SX

    @property
    def s(self) -> cs.SX:
        """Position [m] (flanges)."""
        return self._get("s")

    @property
    def f(self) -> cs.SX:
        """Force into the component [N] (flanges)."""
        return self._get("f")

    @property
    def p(self) -> cs.SX:
        """Absolute pressure [Pa] (pneumatic ports)."""
        return self._get("p")

    @property
    def m_flow(self) -> cs.SX:
        """Mass flow into the component [kg/s] (pneumatic ports)."""
        return self._get("m_flow")

    def _get(self, which: str) -> cs.SX:
        if which == self.kind.potential:
            return self.potential
        if which == self.kind.flow:
            return self.flow
        raise AttributeError(f"port {self.path} ({self.kind.name}) has no variable '{which}'")
