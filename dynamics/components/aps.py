"""The artificial pneumatic sarcomere (APS) and the myofibril: components and composition.

Coordinates (see docs/model.md for the derivation and assumptions):

* chain axis ``s`` [m], pointing down (along gravity); the frame hook is at s = 0;
* SPA expansion ``d`` [m]: increase of the anchor spacing ``2 r2 = 2 r2' + d`` of the
  actin threads (both junction zones together).

An APS holds a chamber (air, volume ``V0 + A_p d``), the expansion degree of freedom
(effective mass, viscous loss), the Yeoh restoring element and the SPA body (a mass on
the chain axis). Between neighbouring bodies hang :class:`Actin` elements: two hooked
thread "V"s whose taut height ``r1(d)`` follows from ``r1^2 + r2^2 = (l/2)^2``, with a
series compliance and a smoothly regularised slack. Every coupling force derives from
an energy, so ``p dV`` work, elastic energy and gravity balance exactly.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import casadi as cs

from ..errors import ParameterError
from ..modeling.component import Builder, Component
from ..modeling.ports import FLANGE
from ..params import experimental_geometry, get_material, yeoh_energy
from .mechanical import G_STANDARD, Damper, Fixed, Mass, Node, ViscousNode
from .pneumatic import T_REF, Chamber, Restriction


@dataclass(frozen=True)
class APSParams:
    """Effective parameters of one APS (SI). Geometry defaults: the paper's experimental APS.

    Attributes
    ----------
    l : float
        Actin thread length [m] (paper: 32 mm).
    w0 : float
        Anchor spacing at rest ``2 r2' = h_m - 2 t_w - h_ch`` [m] (paper: 20 mm).
    A_band : float
        SPA body height along the chain, the A-band ``A`` [m] (paper: 30 mm).
    h_jz : float
        Junction-zone height [m] (paper: 2 mm); the restoring stretch is ``1 + d/L_r``.
    L_r : float
        Length over which the expansion stretches the junction zones [m]
        (default ``2 h_jz``: two junction zones between the anchors).
    A_r : float
        Effective cross-section of the Yeoh restoring element [m^2]
        (calibrated against the paper's concentric experiment; ``a_hz b_hz`` = 90 mm^2
        would be the paper's F_r).
    C1, C2, C3 : float
        Yeoh constants [Pa] (default DragonSkin 30, paper).
    A_p : float
        Effective pneumatic area ``dV/dd`` [m^2] (calibrated against the 0.315 N
        isometric force; ``a_ch b_ch`` = 95 mm^2 is the geometric bound).
    k_s : float
        Series stiffness of one I-band (two hooked thread V's, anchors) [N/m]
        (calibrated against the 100 g passive stretch).
    c_s : float
        Viscous damping along the I-band [N s/m] (estimate).
    eps_slack : float
        Regularisation length of the thread slack [m] (numerical; the taut force error
        at zero stretch is ``k_s eps_slack / 2``).
    m_e : float
        Effective mass of the expansion motion [kg] (estimate: the outer chamber walls).
    c_e : float
        Viscous damping of the expansion [N s/m] (estimate: silicone loss).
    m_body : float
        SPA body mass on the chain axis [kg] (DragonSkin 30, 1080 kg/m^3, estimated
        solid volume 8 cm^3).
    V0 : float
        Chamber volume at rest incl. the tube's dead volume [m^3] (estimate: six
        chambers ``a_ch b_ch h_ch`` = 2.85 cm^3 plus about 1.2 cm^3 of tube).
    C_tube : float
        Sonic conductance of the feed tube and fittings [m^3/(s Pa)] (estimate:
        0.2 l/(s bar)).
    b_tube : float
        Critical pressure ratio of the feed tube [1] (estimate, ISO 6358 typical 0.3).
    r_lam : float
        Laminar-region threshold ratio [1] (numerical, 0.995..0.999 typical).
    n_poly : float
        Polytropic exponent of the chamber air [1] (1 isothermal, 1.4 adiabatic).
    material : str
        Slug of the Yeoh material C1..C3 come from (provenance only).
    """

    l: float = 32e-3
    w0: float = 20e-3
    A_band: float = 30e-3
    h_jz: float = 2e-3
    L_r: float = 4e-3
    A_r: float = 2.6106e-7
    C1: float = 0.096e6
    C2: float = 0.0095e6
    C3: float = 0.0
    A_p: float = 4.0479e-6
    k_s: float = 417.72
    c_s: float = 0.5
    eps_slack: float = 1e-5
    m_e: float = 1e-3
    c_e: float = 2.0
    m_body: float = 8.6e-3
    V0: float = 4.0e-6
    C_tube: float = 2.0e-9
    b_tube: float = 0.3
    r_lam: float = 0.999
    n_poly: float = 1.0
    material: str = "dragonskin_30"

    def __post_init__(self) -> None:
        for name in ("l", "w0", "A_band", "h_jz", "L_r", "A_r", "A_p", "V0", "eps_slack"):
            v = getattr(self, name)
            if not (v > 0 and math.isfinite(v)):
                raise ParameterError(name, v, "(0, inf) in SI units")
        for name in ("k_s", "c_s", "m_e", "c_e", "m_body", "C_tube"):
            v = getattr(self, name)
            if not (v >= 0 and math.isfinite(v)):
                raise ParameterError(name, v, "[0, inf) in SI units")
        if self.w0 >= self.l:
            raise ParameterError(
                "w0",
                self.w0,
                f"(0, l = {self.l:g}) m",
                "anchors as wide as the thread: 2 r2' >= l, the thread cannot close",
            )
        if not 1.0 <= self.n_poly <= 1.67:
            raise ParameterError("n_poly", self.n_poly, "[1, 1.67]")

    @classmethod
    def from_paper(cls, material: str = "dragonskin_30", **overrides) -> APSParams:
        """Geometry from the paper's experimental APS and a Yeoh material by slug."""
        g = experimental_geometry()
        mat = get_material(material)
        base = cls(
            l=g["l"],
            w0=g["h_m"] - 2 * g["t_w"] - g["h_ch"],
            A_band=g["A"],
            h_jz=g["h_jz"],
            L_r=2 * g["h_jz"],
            C1=mat.C1,
            C2=mat.C2,
            C3=mat.C3,
            material=mat.slug,
        )
        return replace(base, **overrides)

    @property
    def r1_rest(self) -> float:
        """Taut V height at rest ``r1' = sqrt((l/2)^2 - (w0/2)^2)`` [m]."""
        return math.sqrt((self.l / 2) ** 2 - (self.w0 / 2) ** 2)

    @property
    def unit_length_rest(self) -> float:
        """Geometric rest length of one APS in the chain, ``A + 2 r1'`` [m]."""
        return self.A_band + 2 * self.r1_rest


THETA_MIN_RAD = 1e-2
"""Smallest physical thread angle [rad]: below it the thread is taken as pulled straight
(the taut height r1 is floored there, see :func:`thread_height`)."""


def thread_height(d: cs.SX, l: cs.SX, w0: cs.SX) -> cs.SX:
    """Taut height ``r1`` [m] of one thread V for expansion ``d`` [m].

    Floored at 1e-4 l (the thread pulled straight): beyond that the geometry has no
    solution and the equilibrium solver reports it.
    """
    r2 = 0.5 * (w0 + d)
    return cs.sqrt(cs.fmax((0.5 * l) ** 2 - r2**2, (1e-4 * l) ** 2))


class YeohSpring(Component):
    """Restoring element of the SPA: energy ``A_r L_r W(1 + d/L_r)`` [J], d = s_b - s_a."""

    def __init__(self, name: str, p: APSParams) -> None:
        super().__init__(name)
        self.p = p

    def build(self, b: Builder) -> None:
        p = self.p
        A_r = b.parameter(
            "A_r",
            p.A_r,
            "m^2",
            "effective restoring cross-section",
            low=0.0,
            source="calibrated against the paper's concentric experiment",
        )
        L_r = b.parameter(
            "L_r",
            p.L_r,
            "m",
            "stretched length (2 h_jz)",
            low=1e-6,
            source="paper geometry: two junction zones of h_jz = 2 mm",
        )
        src = f"paper, material '{p.material}'"
        C1 = b.parameter("C1", p.C1, "Pa", "Yeoh C1", source=src)
        C2 = b.parameter("C2", p.C2, "Pa", "Yeoh C2", source=src)
        C3 = b.parameter("C3", p.C3, "Pa", "Yeoh C3", source=src)
        fa, fb = b.port("flange_a", FLANGE), b.port("flange_b", FLANGE)
        lam = 1.0 + (fb.s - fa.s) / L_r
        energy = A_r * L_r * yeoh_energy(lam, C1, C2, C3)
        force = cs.gradient(energy, fb.s)
        b.equation(fb.f, force)
        b.equation(fa.f, -force)
        b.output("lambda", lam, "1", "junction-zone stretch", low=0.0)
        b.output("f", force, "N", "restoring force")
        b.energy("elastic", energy)


class Actin(Component):
    """An I-band: two hooked thread V's (or one, at the chain ends) with a series spring.

    Flanges ``flange_a`` (upper body) and ``flange_b`` (lower body) on the chain axis;
    ``exp_a``/``exp_b``: the expansion flanges of the SPAs whose threads form this
    I-band (present when ``upper``/``lower`` is True). Taut length
    ``L_geo = sum(A/2 + r1(d))`` over those SPAs; stretch ``e = s_b - s_a - L_geo``;
    tension ``T = k_s softplus(e) + c_s de/dt`` with
    ``softplus(e) = (e + sqrt(e^2 + eps^2))/2`` (tension only, smooth).
    """

    def __init__(
        self, name: str, p: APSParams, upper: bool, lower: bool, damped: bool = True
    ) -> None:
        super().__init__(name)
        self.p, self.upper, self.lower, self.damped = p, upper, lower, damped

    def build(self, b: Builder) -> None:
        p = self.p
        l = b.parameter("l", p.l, "m", "thread length", low=1e-6, source="paper: 32 mm")
        w0 = b.parameter(
            "w0",
            p.w0,
            "m",
            "anchor spacing at rest 2 r2'",
            low=0.0,
            source="paper: h_m - 2 t_w - h_ch = 20 mm",
        )
        A = b.parameter(
            "A_band", p.A_band, "m", "SPA body height (A-band)", low=0.0, source="paper: A = 30 mm"
        )
        k_s = b.parameter(
            "k_s",
            p.k_s,
            "N/m",
            "series stiffness of the I-band",
            low=0.0,
            source="calibrated against the 100 g passive stretch",
        )
        c_s = b.parameter("c_s", p.c_s, "N*s/m", "I-band damping", low=0.0, source="estimate")
        eps = b.parameter("eps_slack", p.eps_slack, "m", "slack regularisation", low=1e-12)
        fa, fb = b.port("flange_a", FLANGE), b.port("flange_b", FLANGE)
        L_geo = cs.SX(0)
        exps = []
        for side, present in (("exp_a", self.upper), ("exp_b", self.lower)):
            if present:
                fl = b.port(side, FLANGE)
                exps.append(fl)
                L_geo = L_geo + 0.5 * A + thread_height(fl.s, l, w0)
                cos_theta = cs.fmin(cs.fmax((w0 + fl.s) / l, -1.0), 1.0)
                b.output(
                    f"theta_{side[-1]}",
                    cs.acos(cos_theta),
                    "rad",
                    "thread angle, cos(theta) = 2 r2 / l (paper); at its lower bound the thread "
                    "is pulled straight, at its upper bound the anchors meet",
                    low=THETA_MIN_RAD,
                    high=0.5 * math.pi,
                )
        e = fb.s - fa.s - L_geo
        sp = 0.5 * (e + cs.sqrt(e**2 + eps**2))
        tension = k_s * sp
        if self.damped:  # needs the stretch rate: the ends must be masses (not quasi-static)
            e_rate = b.der_of("e_rate", e, "m/s", "stretch rate of the I-band")
            tension = tension + c_s * e_rate
            b.dissipation("damping", c_s * e_rate**2)
        b.equation(fb.f, tension)
        b.equation(fa.f, -tension)
        for fl in exps:  # generalised force on the expansion: T de/dd
            b.equation(fl.f, tension * cs.jacobian(e, fl.s))
        b.output("T", tension, "N", "thread tension (I-band)")
        b.output("e", e, "m", "stretch beyond the taut length (negative: slack)")
        b.output("L_geo", L_geo, "m", "taut length of the I-band")
        # energy of k_s * softplus: integral of (e + sqrt(e^2 + eps^2))/2 de
        r = cs.sqrt(e**2 + eps**2)
        b.energy("elastic", 0.25 * k_s * (e**2 + e * r + eps**2 * cs.asinh(e / eps)))


class APS(Component):
    """One artificial pneumatic sarcomere: chamber, expansion, restoring element, body.

    Ports: ``port`` (pneumatic, the chamber inlet), ``body`` (chain flange at the SPA
    body centre), ``exp`` (the expansion flange the actins hang on).
    ``quasi_static=True`` drops the expansion inertia (the expansion becomes a first-order
    viscous state); ``massless_body=True`` makes the body a weighted massless node (its
    position an algebraic unknown).
    """

    def __init__(
        self,
        name: str,
        p: APSParams,
        s_start: float = 0.0,
        quasi_static: bool = False,
        g: float = G_STANDARD,
        massless_body: bool = False,
    ) -> None:
        super().__init__(name)
        self.p, self.s_start, self.quasi_static, self.g = p, s_start, quasi_static, g
        self.massless_body = massless_body

    def build(self, b: Builder) -> None:
        p = self.p
        ground = b.add(Fixed("ground"))
        chamber = b.add(Chamber("chamber", V0=p.V0, A=p.A_p, n_poly=p.n_poly, T=T_REF))
        yeoh = b.add(YeohSpring("yeoh", p))
        if self.quasi_static:
            exp = b.add(ViscousNode("expansion", d=p.c_e))
        else:
            exp = b.add(Mass("expansion", m=p.m_e, g=0.0))
            loss = b.add(Damper("loss", d=p.c_e))
            b.connect(ground.flange, loss.flange_a)
            b.connect(loss.flange_b, exp.flange_a)
        if self.massless_body:
            body = b.add(Node("body", weight=p.m_body * self.g, s_start=self.s_start))
        else:
            body = b.add(Mass("body", m=p.m_body, g=self.g, s_start=self.s_start))
        b.connect(ground.flange, yeoh.flange_a)
        b.connect(yeoh.flange_b, exp.flange_a)
        b.connect(chamber.flange, exp.flange_a)
        b.expose("port", chamber.port)
        b.expose("body", body.flange_a)
        b.expose("exp", exp.flange_a)


CHAIN_LEVELS = {  # level -> (massless SPA expansion, massless bodies)
    "full": (False, False),
    "quasi_static": (True, False),
    "static_chain": (True, True),
}
"""Fidelity levels of :class:`Myofibril`: all inertias; massless SPA expansion (first
order, viscous; explicit ODE); massless SPA and bodies (undamped threads; the body
positions are algebraic: an index-1 DAE)."""


class Myofibril(Component):
    """``n`` APS in series, each fed by its own tube from one manifold port.

    Ports: ``port`` (the manifold, pneumatic), ``flange_a`` (top hook, on the frame),
    ``flange_b`` (bottom hook, to the load or the fixture). Output ``length`` [m]:
    ``flange_b.s - flange_a.s``. ``params`` is one APSParams for identical units or a
    list of ``n``. ``level`` is one of :data:`CHAIN_LEVELS`.
    """

    def __init__(
        self,
        name: str,
        n: int,
        params: APSParams | list[APSParams],
        level: str = "full",
        g: float = G_STANDARD,
        s_top: float = 0.0,
    ) -> None:
        super().__init__(name)
        if not (isinstance(n, int) and 1 <= n <= 10_000):
            raise ParameterError("n", n, "an integer in [1, 10000]")
        plist = list(params) if isinstance(params, list | tuple) else [params] * n
        if len(plist) != n:
            raise ParameterError("params", len(plist), f"one APSParams or a list of n = {n}")
        if level not in CHAIN_LEVELS:
            raise ParameterError("level", level, f"one of {tuple(CHAIN_LEVELS)}")
        self.n, self.params, self.level, self.g, self.s_top = n, plist, level, g, s_top

    def build(self, b: Builder) -> None:
        units, s = [], self.s_top
        for i, p in enumerate(self.params):
            s += (
                (0.5 * p.A_band + p.r1_rest)
                if i == 0
                else (
                    0.5 * self.params[i - 1].A_band
                    + self.params[i - 1].r1_rest
                    + 0.5 * p.A_band
                    + p.r1_rest
                )
            )
            massless_expansion, massless_body = CHAIN_LEVELS[self.level]
            unit = b.add(APS(f"aps{i + 1}", p, s, massless_expansion, self.g, massless_body))
            tube = b.add(Restriction(f"tube{i + 1}", C=p.C_tube, b=p.b_tube, r_lam=p.r_lam))
            b.connect(tube.port_b, unit.port)
            if i == 0:
                b.expose("port", tube.port_a)
            else:
                b.connect(b.ports["port"], tube.port_a)
            units.append(unit)
        damped = not CHAIN_LEVELS[self.level][1]  # thread damping needs body velocities
        top = b.add(Actin("actin0", self.params[0], upper=False, lower=True, damped=damped))
        b.connect(top.flange_b, units[0].body)
        b.connect(top.exp_b, units[0].exp)
        b.expose("flange_a", top.flange_a)
        for i in range(1, self.n):
            a = b.add(Actin(f"actin{i}", self.params[i], True, True, damped=damped))
            b.connect(a.flange_a, units[i - 1].body)
            b.connect(a.exp_a, units[i - 1].exp)
            b.connect(a.flange_b, units[i].body)
            b.connect(a.exp_b, units[i].exp)
        end = b.add(Actin(f"actin{self.n}", self.params[-1], True, False, damped=damped))
        b.connect(end.flange_a, units[-1].body)
        b.connect(end.exp_a, units[-1].exp)
        b.expose("flange_b", end.flange_b)
        b.output("length", end.flange_b.s - top.flange_a.s, "m", "myofibril length")

    @property
    def rest_length(self) -> float:
        """Geometric rest length ``sum(A + 2 r1')`` [m] (taut threads, no expansion)."""
        return sum(p.unit_length_rest for p in self.params)


class SeriesCopies(Component):
    """``ratio`` identical copies in series of what hangs on ``flange_a``.

    ``s_b = ratio s_a`` and ``f_a = -f_b``: every copy carries the same force and adds
    its own stretch. Not passive on its own (the other copies do work); the energy
    function of a model using it counts one copy.
    """

    def __init__(self, name: str, ratio: float) -> None:
        super().__init__(name)
        self.ratio = ratio

    def build(self, b: Builder) -> None:
        r = b.parameter("ratio", self.ratio, "1", "number of copies in series", low=1.0)
        fa, fb = b.port("flange_a", FLANGE), b.port("flange_b", FLANGE)
        b.equation(fb.s, r * fa.s)
        b.equation(fa.f, -fb.f)


class SymmetricMyofibril(Component):
    """``n`` identical APS reduced to one representative unit (the "symmetric" level).

    All units share one pressure, one expansion and one tension: the representative
    APS (full internal dynamics) carries one unit length ``A + 2 r1(d)`` through an I-band
    of stiffness ``n k_s / (n + 1)`` and damping ``n c_s / (n + 1)`` (the ``n + 1``
    I-bands of the chain in series, per unit); :class:`SeriesCopies` of ratio ``n`` maps
    it to the chain end.
    The bodies are massless; their weight ``n m_body g / 2`` (the mean over the chain)
    acts at the chain end. Ports and the ``length`` output as :class:`Myofibril`.
    """

    def __init__(self, name: str, n: int, params: APSParams, g: float = G_STANDARD) -> None:
        super().__init__(name)
        if not (isinstance(n, int) and 1 <= n <= 10_000):
            raise ParameterError("n", n, "an integer in [1, 10000]")
        self.n, self.p, self.g = n, params, g

    def build(self, b: Builder) -> None:
        n, p = self.n, self.p
        unit = b.add(APS("aps1", replace(p, m_body=0.0), g=self.g, massless_body=True))
        tube = b.add(Restriction("tube1", C=p.C_tube, b=p.b_tube, r_lam=p.r_lam))
        b.connect(tube.port_b, unit.port)
        b.expose("port", tube.port_a)
        per_unit = n / (n + 1)
        band = b.add(
            Actin("actin", replace(p, k_s=per_unit * p.k_s, c_s=per_unit * p.c_s), True, True)
        )
        b.connect(band.flange_b, unit.body)
        b.connect(band.exp_a, unit.exp)
        b.connect(band.exp_b, unit.exp)
        lever = b.add(SeriesCopies("chain", ratio=float(n)))
        b.connect(band.flange_b, lever.flange_a)
        end = b.add(Node("bodies", weight=0.5 * n * p.m_body * self.g))
        b.connect(lever.flange_b, end.flange_a)
        b.expose("flange_a", band.flange_a)
        b.expose("flange_b", lever.flange_b)
        b.output("length", lever.flange_b.s - band.flange_a.s, "m", "myofibril length")

    @property
    def rest_length(self) -> float:
        """Geometric rest length ``n (A + 2 r1')`` [m]."""
        return self.n * self.p.unit_length_rest


__all__ = [
    "APS",
    "APSParams",
    "Actin",
    "Myofibril",
    "SeriesCopies",
    "SymmetricMyofibril",
    "YeohSpring",
    "thread_height",
]
