"""Geometry of the artificial pneumatic sarcomere (APS): the paper's two parameter sets.

Symbols follow the paper (Fig. "geometry"): a soft pneumatic actuator (SPA, the
"myosin") of three chambers in a row (outer, middle, outer), each ``2 t_w + h_ch`` high,
joined by two junction zones of height ``h_jz``. Two actin threads of length ``l`` are
anchored in the middle of the outer chambers.

``h_m`` is **derived**: ``h_m = 3 (2 t_w + h_ch) + 2 h_jz``. For the experimental APS this
gives the 28 mm the paper states (the stated value is checked against the rule when the
set is built); overriding ``t_w``, ``h_ch`` or ``h_jz`` updates ``h_m``, and overriding
``h_m`` itself is refused. The paper also defines ``h_m = 2 r2' + 2 t_w + h_ch``, so the
anchor spacing at rest is ``2 r2' = h_m - 2 t_w - h_ch`` (20 mm); the cross check
:func:`check_anchors_fit_thread` requires ``2 r2' < l``.

Two sets:

* :func:`experimental_geometry` - the APS built and tested (paper, Results:
  Experimental Setup), with thread (``l``) and A-band (``A``).
* :func:`fem_geometry` - the SPA of the paper's FEM study (Modeling: Inflation of the
  Myosin). It has no thread: ``l`` and ``A`` are absent, so only the SPA force
  (``F_SPA``) can be evaluated with it. ``h_ch`` is not stated in the paper; the default
  :data:`FEM_H_CH_ESTIMATE_M` = 6.85 mm is our estimate that reproduces Table 1.
"""

from __future__ import annotations

from collections.abc import Mapping

from ..errors import ParameterError
from ..units import to_si
from .core import Derived, Param, ParameterSet

__all__ = [
    "FEM_H_CH_ESTIMATE_M",
    "FEM_T_W_OVER_H_CH",
    "anchor_spacing",
    "check_anchors_fit_thread",
    "experimental_geometry",
    "fem_geometry",
    "myosin_height",
]

MM = 1e-3

EXPERIMENTAL_SOURCE = "paper, Results: Experimental Setup"
FEM_SOURCE = "paper, Modeling: Inflation of the Myosin (FEM model)"

FEM_T_W_OVER_H_CH: tuple[float, ...] = (1 / 5, 1 / 4, 1 / 3, 1 / 2, 1.0, 3 / 2)
"""Wall-thickness to chamber-height ratios of the paper's FEM study (dimensionless)."""

FEM_H_CH_ESTIMATE_M: float = 6.85e-3
"""Chamber height of the FEM model, m. Not stated in the paper. Estimated: 6.85 mm
minimises the largest relative error of the paper's own analytical model against the
analytical column of Table 1 (errors -0.9 %, -2.0 %, +2.0 % for Ecoflex 00-30,
Elastosil M4601, Smooth-Sil 950; see docs/paper.md). 7 mm gives +0.9 %, -0.2 %, +4.0 %."""


def _length(name: str, value_m: float, source: str, description: str) -> Param:
    return Param(
        name=name,
        value=value_m,
        unit="m",
        low=0.0,
        low_open=True,
        source=source,
        description=description,
    )


def myosin_height(values: Mapping[str, float]) -> float:
    """Height of the SPA at rest, m: ``h_m = 3 (2 t_w + h_ch) + 2 h_jz``.

    Parameters
    ----------
    values : mapping
        SI values of ``t_w``, ``h_ch``, ``h_jz`` (m).
    """
    return 3.0 * (2.0 * values["t_w"] + values["h_ch"]) + 2.0 * values["h_jz"]


def anchor_spacing(values: Mapping[str, float]) -> float:
    """Distance between the two thread anchors at rest, m: ``2 r2' = h_m - 2 t_w - h_ch``.

    From the paper's definition ``h_m = 2 r2' + 2 t_w + h_ch`` (Modeling: Kinematic
    Analysis): the anchors sit in the middle of the outer chambers.
    """
    return values["h_m"] - 2.0 * values["t_w"] - values["h_ch"]


def check_anchors_fit_thread(values: Mapping[str, float]) -> None:
    """Cross check: the anchors must be closer than the thread is long, ``2 r2' < l``.

    Skipped when the set has no thread (``l`` absent).

    Raises
    ------
    ParameterError
        Naming ``h_m``, ``t_w``, ``h_ch``, ``l``, the value of ``2 r2'`` and ``l``.
    """
    if "l" not in values:
        return
    span = anchor_spacing(values)
    length = values["l"]
    if not span < length:
        raise ParameterError(
            "h_m, t_w, h_ch, l",
            f"2 r2' = h_m - 2 t_w - h_ch = {span / MM:.6g} mm",
            f"2 r2' < l = {length / MM:.6g} mm",
            "the thread anchors are wider apart than the thread is long",
        )


_H_M_RULE = Derived(
    fn=myosin_height, formula="3 (2 t_w + h_ch) + 2 h_jz", inputs=("t_w", "h_ch", "h_jz")
)


def experimental_geometry() -> ParameterSet:
    """The APS the paper built and tested (all lengths in m).

    A = 30, h_m = 28 (derived, checked), a_ch = 9.5, b_ch = 10, a_hz = 6, b_hz = 15,
    h_jz = 2, t_w = 1.5, h_ch = 5, l = 32 (mm); source: paper, Results: Experimental Setup.

    Returns
    -------
    ParameterSet
        Named ``"experimental_geometry"``, with the cross check
        :func:`check_anchors_fit_thread`.

    Examples
    --------
    >>> g = experimental_geometry()
    >>> round(g["l"] * 1e3, 6), round(g["h_m"] * 1e3, 6)
    (32.0, 28.0)
    """
    s = EXPERIMENTAL_SOURCE
    params = [
        _length("A", 30 * MM, s, "length of the A-band (SPA extent along the myofibril)"),
        _length("h_m", 28 * MM, s, "height of the myosin (SPA) at rest, across the fibre"),
        _length("a_ch", 9.5 * MM, s, "length of an inner channel (chamber)"),
        _length("b_ch", 10 * MM, s, "width of an inner channel (chamber)"),
        _length("a_hz", 6 * MM, s, "length of the H-zone cross-section"),
        _length("b_hz", 15 * MM, s, "width of the H-zone cross-section"),
        _length("h_jz", 2 * MM, s, "height of a junction zone (distance between chambers)"),
        _length("t_w", 1.5 * MM, s, "thickness of the chamber walls"),
        _length("h_ch", 5 * MM, s, "height of an inner channel (chamber)"),
        _length("l", 32 * MM, s, "length of an actin thread (inextensible)"),
    ]
    return ParameterSet(
        params,
        checks=(check_anchors_fit_thread,),
        derived={"h_m": _H_M_RULE},
        name="experimental_geometry",
    )


def fem_geometry(
    t_w_over_h_ch: float | str = 1 / 3, h_ch: float | str = FEM_H_CH_ESTIMATE_M
) -> ParameterSet:
    """The SPA of the paper's FEM study (no thread; all lengths in m).

    a_ch = b_ch = 14, a_hz = 6, b_hz = 20, h_jz = 3 (mm) from the paper's FEM section;
    ``t_w = t_w_over_h_ch * h_ch``; ``h_m`` derived as in :func:`experimental_geometry`.
    The set has no ``l`` and no ``A``: the FEM study models the SPA alone, so only the
    SPA force can be computed from it (``paper_static`` then returns no thread outputs).
    ``t_w`` is stored as a length: overriding ``h_ch`` later with ``with_overrides`` does
    not rescale it; call ``fem_geometry(ratio, h_ch)`` to change both together.

    Parameters
    ----------
    t_w_over_h_ch : float or str, default 1/3
        Wall thickness over chamber height, dimensionless, > 0. The paper's FEM values
        are :data:`FEM_T_W_OVER_H_CH` (1/5, 1/4, 1/3, 1/2, 1, 3/2).
    h_ch : float or str, default FEM_H_CH_ESTIMATE_M = 6.85e-3 m
        Chamber height, m (or a string such as ``"7 mm"``). Not stated in the paper;
        the default is estimated so that the paper's model reproduces Table 1.

    Returns
    -------
    ParameterSet
        Named ``"fem_geometry"``.

    Raises
    ------
    ParameterError
        Non-positive ratio or chamber height, or a wrong unit.
    """
    ratio = Param(
        "t_w_over_h_ch",
        to_si(t_w_over_h_ch, "1", "t_w_over_h_ch"),
        low=0.0,
        low_open=True,
        source=FEM_SOURCE,
        description="wall thickness over chamber height",
    ).value
    hch = Param(
        "h_ch",
        to_si(h_ch, "m", "h_ch"),
        unit="m",
        low=0.0,
        low_open=True,
        source="argument of fem_geometry",
    ).value
    s = FEM_SOURCE
    tw = ratio * hch
    if hch == FEM_H_CH_ESTIMATE_M:
        hch_source = "estimated: reproduces Table 1 (not stated in the paper)"
    else:
        hch_source = "user value (not stated in the paper)"
    params = [
        _length(
            "h_m",
            myosin_height({"t_w": tw, "h_ch": hch, "h_jz": 3 * MM}),
            s,
            "height of the myosin (SPA) at rest",
        ),
        _length("a_ch", 14 * MM, s, "length of an inner channel (chamber)"),
        _length("b_ch", 14 * MM, s, "width of an inner channel (chamber)"),
        _length("a_hz", 6 * MM, s, "length of the H-zone cross-section"),
        _length("b_hz", 20 * MM, s, "width of the H-zone cross-section"),
        _length("h_jz", 3 * MM, s, "height of a junction zone (distance between chambers)"),
        _length(
            "t_w", tw, f"t_w = {ratio:.6g} h_ch (FEM ratio, {s})", "thickness of the chamber walls"
        ),
        _length("h_ch", hch, hch_source, "height of an inner channel (chamber)"),
    ]
    return ParameterSet(
        params,
        checks=(check_anchors_fit_thread,),
        derived={"h_m": _H_M_RULE},
        name="fem_geometry",
    )
