"""Translational components along the chain axis (s points down, along gravity).

Sign convention (Modelica): ``flange.f`` is the force the connected world exerts on
the component [N], positive along +s (down).
"""

from __future__ import annotations

import casadi as cs

from ..modeling import laws
from ..modeling.component import Builder, Component
from ..modeling.ports import FLANGE
from .environment import ENVIRONMENT


class Fixed(Component):
    """A flange held at position ``s0`` [m] (the frame, a rigid fixture)."""

    def __init__(self, name: str, s0: float = 0.0) -> None:
        super().__init__(name)
        self.s0 = s0

    def build(self, b: Builder) -> None:
        s0 = b.parameter("s0", self.s0, "m", "position of the fixed flange")
        b.equation(b.port("flange", FLANGE).s, s0)


class Position(Component):
    """A flange moved to the input position ``s`` [m] (an ideal position source)."""

    def build(self, b: Builder) -> None:
        s = b.input("s", "m", "position imposed on the flange")
        b.equation(b.port("flange", FLANGE).s, s)


class Force(Component):
    """The input force ``f`` [N] applied to a flange along +s (an ideal force source)."""

    def build(self, b: Builder) -> None:
        f = b.input("f", "N", "force applied to the connected flange along +s")
        b.equation(b.port("flange", FLANGE).f, -f)


class Mass(Component):
    """A point mass ``m`` [kg] with gravity along +s; states s [m], v [m/s].

    ``g`` None: the environment's gravity (``ambient.g``, one for the whole model); a
    number [m/s^2]: this mass's own parameter (0 for a motion across gravity).
    ``s_nominal`` [m], ``v_nominal`` [m/s]: the states' scaling magnitudes (default
    ``|start|``, or 1 for a zero start); importers scale their absolute tolerance by them
    (fmpy's CVode: ``atol = rtol * nominal``), so a millimetre travel needs its own.
    """

    def __init__(
        self,
        name: str,
        m: float,
        g: float | None = None,
        s_start: float | cs.SX = 0.0,
        v_start: float = 0.0,
        s_nominal: float | None = None,
        v_nominal: float | None = None,
    ) -> None:
        super().__init__(name)
        self.m, self.g, self.s_start, self.v_start = m, g, s_start, v_start
        self.s_nominal, self.v_nominal = s_nominal, v_nominal

    def build(self, b: Builder) -> None:
        m = b.parameter("m", self.m, "kg", "mass", low=1e-12)
        if self.g is None:
            g = b.outer(ENVIRONMENT)["g"]
        else:
            g = b.parameter("g", self.g, "m/s^2", "gravitational acceleration along +s")
        s = b.state("s", self.s_start, "m", "position", nominal=self.s_nominal)
        v = b.state("v", self.v_start, "m/s", "velocity", nominal=self.v_nominal)
        self.position = s
        fa, fb = b.port("flange_a", FLANGE), b.port("flange_b", FLANGE)
        b.equation(fa.s, s)
        b.equation(fb.s, s)
        acceleration, kinetic, gravity = laws.apply(_point_mass, [fa.f, fb.f, m, g, s, v])
        b.der(s, v)
        b.der(v, acceleration)
        b.energy("kinetic", kinetic)
        b.energy("gravity", gravity)


def _point_mass(f_a, f_b, m, g, s, v) -> list:
    """Acceleration [m/s^2], kinetic and gravitational energy [J] of a point mass."""
    return [(f_a + f_b) / m + g, 0.5 * m * v**2, -m * g * s]


class Node(Component):
    """A massless point carrying a weight along +s: ``weight`` [N] (its own parameter), or
    the weight of a mass ``m`` [kg] under the environment's gravity (``ambient.g``).

    Its position is fixed by the forces of what is connected (they must balance), so it
    turns a mass into an algebraic unknown: the quasi-static fidelity level uses it.
    """

    def __init__(
        self,
        name: str,
        weight: float = 0.0,
        s_start: float | cs.SX = 0.0,
        m: float | None = None,
    ) -> None:
        super().__init__(name)
        self.weight, self.s_start, self.m = weight, s_start, m

    def build(self, b: Builder) -> None:
        if self.m is None:
            w = b.parameter("weight", self.weight, "N", "weight carried by the node")
        else:
            m = b.parameter("m", self.m, "kg", "mass whose weight the node carries", low=0.0)
            w = m * b.outer(ENVIRONMENT)["g"]
        fl = b.port("flange_a", FLANGE)
        b.set_start(fl.s, self.s_start)
        self.position = fl.s
        b.equation(fl.f + w, 0.0)
        b.energy("gravity", -w * fl.s)


class ViscousNode(Component):
    """A massless point held by viscous drag ``d`` [N s/m] to the ground: first order,
    ``d ds/dt = f`` with ``f`` the sum of the forces of what is connected [N]."""

    def __init__(self, name: str, d: float, s_start: float = 0.0) -> None:
        super().__init__(name)
        self.d, self.s_start = d, s_start

    def build(self, b: Builder) -> None:
        d = b.parameter("d", self.d, "N*s/m", "viscous drag to the ground", low=1e-12)
        s = b.state("s", self.s_start, "m", "position")
        fl = b.port("flange_a", FLANGE)
        b.equation(fl.s, s)
        b.der(s, fl.f / d)
        b.dissipation("damping", fl.f**2 / d)


class _Compliant(Component):
    """Base of two-flange transport elements: relative position s_rel = s_b - s_a."""

    def _flanges(self, b: Builder):
        fa, fb = b.port("flange_a", FLANGE), b.port("flange_b", FLANGE)
        return fa, fb, fb.s - fa.s

    @staticmethod
    def _force(b: Builder, fa, fb, f) -> None:
        """``f`` [N] is the tension of the element: it pulls its two flanges together."""
        b.equation(fb.f, f)
        b.equation(fa.f, -f)


class Spring(_Compliant):
    """Linear spring ``f = c (s_rel - s_rel0 - gap)`` [N], only while stretched past ``gap``.

    With ``gap = 0`` and ``one_sided = False`` it is the textbook two-sided spring; with
    ``one_sided = True`` it pushes back only when stretched beyond ``s_rel0 + gap``
    (a fixture with play).
    """

    def __init__(
        self, name: str, c: float, s_rel0: float = 0.0, gap: float = 0.0, one_sided: bool = False
    ) -> None:
        super().__init__(name)
        self.c, self.s_rel0, self.gap, self.one_sided = c, s_rel0, gap, one_sided

    def build(self, b: Builder) -> None:
        c = b.parameter("c", self.c, "N/m", "spring constant", low=0.0)
        s0 = b.parameter("s_rel0", self.s_rel0, "m", "unstretched length")
        gap = b.parameter("gap", self.gap, "m", "play before the spring engages", low=0.0)
        fa, fb, s_rel = self._flanges(b)
        e = s_rel - s0 - gap
        if self.one_sided:
            e = cs.fmax(e, 0.0)
        self._force(b, fa, fb, c * e)
        b.output("f", c * e, "N", "spring tension")
        b.energy("elastic", 0.5 * c * e**2)


class Damper(_Compliant):
    """Linear damper ``f = d v_rel`` [N] with ``v_rel = d(s_b - s_a)/dt`` [m/s]."""

    def __init__(self, name: str, d: float) -> None:
        super().__init__(name)
        self.d = d

    def build(self, b: Builder) -> None:
        d = b.parameter("d", self.d, "N*s/m", "damping coefficient", low=0.0)
        fa, fb, s_rel = self._flanges(b)
        v_rel = b.der_of("v_rel", s_rel, "m/s", "relative velocity of flange_b to flange_a")
        self._force(b, fa, fb, d * v_rel)
        b.dissipation("damping", d * v_rel**2)


class ForceSensor(Component):
    """Massless sensor between two flanges; output ``f`` [N], the force it transmits."""

    def build(self, b: Builder) -> None:
        fa, fb = b.port("flange_a", FLANGE), b.port("flange_b", FLANGE)
        b.equation(fa.s, fb.s)
        b.equation(fa.f + fb.f, 0.0)
        b.output("f", fb.f, "N", "tension transmitted (pulling flange_b along +s)")


class PositionSensor(Component):
    """Ideal position sensor; output ``s`` [m]."""

    def build(self, b: Builder) -> None:
        fl = b.port("flange", FLANGE)
        b.equation(fl.f, 0.0)
        b.output("s", fl.s, "m", "measured position")


__all__ = [
    "Damper",
    "Fixed",
    "Force",
    "ForceSensor",
    "Mass",
    "Node",
    "Position",
    "PositionSensor",
    "Spring",
    "ViscousNode",
]
