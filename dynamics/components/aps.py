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

import functools
import math
from dataclasses import dataclass, field, fields, replace

import casadi as cs

from ..errors import ParameterError
from ..modeling import laws
from ..modeling.component import Builder, Component
from ..modeling.ports import FLANGE
from ..params import experimental_geometry, get_material, yeoh_energy
from ..params.core import Quantity
from .environment import ENVIRONMENT
from .mechanical import Damper, Fixed, Mass, Node, ViscousNode
from .pneumatic import THERMAL, Chamber, InstantChamber, Restriction


def _f(default, unit: str, low: float, high: float, source: str, description: str, **kw):
    """An APSParams field: default [unit], allowed range ``[low, high]`` (a
    :class:`Quantity`; ``low_open`` / ``high_open`` exclude the bound; ``inf_ok``: inf
    allowed), source and description."""
    inf_ok = kw.pop("inf_ok", False)
    q = Quantity(unit=unit, low=low, high=high, **kw)
    meta = {"quantity": q, "source": source, "description": description, "inf_ok": inf_ok}
    return field(default=default, metadata=meta)


_POS = {"low_open": True}  # (0, inf)
_CAL = "calibrated against the paper's three targets (docs/model.md, Calibration)"


@dataclass(frozen=True)
class APSParams:
    """Effective parameters of one APS (SI). Geometry defaults: the paper's experimental APS.

    Every numeric field carries its unit, allowed range, source and description in its
    metadata (:meth:`quantity`, :meth:`unit`): the one place they are written. Out-of-range
    values raise a :class:`ParameterError` naming the field, the value and the range.
    """

    l: float = _f(32e-3, "m", 0, math.inf, "paper: 32 mm", "actin thread length", **_POS)
    w0: float = _f(
        20e-3, "m", 0, math.inf, "paper: h_m - 2 t_w - h_ch", "anchor spacing at rest 2 r2'", **_POS
    )
    A_band: float = _f(30e-3, "m", 0, math.inf, "paper: A = 30 mm", "SPA body height", **_POS)
    h_jz: float = _f(2e-3, "m", 0, math.inf, "paper: 2 mm", "junction-zone height", **_POS)
    L_r: float = _f(
        20e-3,
        "m",
        0,
        math.inf,
        "geometry: the anchor span 2 r2' = 20 mm the expansion changes (docs/model.md)",
        "length the expansion stretches (restoring element)",
        **_POS,
    )
    A_r: float = _f(7.3706e-7, "m^2", 0, math.inf, _CAL, "restoring cross-section", **_POS)
    C1: float = _f(0.096e6, "Pa", 0, math.inf, "paper, Yeoh fit of the material", "Yeoh C1", **_POS)
    C2: float = _f(0.0095e6, "Pa", -math.inf, math.inf, "paper, Yeoh fit", "Yeoh C2")
    C3: float = _f(0.0, "Pa", -math.inf, math.inf, "paper, Yeoh fit", "Yeoh C3")
    A_p: float = _f(2.6238e-6, "m^2", 0, math.inf, _CAL, "effective pneumatic area dV/dd", **_POS)
    k_s: float = _f(
        694.00, "N/m", 0, math.inf, _CAL, "series stiffness of an I-band of two thread V's", **_POS
    )
    c_s: float = _f(0.5, "N*s/m", 0, math.inf, "estimate", "damping of a two-V I-band")
    eps_slack: float = _f(
        1e-5, "m", 0, math.inf, "numerical", "slack regularisation length", **_POS
    )
    m_e: float = _f(1e-3, "kg", 0, math.inf, "estimate: outer chamber walls", "expansion mass")
    c_e: float = _f(2.0, "N*s/m", 0, math.inf, "estimate: silicone loss", "expansion damping")
    m_body: float = _f(
        8.6e-3,
        "kg",
        0,
        math.inf,
        "estimate: DragonSkin 30, 1080 kg/m^3, about 8 cm^3 of solid",
        "SPA body mass",
    )
    V0: float = _f(
        4.0e-6,
        "m^3",
        0,
        math.inf,
        "estimate: six chambers a_ch b_ch h_ch = 2.85 cm^3 plus about 1.2 cm^3 of tube",
        "chamber volume at rest",
        **_POS,
    )
    C_tube: float = _f(
        2.0e-9, "m^3/(s*Pa)", 0, math.inf, "estimate: 0.2 l/(s bar)", "tube sonic conductance"
    )
    b_tube: float = _f(
        0.3, "1", 0, 1, "estimate, ISO 6358 typical", "tube critical pressure ratio", high_open=True
    )
    r_lam: float = _f(
        0.999, "1", 0.5, 1, "numerical (0.995..0.999 typical)", "laminar threshold", high_open=True
    )
    tau_heat: float = _f(
        1.0,
        "s",
        0,
        math.inf,
        "estimate: small silicone chamber, order 1 s",
        "heat-exchange time constant of an adiabatic chamber (inf: none)",
        low_open=True,
        inf_ok=True,
    )
    thermal: str = field(
        default="isothermal",
        metadata={"choices": THERMAL, "description": "chamber thermal model"},
    )
    material: str = field(
        default="dragonskin_30", metadata={"description": "Yeoh material of C1..C3 (provenance)"}
    )

    def __post_init__(self) -> None:
        for f in fields(self):
            v = getattr(self, f.name)
            if "choices" in f.metadata:
                if v not in f.metadata["choices"]:
                    raise ParameterError(f.name, v, f"one of {f.metadata['choices']}")
                continue
            if "quantity" not in f.metadata:
                continue
            q = f.metadata["quantity"]
            ok = (
                isinstance(v, int | float)
                and not isinstance(v, bool)
                and (math.isfinite(v) or (v == math.inf and f.metadata["inf_ok"]))
                and q.contains(v)
            )
            if not ok:
                raise q.refuse(f.name, v)
        if self.w0 >= self.l:
            raise ParameterError(
                "w0",
                self.w0,
                f"(0, l = {self.l:g}) m",
                "anchors as wide as the thread: 2 r2' >= l, the thread cannot close",
            )

    @classmethod
    def unit(cls, name: str) -> str:
        """SI unit of a numeric field (``"1"``: dimensionless)."""
        return _field(name).metadata["quantity"].unit

    @classmethod
    def quantity(cls, name: str) -> Quantity:
        """Unit and allowed range of a numeric field."""
        return _field(name).metadata["quantity"]

    @classmethod
    def numeric_fields(cls) -> tuple[str, ...]:
        """Names of the numeric fields (those with a unit)."""
        return tuple(f.name for f in fields(cls) if "quantity" in f.metadata)

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
            L_r=g["h_m"] - 2 * g["t_w"] - g["h_ch"],
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


@functools.cache  # a class's fields do not change; every APS asks for a dozen
def _field(name: str):
    for f in fields(APSParams):
        if f.name == name and "quantity" in f.metadata:
            return f
    raise ParameterError("APSParams field", name, f"one of {APSParams.numeric_fields()}")


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


def aps_parameter(b: Builder, p: APSParams, name: str, source: str | None = None) -> cs.SX:
    """Declare the APSParams field ``name`` as a model parameter with the field's value,
    unit, range (closed at its bounds) and source: the one place they are written."""
    m = _field(name).metadata
    q = m["quantity"]
    return b.parameter(
        name,
        getattr(p, name),
        q.unit,
        m["description"],
        low=q.low if not q.low_open else math.nextafter(q.low, math.inf),
        high=q.high,
        source=source or m["source"],
    )


class YeohSpring(Component):
    """Restoring element of the SPA: energy ``A_r L_r W(1 + d/L_r)`` [J], d = s_b - s_a."""

    def __init__(self, name: str, p: APSParams) -> None:
        super().__init__(name)
        self.p = p

    def build(self, b: Builder) -> None:
        p = self.p
        A_r, L_r = aps_parameter(b, p, "A_r"), aps_parameter(b, p, "L_r")
        src = f"paper, Yeoh fit of material '{p.material}'"
        C1, C2, C3 = (aps_parameter(b, p, k, source=src) for k in ("C1", "C2", "C3"))
        fa, fb = b.port("flange_a", FLANGE), b.port("flange_b", FLANGE)
        lam, energy, force = laws.apply(_yeoh, [fa.s, fb.s, A_r, L_r, C1, C2, C3])
        b.equation(fb.f, force)
        b.equation(fa.f, -force)
        b.output("lambda", lam, "1", "stretch of the restoring element", low=0.0)
        b.output("f", force, "N", "restoring force")
        b.energy("elastic", energy)


def _yeoh(s_a, s_b, A_r, L_r, C1, C2, C3) -> list:
    """Stretch ``1 + (s_b - s_a)/L_r`` [1], energy ``A_r L_r W`` [J] and force on
    ``flange_b`` (its gradient in ``s_b``) [N] of the restoring element."""
    lam = 1.0 + (s_b - s_a) / L_r
    energy = A_r * L_r * yeoh_energy(lam, C1, C2, C3)
    return [lam, energy, cs.gradient(energy, s_b)]


THREAD_DAMPING = ("tension_only", "gated", "none")
"""Damping of an I-band: ``k softplus(e + c/k de/dt)`` (never pushes; nonlinear in the rate,
so the band's ends must be states), ``k softplus(e) + c softplus'(e) de/dt`` (the damping
gated by tautness, linear in the rate: for a massless expansion, whose rate depends on
the tension; it can pull below zero briefly while a band slackens fast), or none."""


class Actin(Component):
    """An I-band: two hooked thread V's (or one, at the chain ends) with a series spring.

    Flanges ``flange_a`` (upper body) and ``flange_b`` (lower body) on the chain axis;
    ``exp_a``/``exp_b``: the expansion flanges of the SPAs whose threads form this
    I-band (present when ``upper``/``lower`` is True). Taut length
    ``L_geo = sum(A/2 + r1(d))`` over those SPAs; stretch ``e = s_b - s_a - L_geo``;
    tension ``T = k softplus(e + (c/k) de/dt)`` with
    ``softplus(e) = (e + sqrt(e^2 + eps^2))/2``: tension only and smooth; taut, it is the
    spring-damper ``k e + c de/dt``; slack, it neither pushes nor damps. ``damping`` is one
    of :data:`THREAD_DAMPING`. ``k_s``, ``c_s`` are those of a band of two
    V's in series; a band of one V (a chain end) has twice the stiffness and damping
    (half the compliance), so a chain of n units has the compliance ``n / k_s``.
    """

    def __init__(
        self, name: str, p: APSParams, upper: bool, lower: bool, damping: str = "tension_only"
    ) -> None:
        super().__init__(name)
        if damping not in THREAD_DAMPING:
            raise ParameterError("damping", damping, f"one of {THREAD_DAMPING}")
        self.p, self.upper, self.lower, self.damping = p, upper, lower, damping

    def build(self, b: Builder) -> None:
        p = self.p
        l, w0, A, k_s, c_s, eps = (
            aps_parameter(b, p, k) for k in ("l", "w0", "A_band", "k_s", "c_s", "eps_slack")
        )
        fa, fb = b.port("flange_a", FLANGE), b.port("flange_b", FLANGE)
        L_geo, L_rest = cs.SX(0), cs.SX(0)
        exps = []
        for side, present in (("exp_a", self.upper), ("exp_b", self.lower)):
            if present:
                fl = b.port(side, FLANGE)
                exps.append(fl)
                L_geo, L_rest, theta = laws.apply(_band_side, [L_geo, L_rest, fl.s, l, w0, A])
                b.output(
                    f"theta_{side[-1]}",
                    theta,
                    "rad",
                    "thread angle, cos(theta) = 2 r2 / l (paper); at its lower bound the thread "
                    "is pulled straight, at its upper bound the anchors meet",
                    low=THETA_MIN_RAD,
                    high=0.5 * math.pi,
                )
        self.rest_length = L_rest  # taut length at zero expansion [m], for start values
        per_v = 2.0 / len(exps)  # two V's in series: k_s; one V alone: 2 k_s
        e = fb.s - fa.s - L_geo
        if self.damping == "none":
            e_rate = cs.SX(0)  # undamped: no rate (the dissipation below is 0, not declared)
        else:  # needs the stretch rate: the band's ends must be masses
            e_rate = b.der_of("e_rate", e, "m/s", "stretch rate of the I-band")
        tension, dissipation, energy = laws.apply(
            _band_tension, [e, e_rate, k_s, c_s, eps], per_v=per_v, damping=self.damping
        )
        if self.damping != "none":
            b.dissipation("damping", dissipation)
        b.equation(fb.f, tension)
        b.equation(fa.f, -tension)
        for fl in exps:  # generalised force on the expansion: T de/dd
            b.equation(fl.f, tension * cs.jacobian(e, fl.s))
        b.output("T", tension, "N", "thread tension (I-band)")
        b.output("e", e, "m", "stretch beyond the taut length (negative: slack)")
        b.output("L_geo", L_geo, "m", "taut length of the I-band")
        b.energy("elastic", energy)


def _band_side(L_geo, L_rest, d, l, w0, A) -> list:
    """One side of an I-band (its SPA's expansion ``d``): the taut and rest lengths with
    that side's ``A/2 + r1`` added, and the thread angle, ``cos(theta) = 2 r2 / l``."""
    cos_theta = cs.fmin(cs.fmax((w0 + d) / l, -1.0), 1.0)
    return [
        L_geo + 0.5 * A + thread_height(d, l, w0),
        L_rest + 0.5 * A + thread_height(0.0, l, w0),
        cs.acos(cos_theta),
    ]


def _band_tension(e, e_rate, k_s, c_s, eps, per_v: float, damping: str) -> list:
    """Tension [N], dissipated power [W] and elastic energy [J] of an I-band of ``per_v``
    times the stiffness ``k_s`` at stretch ``e`` and stretch rate ``e_rate`` (see
    :class:`Actin`)."""
    k = per_v * k_s
    r = cs.sqrt(e**2 + eps**2)
    spring = 0.5 * (e + r)  # softplus(e)
    if damping == "none":
        tension = k * spring
    elif damping == "tension_only":
        # a Kelvin-Voigt band that can only pull: T = k softplus(e + (c/k) de/dt):
        # taut, T = k e + c de/dt; slack, it neither pushes nor damps. The power
        # T de/dt minus the elastic rate k softplus(e) de/dt is >= 0.
        ed = e + c_s / k_s * e_rate
        tension = k * 0.5 * (ed + cs.sqrt(ed**2 + eps**2))
    else:  # "gated": linear in the rate, damping times the softplus slope
        tension = k * spring + per_v * c_s * 0.5 * (1.0 + e / r) * e_rate
    # energy of k softplus: integral of (e + sqrt(e^2 + eps^2))/2 de
    energy = 0.25 * k * (e**2 + e * r + eps**2 * cs.asinh(e / eps))
    return [tension, (tension - k * spring) * e_rate, energy]


class APS(Component):
    """One artificial pneumatic sarcomere: chamber, expansion, restoring element, body.

    Ports: ``port`` (pneumatic, the chamber inlet), ``body`` (chain flange at the SPA
    body centre), ``exp`` (the expansion flange the actins hang on).
    ``quasi_static=True`` drops the expansion inertia (the expansion becomes a first-order
    viscous state); ``massless_body=True`` makes the body a weighted massless node (its
    position an algebraic unknown); ``instant=True`` makes the chamber an
    :class:`~.pneumatic.InstantChamber` (its pressure that of ``port``, no air-mass
    state). After building, ``temperature`` is the chamber air's temperature and
    ``position`` the body's position (symbols, for the parent).
    """

    def __init__(
        self,
        name: str,
        p: APSParams,
        quasi_static: bool = False,
        massless_body: bool = False,
        instant: bool = False,
    ) -> None:
        super().__init__(name)
        self.p, self.quasi_static, self.massless_body = p, quasi_static, massless_body
        self.instant = instant

    def build(self, b: Builder) -> None:
        p = self.p
        ground = b.add(Fixed("ground"))
        if self.instant:
            gas = InstantChamber("chamber", V0=p.V0, A=p.A_p)
        else:
            gas = Chamber("chamber", V0=p.V0, A=p.A_p, thermal=p.thermal, tau_heat=p.tau_heat)
        chamber = b.add(gas)
        self.temperature = gas.temperature
        yeoh = b.add(YeohSpring("yeoh", p))
        if self.quasi_static:
            exp = b.add(ViscousNode("expansion", d=p.c_e))
        else:
            # scales: the wall travels 2-8 mm at up to ~10 mm/s (docs/fmu.md, tolerances)
            exp = b.add(Mass("expansion", m=p.m_e, g=0.0, s_nominal=1e-3, v_nominal=1e-2))
            loss = b.add(Damper("loss", d=p.c_e))
            b.connect(ground.flange, loss.flange_a)
            b.connect(loss.flange_b, exp.flange_a)
        body_c = (
            Node("body", m=p.m_body)
            if self.massless_body
            else Mass("body", m=p.m_body, v_nominal=1e-2)
        )
        body = b.add(body_c)
        self.position = body_c.position
        b.connect(ground.flange, yeoh.flange_a)
        b.connect(yeoh.flange_b, exp.flange_a)
        b.connect(chamber.flange, exp.flange_a)
        b.expose("port", chamber.port)
        b.expose("body", body.flange_a)
        b.expose("exp", exp.flange_a)


FLOW_LAWS = {"iso6358": False, "smooth": True}
"""Flow laws of the feed tubes -> ``smooth`` of :func:`~.pneumatic.iso6358_flow`: the exact
ISO 6358 law with a linear laminar region (plants), or its C1 variant (optimisers)."""


CHAIN_LEVELS = {  # level -> (massless SPA expansion, massless bodies)
    "full": (False, False),
    "quasi_static": (True, False),
    "static_chain": (True, True),
}
"""Fidelity levels of :class:`Myofibril`: all inertias; massless SPA expansion (first
order, viscous; explicit ODE); massless SPA and bodies (undamped threads; the body
positions are algebraic: an index-1 DAE)."""

INSTANT_LEVELS = {"instant_pneumatics": "full", "instant_quasi_static": "quasi_static"}
"""Levels with instant pneumatics -> the :data:`CHAIN_LEVELS` level of their mechanics:
every chamber an :class:`~.pneumatic.InstantChamber` at the manifold's pressure (no
air-mass states, no tubes), which removes the chamber filling modes (0.37 ms, the
stiffest of the chain); see docs/model.md."""

CHAIN_DAMPING = {"full": "tension_only", "quasi_static": "gated", "static_chain": "none"}
"""Thread damping of each level (:data:`THREAD_DAMPING`): the massless expansion of
"quasi_static" puts the band's rate inside the tension, which needs the linear form; the
massless bodies of "static_chain" have no rates."""


class Myofibril(Component):
    """``n`` APS in series, each fed by its own tube from one manifold port.

    Ports: ``port`` (the manifold, pneumatic), ``flange_a`` (top hook, on the frame),
    ``flange_b`` (bottom hook, to the load or the fixture). Output ``length`` [m]:
    ``flange_b.s - flange_a.s``. ``params`` is one APSParams for identical units or a
    list of ``n``. ``level`` is one of :data:`CHAIN_LEVELS`, ``flow_law`` one of
    :data:`FLOW_LAWS`. ``instant=True``: every chamber at the manifold's pressure
    (:class:`~.pneumatic.InstantChamber`, no tubes; :data:`INSTANT_LEVELS`). The bodies
    start at their geometric rest positions below ``flange_a`` (expressions of the thread
    parameters); after building, ``rest_length_expr`` is the geometric length as such an
    expression.
    """

    def __init__(
        self,
        name: str,
        n: int,
        params: APSParams | list[APSParams],
        level: str = "full",
        flow_law: str = "iso6358",
        instant: bool = False,
    ) -> None:
        super().__init__(name)
        if not isinstance(instant, bool):
            raise ParameterError("instant", instant, "True or False")
        self.instant = instant
        if not (isinstance(n, int) and not isinstance(n, bool) and 1 <= n <= 10_000):
            raise ParameterError("n", n, "an integer in [1, 10000]")
        plist = list(params) if isinstance(params, list | tuple) else [params] * n
        if len(plist) != n:
            raise ParameterError("params", len(plist), f"one APSParams or a list of n = {n}")
        if level not in CHAIN_LEVELS:
            raise ParameterError("level", level, f"one of {tuple(CHAIN_LEVELS)}")
        if flow_law not in FLOW_LAWS:
            raise ParameterError("flow_law", flow_law, f"one of {tuple(FLOW_LAWS)}")
        self.n, self.params, self.level, self.flow_law = n, plist, level, flow_law

    def build(self, b: Builder) -> None:
        units = []
        massless_expansion, massless_body = CHAIN_LEVELS[self.level]
        for i, p in enumerate(self.params):
            aps = APS(f"aps{i + 1}", p, massless_expansion, massless_body, self.instant)
            unit = b.add(aps)
            if self.instant:  # no tube: the chamber takes the manifold's pressure
                if i == 0:
                    b.expose("port", unit.port)
                else:
                    b.connect(b.ports["port"], unit.port)
                units.append((aps, unit))
                continue
            tube = b.add(
                Restriction(
                    f"tube{i + 1}",
                    C=p.C_tube,
                    b=p.b_tube,
                    r_lam=p.r_lam,
                    smooth=FLOW_LAWS[self.flow_law],
                    T_b=aps.temperature,
                )
            )
            b.connect(tube.port_b, unit.port)
            if i == 0:
                b.expose("port", tube.port_a)
            else:
                b.connect(b.ports["port"], tube.port_a)
            units.append((aps, unit))
        damping = CHAIN_DAMPING[self.level]
        bands = [Actin("actin0", self.params[0], upper=False, lower=True, damping=damping)]
        top = b.add(bands[0])
        b.connect(top.flange_b, units[0][1].body)
        b.connect(top.exp_b, units[0][1].exp)
        b.expose("flange_a", top.flange_a)
        for i in range(1, self.n):
            bands.append(Actin(f"actin{i}", self.params[i], True, True, damping=damping))
            a = b.add(bands[-1])
            b.connect(a.flange_a, units[i - 1][1].body)
            b.connect(a.exp_a, units[i - 1][1].exp)
            b.connect(a.flange_b, units[i][1].body)
            b.connect(a.exp_b, units[i][1].exp)
        bands.append(Actin(f"actin{self.n}", self.params[-1], True, False, damping=damping))
        end = b.add(bands[-1])
        b.connect(end.flange_a, units[-1][1].body)
        b.connect(end.exp_a, units[-1][1].exp)
        b.expose("flange_b", end.flange_b)
        b.output("length", end.flange_b.s - top.flange_a.s, "m", "myofibril length", low=0.0)
        s = cs.SX(0)  # geometric rest positions below the top hook (taut, no expansion)
        for (aps, _), band in zip(units, bands, strict=False):
            s = s + band.rest_length
            b.set_start(aps.position, s)
        self.rest_length_expr = s + bands[-1].rest_length

    @property
    def rest_length(self) -> float:
        """Geometric rest length ``sum(A + 2 r1')`` [m] (taut threads, no expansion)."""
        return sum(p.unit_length_rest for p in self.params)


class SeriesCopies(Component):
    """``ratio`` identical copies in series of what hangs between ``flange_ref`` and
    ``flange_a``.

    ``s_b - s_ref = ratio (s_a - s_ref)``, ``f_a = -f_b`` and ``f_ref = 0``: every copy
    carries the same force and adds its own stretch. Not passive on its own (the other
    copies do work); the energy function of a model using it counts one copy.
    """

    def __init__(self, name: str, ratio: float) -> None:
        super().__init__(name)
        self.ratio = ratio

    def build(self, b: Builder) -> None:
        r = b.parameter("ratio", self.ratio, "1", "number of copies in series", low=1.0)
        fa, fb = b.port("flange_a", FLANGE), b.port("flange_b", FLANGE)
        ref = b.port("flange_ref", FLANGE)
        b.equation(fb.s, ref.s + r * (fa.s - ref.s))
        b.equation(fa.f, -fb.f)
        b.equation(ref.f, 0.0)


class Alias(Component):
    """Signals of a reduced chain named as the full chain's (``"chamber.p_gauge"`` under
    this component's name): ``signals`` maps a dotted local name to ``(expression, unit,
    description)``, the expression of the model's own variables."""

    def __init__(self, name: str, signals: dict[str, tuple[cs.SX, str, str]]) -> None:
        super().__init__(name)
        self.signals = signals

    def build(self, b: Builder) -> None:
        _add_aliases(b, self.signals)


def _add_aliases(b: Builder, signals: dict[str, tuple[cs.SX, str, str]]) -> None:
    """Declare ``signals`` (dotted names) as outputs of ``b``, nested components on the way."""
    nested: dict[str, dict[str, tuple[cs.SX, str, str]]] = {}
    for key, value in signals.items():
        head, _, rest = key.partition(".")
        if rest:
            nested.setdefault(head, {})[rest] = value
        else:
            b.output(key, *value)
    for head, sub in nested.items():
        b.add(Alias(head, sub))


def chain_end_names(n: int) -> list[str]:
    """The full chain's per-unit signals a reduced chain of ``n`` units also has
    (:func:`chain_end_aliases`), below the chain's name."""
    return ["aps1.chamber.p_gauge", *([f"aps{n}.chamber.p_gauge"] if n > 1 else []), "actin0.T"]


def chain_end_aliases(
    n: int, top_p: cs.SX, bottom_p: cs.SX, top_tension: cs.SX, p_amb: cs.SX
) -> dict[str, tuple[cs.SX, str, str]]:
    """The full chain's names a reduced chain gives its representatives (top first):
    ``aps1`` and ``aps<n>.chamber.p_gauge``, the gauge pressure of the representative
    that stands for the top and the bottom unit (equal at rest; in transients the
    representative's), and ``actin0.T``, the tension at the top hook (``top_tension``)."""
    rep = "gauge pressure of the representative unit that stands for unit"
    values = [(top_p - p_amb, "Pa", f"{rep} 1")]
    if n > 1:
        values.append((bottom_p - p_amb, "Pa", f"{rep} {n}"))
    values.append((top_tension, "N", "tension at the top hook (the top I-band's)"))
    return dict(zip(chain_end_names(n), values, strict=True))


class SymmetricMyofibril(Component):
    """``n`` identical APS reduced to one representative unit (the "symmetric" level).

    All units share one pressure, one expansion and one tension: the representative
    APS (full internal dynamics) carries one unit length ``A + 2 r1(d)`` through one
    two-V I-band (``k_s``, ``c_s``: the chain's n - 1 inner bands and two one-V end bands
    have the compliance ``n / k_s``, one band per unit); :class:`SeriesCopies` of ratio
    ``n`` maps it to the chain end. The bodies are massless; their weight
    ``n m_body g / 2`` (the mean over the chain) acts at the chain end. Ports, the
    ``length`` output and ``flow_law`` as :class:`Myofibril`, the end signals as
    :func:`chain_end_aliases`.

    As a group of :class:`GroupedMyofibril`: ``s_top`` is the start position of
    ``flange_a`` [m] (an expression), and ``end_mass`` [kg] replaces the end's weight by
    a :class:`~.mechanical.Mass` (weight and inertia) of that many kg, or by nothing (0);
    ``n`` may then be fractional (half a group of an odd number of units).
    """

    def __init__(
        self,
        name: str,
        n: int,
        params: APSParams,
        flow_law: str = "iso6358",
        s_top: float | cs.SX = 0.0,
        end_mass: float | None = None,
    ) -> None:
        super().__init__(name)
        if isinstance(n, bool) or not isinstance(n, int | float) or not 1 <= n <= 10_000:
            raise ParameterError("n", n, "a number of units in [1, 10000]")
        if flow_law not in FLOW_LAWS:
            raise ParameterError("flow_law", flow_law, f"one of {tuple(FLOW_LAWS)}")
        self.n, self.p, self.flow_law = n, params, flow_law
        self.s_top, self.end_mass = s_top, end_mass

    def build(self, b: Builder) -> None:
        n, p = self.n, self.p
        aps = APS("aps1", replace(p, m_body=0.0), massless_body=True)
        unit = b.add(aps)
        tube = b.add(
            Restriction(
                "tube1",
                C=p.C_tube,
                b=p.b_tube,
                r_lam=p.r_lam,
                smooth=FLOW_LAWS[self.flow_law],
                T_b=aps.temperature,
            )
        )
        b.connect(tube.port_b, unit.port)
        b.expose("port", tube.port_a)
        band_c = Actin("actin", p, True, True)
        band = b.add(band_c)
        b.connect(band.flange_b, unit.body)
        b.connect(band.exp_a, unit.exp)
        b.connect(band.exp_b, unit.exp)
        b.set_start(aps.position, self.s_top + band_c.rest_length)
        lever = b.add(SeriesCopies("chain", ratio=float(n)))
        b.connect(band.flange_b, lever.flange_a)
        b.connect(band.flange_a, lever.flange_ref)
        self.rest_length_expr = n * band_c.rest_length
        bottom = self.s_top + self.rest_length_expr
        if self.end_mass is None:
            end = b.add(Node("bodies", m=0.5 * n * p.m_body, s_start=bottom))
            b.connect(lever.flange_b, end.flange_a)
        elif self.end_mass > 0:
            end = b.add(Mass("bodies", m=self.end_mass, s_start=bottom))
            b.connect(lever.flange_b, end.flange_a)
        b.expose("flange_a", band.flange_a)
        b.expose("flange_b", lever.flange_b)
        b.output("length", lever.flange_b.s - band.flange_a.s, "m", "myofibril length", low=0.0)
        self.chamber_p = unit.port.potential  # the representative's pressure [Pa]
        self.band_tension = -band.flange_a.flow  # the representative's tension [N]
        if self.end_mass is None:  # the "symmetric" level: the full chain's end names
            env = b.outer(ENVIRONMENT)
            # the band carries the load and half the bodies; the top hook all of them
            top = self.band_tension + 0.5 * n * p.m_body * env["g"]
            names = chain_end_aliases(n, self.chamber_p, self.chamber_p, top, env["p"])
            del names["aps1.chamber.p_gauge"]  # the representative is aps1 itself
            _add_aliases(b, names)

    @property
    def rest_length(self) -> float:
        """Geometric rest length ``n (A + 2 r1')`` [m]."""
        return self.n * self.p.unit_length_rest


class GroupedMyofibril(Component):
    """``n`` identical APS as ``groups`` groups in series (the "grouped" level), each
    group of ``n_g >= 2`` units as two representative half-groups
    (:class:`SymmetricMyofibril` of ``n_g / 2`` units: one pressure, expansion and
    tension each), a group of one unit as itself.

    The weight gradient: the units of a group carry tensions ``T_lo + (k - 1/2) m_body g``,
    ``k = 1..n_g`` (``T_lo``: what hangs below the group), of mean ``T_lo + n_g w / 2``
    and variance ``(n_g^2 - 1) w^2 / 12`` (``w = m_body g``). The group's body mass sits
    at three joints, ``n_g / 2 - d``, ``2 d`` and ``n_g / 2 - d`` body masses (top,
    middle, bottom; ``d = sqrt((n_g^2 - 1) / 12)``), so the two half-groups carry
    ``mean -/+ d w``: the two-point rule with the group's mean and variance, so the
    group's length is exact up to the fourth derivative of a unit's length in its
    tension (a single representative at the mean misses the second: 11 % on a 50 g
    step at n = 30 with three groups, against 1.4 % here). The bodies keep their
    inertia as those joint masses. The bottom joint's mass, :attr:`end_mass` [kg], is
    left to the set-up: it rides on the mass that hangs at the chain end; the top
    one's weight hangs on the frame. The representatives are ``rep1``, ``rep2``, ...
    top first, each with its own tube from the manifold ``port``. Ports, the ``length``
    output and ``flow_law`` as :class:`Myofibril`, the end signals as
    :func:`chain_end_aliases`; cost grows with ``groups``, not with ``n``.
    """

    def __init__(
        self, name: str, n: int, params: APSParams, groups: int, flow_law: str = "iso6358"
    ) -> None:
        super().__init__(name)
        if not (isinstance(groups, int) and 1 <= groups <= n):
            raise ParameterError("groups", groups, f"an integer in [1, n = {n}]")
        self.n, self.p, self.groups, self.flow_law = n, params, groups, flow_law

    @property
    def sizes(self) -> list[int]:
        """Units per group, top first (as equal as possible, the larger groups on top)."""
        q, r = divmod(self.n, self.groups)
        return [q + 1] * r + [q] * (self.groups - r)

    @property
    def segments(self) -> list[tuple[float, float, float]]:
        """Representative units top first: (units it stands for, body masses at its top
        joint, at its bottom joint), in units of ``m_body``."""
        out = []
        for n_g in self.sizes:
            if n_g == 1:
                out.append((1.0, 0.5, 0.5))
                continue
            d = math.sqrt((n_g**2 - 1) / 12)
            out += [(n_g / 2, n_g / 2 - d, d), (n_g / 2, d, n_g / 2 - d)]
        return out

    @staticmethod
    def units(n: int, groups: int) -> int:
        """Representative units (APS models, the cost) of ``n`` units in ``groups``
        groups: two per group of more than one unit."""
        q, r = divmod(n, groups)
        return sum(1 if q_g == 1 else 2 for q_g in [q + 1] * r + [q] * (groups - r))

    @property
    def end_mass(self) -> float:
        """Body mass [kg] the set-up must add to the mass at the chain end."""
        return self.segments[-1][2] * self.p.m_body

    def build(self, b: Builder) -> None:
        segs, m_b = self.segments, self.p.m_body
        s_top: float | cs.SX = 0.0
        prev, reps = None, []
        for k, (size, _, below) in enumerate(segs):
            last = k == len(segs) - 1
            end_mass = 0.0 if last else (below + segs[k + 1][1]) * m_b
            sub = SymmetricMyofibril(
                f"rep{k + 1}", size, self.p, self.flow_law, s_top=s_top, end_mass=end_mass
            )
            grp = b.add(sub)
            if prev is None:
                b.expose("port", grp.port)
                b.expose("flange_a", grp.flange_a)
                top = grp.flange_a
            else:
                b.connect(b.ports["port"], grp.port)
                b.connect(prev.flange_b, grp.flange_a)
            prev = grp
            s_top = s_top + sub.rest_length_expr
            reps.append(sub)
        b.expose("flange_b", prev.flange_b)
        b.output("length", prev.flange_b.s - top.s, "m", "myofibril length", low=0.0)
        self.rest_length_expr = s_top
        env = b.outer(ENVIRONMENT)
        # the top half-group's band carries all but the body mass at the top joint
        top_t = reps[0].band_tension + segs[0][1] * m_b * env["g"]
        p_top, p_bottom = reps[0].chamber_p, reps[-1].chamber_p
        _add_aliases(b, chain_end_aliases(self.n, p_top, p_bottom, top_t, env["p"]))

    @property
    def rest_length(self) -> float:
        """Geometric rest length ``n (A + 2 r1')`` [m]."""
        return self.n * self.p.unit_length_rest


__all__ = [
    "Alias",
    "GroupedMyofibril",
    "APS",
    "APSParams",
    "Actin",
    "FLOW_LAWS",
    "Myofibril",
    "SeriesCopies",
    "SymmetricMyofibril",
    "YeohSpring",
    "chain_end_aliases",
    "chain_end_names",
    "thread_height",
]
