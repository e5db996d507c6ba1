"""Chains of APS units: the myofibril of each fidelity level (see docs/model.md).

:class:`Myofibril` is ``n`` units in series (the "full", "quasi_static", "static_chain"
and instant levels), :class:`SymmetricMyofibril` one representative unit for ``n``
identical ones, :class:`GroupedMyofibril` groups of two representative half-groups; the
reduced chains name their end signals as the full chain does (:func:`chain_end_aliases`).
"""

from __future__ import annotations

import math
from dataclasses import replace

import casadi as cs

from ..errors import ParameterError
from ..modeling.component import Builder, Component
from ..modeling.ports import FLANGE
from .aps import APS, Actin, APSParams
from .environment import ENVIRONMENT
from .mechanical import Mass, Node
from .pneumatic import Restriction

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


def _tube(b: Builder, name: str, p: APSParams, aps: APS, unit, flow_law: str):
    """Feed ``unit`` (the built ``aps``) through its tube ``name``, an ISO 6358 restriction
    of ``p``'s tube parameters; returns the tube's free (supply) port."""
    smooth = FLOW_LAWS[flow_law]
    tube = b.add(
        Restriction(name, C=p.C_tube, b=p.b_tube, r_lam=p.r_lam, smooth=smooth, T_b=aps.temperature)
    )
    b.connect(tube.port_b, unit.port)
    return tube.port_a


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
                port = unit.port
            else:
                port = _tube(b, f"tube{i + 1}", p, aps, unit, self.flow_law)
            if i == 0:
                b.expose("port", port)
            else:
                b.connect(b.ports["port"], port)
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
        b.expose("port", _tube(b, "tube1", p, aps, unit, self.flow_law))
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
    "CHAIN_DAMPING",
    "CHAIN_LEVELS",
    "FLOW_LAWS",
    "GroupedMyofibril",
    "INSTANT_LEVELS",
    "Myofibril",
    "SeriesCopies",
    "SymmetricMyofibril",
    "chain_end_aliases",
    "chain_end_names",
]
