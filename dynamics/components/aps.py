"""The artificial pneumatic sarcomere (APS): its parameters, its components and the I-band.

Coordinates (see docs/model.md for the derivation and assumptions):

* chain axis ``s`` [m], pointing down (along gravity); the frame hook is at s = 0;
* SPA expansion ``d`` [m]: increase of the anchor spacing ``2 r2 = 2 r2' + d`` of the
  actin threads (both junction zones together).

An APS holds a chamber (air, volume ``V0 + A_p d``), the expansion degree of freedom
(effective mass, viscous loss), the Yeoh restoring element and the SPA body (a mass on
the chain axis). Between neighbouring bodies hang :class:`Actin` elements: two hooked
thread "V"s whose taut height ``r1(d)`` follows from ``r1^2 + r2^2 = (l/2)^2``, with a
series compliance and a smoothly regularised slack. Every coupling force derives from
an energy, so ``p dV`` work, elastic energy and gravity balance exactly. The chains of
units at each fidelity level are composed in :mod:`.chains`.
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
from .mechanical import Damper, Fixed, Mass, Node, ViscousNode
from .pneumatic import THERMAL, Chamber, InstantChamber


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
    k_thread: float = _f(
        5e3,
        "N/m",
        0,
        math.inf,
        "estimate: the paper's cotton thread, about 10 N at break at about 6 % strain over "
        "l = 32 mm; at least k_s / (2 sin^2 theta') = 569 N/m (a V's calibrated "
        "stiffness 2 k_s taken as its thread's alone)",
        "axial stiffness of one thread (the end stop when it is pulled straight)",
        **_POS,
    )
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


THREAD_STRAIN_MAX = 0.06
"""Largest axial strain of a thread pulled straight [1] (estimate: cotton thread breaks
at 5-10 % elongation): the upper bound of the ``strain`` outputs of :class:`Actin`."""

STOP_LENGTH = 1e-4
"""Length scale [m] over which a thread goes over onto its end stop (numerical, about
the stretch ``1 N / k_thread`` at the expansion force's scale): its stretch is
``c (s(u) - s(-5))``, ``s`` the softplus ``(u + sqrt(u^2 + 1)) / 2`` of
``u = (w0 + d - l) / c``, from 5 c before straight on (0 before: the bent thread's
geometry exactly). A loaded V then stays a V near straight instead of locking straight
(docs/model.md, "End stop")."""

_STOP_FROM = 5.0  # in STOP_LENGTH before straight: where the stretch begins


def thread_stretch(d: cs.SX, l: cs.SX, w0: cs.SX) -> cs.SX:
    """Stretch [m] of one thread whose anchors are ``w0 + d`` apart: exactly 0 while it is
    bent (more than ``5 c`` short of straight), then a smooth ramp onto ``w0 + d - l``
    that stays above it (so the V keeps a height, :func:`thread_height`); ``c`` is
    :data:`STOP_LENGTH`."""
    u = (w0 + d - l) / STOP_LENGTH
    s0 = 0.5 * (math.sqrt(_STOP_FROM**2 + 1.0) - _STOP_FROM)  # softplus(-5)
    ramp = STOP_LENGTH * (0.5 * (u + cs.sqrt(u**2 + 1.0)) - s0)
    return cs.if_else(u > -_STOP_FROM, ramp, 0.0)


def thread_height(d: cs.SX, l: cs.SX, w0: cs.SX, stretch: cs.SX | None = None) -> cs.SX:
    """Taut height ``r1`` [m] of one thread V for expansion ``d`` [m]: the legs of the
    thread, ``l`` long plus its ``stretch`` (default :func:`thread_stretch`), over the
    anchors' half-span ``r2 = (w0 + d) / 2``.

    Floored at 1e-4 l (a thread stretched far beyond its breaking strain).
    """
    r2 = 0.5 * (w0 + d)
    half = 0.5 * (l + (thread_stretch(d, l, w0) if stretch is None else stretch))
    return cs.sqrt(cs.fmax(half**2 - r2**2, (1e-4 * l) ** 2))


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
        l, w0, A, k_s, c_s, eps, k_t = (
            aps_parameter(b, p, k)
            for k in ("l", "w0", "A_band", "k_s", "c_s", "eps_slack", "k_thread")
        )
        fa, fb = b.port("flange_a", FLANGE), b.port("flange_b", FLANGE)
        L_geo, L_rest = cs.SX(0), cs.SX(0)
        exps, stops = [], []
        for side, present in (("exp_a", self.upper), ("exp_b", self.lower)):
            if present:
                fl = b.port(side, FLANGE)
                exps.append(fl)
                L_geo, L_rest, theta, dr1, strain, stop_energy, stop_force = laws.apply(
                    _band_side, [L_geo, L_rest, fl.s, l, w0, A, k_t]
                )
                b.output(
                    f"theta_{side[-1]}",
                    theta,
                    "rad",
                    "thread angle, cos(theta) = 2 r2 / l (paper); 0: the thread pulled "
                    "straight, at its upper bound the anchors meet",
                    low=0.0,
                    high=0.5 * math.pi,
                )
                b.output(
                    f"strain_{side[-1]}",
                    strain,
                    "1",
                    "axial strain of the thread pulled straight (the end stop; 0 while it is "
                    "bent); at its upper bound the thread breaks",
                    low=0.0,
                    high=THREAD_STRAIN_MAX,
                )
                stops.append((dr1, stop_energy, stop_force))
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
        for fl, (dr1, _, stop_force) in zip(exps, stops, strict=True):
            # generalised force on the expansion: T de/dd = -T dr1/dd, and the thread's stop
            b.equation(fl.f, tension * -dr1 + stop_force)
        b.output("T", tension, "N", "thread tension (I-band)")
        b.output("e", e, "m", "stretch beyond the taut length (negative: slack)")
        b.output("L_geo", L_geo, "m", "taut length of the I-band")
        b.energy("elastic", sum((u for _, u, _ in stops), energy))


def _band_side(L_geo, L_rest, d, l, w0, A, k) -> list:
    """One side of an I-band (its SPA's expansion ``d``): the taut and rest lengths with
    that side's ``A/2 + r1`` added, the thread angle, ``cos(theta) = 2 r2 / l``,
    ``dr1/dd``, and the thread's end stop (stiffness ``k`` [N/m]): its strain
    ``delta / l`` [1] at the stretch ``delta`` of :func:`thread_stretch`, energy
    ``k delta^2 / 2`` [J] and force on the expansion [N] (all exactly 0 while the thread
    is bent)."""
    cos_theta = cs.fmin(cs.fmax((w0 + d) / l, -1.0), 1.0)
    delta = thread_stretch(d, l, w0)
    r1 = thread_height(d, l, w0, delta)
    return [
        L_geo + 0.5 * A + r1,
        L_rest + 0.5 * A + thread_height(0.0, l, w0),
        cs.acos(cos_theta),
        cs.jacobian(r1, d),
        delta / l,
        0.5 * k * delta**2,
        k * delta * cs.jacobian(delta, d),
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


__all__ = [
    "APS",
    "APSParams",
    "Actin",
    "THREAD_DAMPING",
    "YeohSpring",
    "THREAD_STRAIN_MAX",
    "aps_parameter",
    "STOP_LENGTH",
    "thread_height",
    "thread_stretch",
]
