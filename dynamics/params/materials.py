"""Yeoh hyperelastic materials of the paper, and the paper's Yeoh stress law.

Materials are :class:`YeohMaterial` records (coefficients in Pa, density in kg/m^3),
looked up by slug with :func:`get_material`.

Stress law
----------
The paper (Modeling, eq. "cauchy-stress", after Polygerinos et al.) uses the plane-strain
form of the Yeoh energy, principal stretches ``(lambda, 1, 1/lambda)``::

    W(lambda)     = sum_i C_i (lambda^2 + lambda^-2 - 2)^i                 [Pa = J/m^3]
    sigma(lambda) = (lambda - lambda^-3) (2 C1 + 4 C2 (lambda - 1/lambda)^2)   [Pa]

and calls ``sigma`` "cauchyStress". ``sigma`` is ``dW/dlambda``: force per *undeformed*
area, i.e. the nominal (first Piola-Kirchhoff) stress, not the Cauchy (true) stress,
which is ``lambda dW/dlambda`` (:func:`true_cauchy_stress`). We keep the paper's name for
the function and say what it is. The paper drops ``C3`` (it is only non-zero for
Ecoflex 00-30); ``include_c3=True`` adds the third term
``6 C3 (lambda - 1/lambda)^4 (lambda - lambda^-3)``.

With ``C2 < 0`` and no ``C3`` (Ecoflex 00-30 as printed) the stress is not monotone: it
peaks (at lambda = 3.88, sigma = 0.0908 MPa) and falls. :func:`cauchy_stress_inverse`
then works on the monotone branch through ``lambda = 1`` and raises a
:class:`ParameterError` for stresses beyond the peak.
"""

from __future__ import annotations

import difflib
import functools
import math
from dataclasses import dataclass

import numpy as np

from ..errors import ParameterError
from .core import Param, ParameterSet

__all__ = [
    "MATERIALS",
    "YeohMaterial",
    "cauchy_stress",
    "cauchy_stress_inverse",
    "get_material",
    "monotone_branch",
    "strain_energy",
    "stress_slope",
    "true_cauchy_stress",
]

MPA = 1e6


@dataclass(frozen=True)
class YeohMaterial:
    """An incompressible Yeoh material.

    Attributes
    ----------
    name : str
        Trade name, e.g. ``"Dragon Skin 30"``.
    slug : str
        Identifier used in code and scenario files, e.g. ``"dragonskin_30"``.
    C1, C2, C3 : float
        Yeoh coefficients, Pa. ``C1 > 0``; ``C2`` and ``C3`` may be negative or zero.
    density : float
        Mass density, kg/m^3, > 0.
    source : str
        Where the coefficients and the density come from.
    description : str, default ""
        Free text (e.g. what the material is used for here).

    Raises
    ------
    ParameterError
        Non-finite coefficient, ``C1 <= 0`` or ``density <= 0``.
    """

    name: str
    slug: str
    C1: float
    C2: float
    C3: float
    density: float
    source: str
    description: str = ""

    def __post_init__(self) -> None:
        for field in ("C1", "C2", "C3", "density"):
            v = getattr(self, field)
            if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v):
                raise ParameterError(f"{self.slug}.{field}", v, "a finite number")
            object.__setattr__(self, field, float(v))
        if self.C1 <= 0:
            raise ParameterError(f"{self.slug}.C1", self.C1, "(0, inf) Pa", "C1 = mu0/2 > 0")
        if self.density <= 0:
            raise ParameterError(f"{self.slug}.density", self.density, "(0, inf) kg/m^3")

    def params(self) -> ParameterSet:
        """The material as a :class:`ParameterSet` (C1, C2, C3 in Pa; density in kg/m^3)."""
        positive = {"low": 0.0, "low_open": True}
        rows = (  # name, unit, bounds, description
            ("C1", "Pa", positive, "Yeoh coefficient 1 (mu0/2)"),
            ("C2", "Pa", {}, "Yeoh coefficient 2"),
            ("C3", "Pa", {}, "Yeoh coefficient 3 (omitted by the paper)"),
            ("density", "kg/m^3", positive, "mass density"),
        )
        return ParameterSet(
            [
                Param(n, getattr(self, n), unit=u, source=self.source, description=text, **bounds)
                for n, u, bounds, text in rows
            ],
            name=self.slug,
        )


_SMOOTH_ON_DS30 = "density: Smooth-On Dragon Skin 30 data sheet, specific gravity 1.08"

MATERIALS: dict[str, YeohMaterial] = {
    m.slug: m
    for m in (
        YeohMaterial(
            "Dragon Skin 30",
            "dragonskin_30",
            0.096 * MPA,
            0.0095 * MPA,
            0.0,
            1080.0,
            "C1, C2: paper, Results: Experimental Setup (citing Chen et al. 2018); "
            + _SMOOTH_ON_DS30,
            "material of the paper's experimental APS; default",
        ),
        YeohMaterial(
            "Dragon Skin 30 (alternative fit)",
            "dragonskin_30_alt",
            0.1536 * MPA,
            0.0016 * MPA,
            0.0,
            1080.0,
            "C1, C2: second published Yeoh fit (soft-robotics toolbox), see "
            "design/model.md; " + _SMOOTH_ON_DS30,
            "for sensitivity studies against the paper's fit",
        ),
        YeohMaterial(
            "Ecoflex 00-30",
            "ecoflex_00_30",
            0.017 * MPA,
            -0.0002 * MPA,
            0.000023 * MPA,
            1070.0,
            "paper, Modeling: Inflation of the Myosin (citing Steck et al. 2018)",
            "FEM study material; C2 < 0: stress not monotone without C3",
        ),
        YeohMaterial(
            "Elastosil M4601",
            "elastosil_m4601",
            0.11 * MPA,
            0.02 * MPA,
            0.0,
            1130.0,
            "paper, Modeling: Inflation of the Myosin (citing Mosadegh et al. 2014)",
            "FEM study material",
        ),
        YeohMaterial(
            "Smooth-Sil 950",
            "smooth_sil_950",
            0.34 * MPA,
            0.0,
            0.0,
            1240.0,
            "paper, Modeling: Inflation of the Myosin (citing Polygerinos et al. 2019)",
            "FEM study material (neo-Hookean: C2 = C3 = 0)",
        ),
    )
}
"""All known materials by slug."""


def get_material(slug: str | YeohMaterial) -> YeohMaterial:
    """Return the material called ``slug`` (a YeohMaterial is passed through).

    Raises
    ------
    ParameterError
        Unknown slug; the message lists the valid slugs and the closest match.
    """
    if isinstance(slug, YeohMaterial):
        return slug
    try:
        return MATERIALS[slug]
    except (KeyError, TypeError):
        close = difflib.get_close_matches(str(slug), list(MATERIALS), n=2, cutoff=0.5)
        hint = "unknown material"
        if close:
            hint += "; did you mean " + " or ".join(repr(c) for c in close) + "?"
        raise ParameterError("material", slug, "one of " + ", ".join(MATERIALS), hint) from None


# --------------------------------------------------------------------------------------
# Yeoh plane-strain stress law
# --------------------------------------------------------------------------------------
def _coefficients(material: YeohMaterial, include_c3: bool) -> tuple[float, float, float]:
    return material.C1, material.C2, (material.C3 if include_c3 else 0.0)


def _stretch(lam: object) -> np.ndarray:
    arr = np.asarray(lam, dtype=float)
    if not np.all(np.isfinite(arr)) or np.any(arr <= 0):
        bad = arr[~(np.isfinite(arr) & (arr > 0))].ravel()[0]
        raise ParameterError("lambda", float(bad), "(0, inf) 1", "stretch must be positive")
    return arr


def _out(x: np.ndarray, like: object):
    return float(x) if np.ndim(like) == 0 else x


def _sigma(lam: np.ndarray, c1: float, c2: float, c3: float) -> np.ndarray:
    d = (lam - 1.0 / lam) ** 2
    return (lam - lam**-3) * (2.0 * c1 + 4.0 * c2 * d + 6.0 * c3 * d * d)


def _slope(lam: np.ndarray, c1: float, c2: float, c3: float) -> np.ndarray:
    f = lam - lam**-3
    df = 1.0 + 3.0 * lam**-4
    u = lam - 1.0 / lam
    d = u * u
    dd = 2.0 * u * (1.0 + lam**-2)
    g = 2.0 * c1 + 4.0 * c2 * d + 6.0 * c3 * d * d
    dg = (4.0 * c2 + 12.0 * c3 * d) * dd
    return df * g + f * dg


def yeoh_energy(lam, c1, c2, c3):
    """Plane-strain Yeoh energy density [J/m^3] from plain arithmetic, so that the same
    expression serves numpy arrays and CasADi symbols (the dynamic model's restoring
    element). ``x = lam^2 + lam^-2 - 2 = I1 - 3``; coefficients in Pa."""
    x = lam**2 + lam**-2 - 2.0
    return c1 * x + c2 * x**2 + c3 * x**3


def strain_energy(lam: object, material: YeohMaterial, *, include_c3: bool = False):
    """Plane-strain Yeoh strain energy density ``W(lambda)``, Pa (J/m^3).

    ``W = C1 x + C2 x^2 (+ C3 x^3)`` with ``x = lambda^2 + lambda^-2 - 2 = I1 - 3`` for the
    principal stretches ``(lambda, 1, 1/lambda)`` (paper, eq. "cauchy-stress", first line).

    Parameters
    ----------
    lam : float or array_like
        Stretch, dimensionless, > 0.
    material : YeohMaterial
        Coefficients C1, C2, C3 in Pa.
    include_c3 : bool, default False
        Add the C3 term (the paper omits it).
    """
    arr = _stretch(lam)
    return _out(yeoh_energy(arr, *_coefficients(material, include_c3)), lam)


def cauchy_stress(lam: object, material: YeohMaterial, *, include_c3: bool = False):
    """The paper's "cauchyStress": ``sigma = dW/dlambda``, Pa (a *nominal* stress).

    ``sigma = (lambda - lambda^-3)(2 C1 + 4 C2 (lambda - 1/lambda)^2)`` exactly as printed
    (paper, eq. "cauchy-stress"); with ``include_c3`` the term
    ``6 C3 (lambda - 1/lambda)^4`` is added inside the second bracket.

    Parameters
    ----------
    lam : float or array_like
        Stretch, dimensionless, > 0.
    material : YeohMaterial
        Coefficients in Pa.
    include_c3 : bool, default False
        Add the C3 term (the paper omits it).

    Returns
    -------
    float or ndarray
        Force per undeformed area, Pa.
    """
    arr = _stretch(lam)
    return _out(_sigma(arr, *_coefficients(material, include_c3)), lam)


def true_cauchy_stress(lam: object, material: YeohMaterial, *, include_c3: bool = False):
    """True (Cauchy) stress of the same plane-strain state, ``lambda dW/dlambda``, Pa."""
    arr = _stretch(lam)
    return _out(arr * _sigma(arr, *_coefficients(material, include_c3)), lam)


def stress_slope(lam: object, material: YeohMaterial, *, include_c3: bool = False):
    """Derivative ``d sigma / d lambda`` of :func:`cauchy_stress`, Pa."""
    arr = _stretch(lam)
    return _out(_slope(arr, *_coefficients(material, include_c3)), lam)


@functools.lru_cache(maxsize=64)
def _branch(c1: float, c2: float, c3: float) -> tuple[float, float]:
    """Stretches bounding the monotone branch of sigma through lambda = 1."""

    def first_turn(grid: np.ndarray) -> float | None:
        s = _slope(grid, c1, c2, c3)
        bad = np.nonzero(s <= 0)[0]
        if bad.size == 0:
            return None
        i = int(bad[0])
        from scipy.optimize import brentq  # here: importing it costs 0.3 s of CLI start-up

        return brentq(lambda x: float(_slope(np.array(x), c1, c2, c3)), grid[i - 1], grid[i])

    hi = first_turn(1.0 + np.geomspace(1e-6, 1e4, 4000))
    lo = first_turn(1.0 - np.geomspace(1e-6, 1.0 - 1e-4, 4000))
    return (0.0 if lo is None else lo), (math.inf if hi is None else hi)


def monotone_branch(
    material: YeohMaterial, *, include_c3: bool = False
) -> tuple[float, float, float, float]:
    """Bounds of the monotone branch of :func:`cauchy_stress` through ``lambda = 1``.

    Returns
    -------
    lam_lo, lam_hi : float
        Stretch bounds, dimensionless (0 and inf when sigma is monotone everywhere).
    sigma_lo, sigma_hi : float
        Stress bounds, Pa (-inf / inf when unbounded).
    """
    c = _coefficients(material, include_c3)
    lam_lo, lam_hi = _branch(*c)
    s_lo = -math.inf if lam_lo == 0.0 else float(_sigma(np.array(lam_lo), *c))
    s_hi = math.inf if math.isinf(lam_hi) else float(_sigma(np.array(lam_hi), *c))
    return lam_lo, lam_hi, s_lo, s_hi


def cauchy_stress_inverse(stress: object, material: YeohMaterial, *, include_c3: bool = False):
    """Inverse of :func:`cauchy_stress` on its monotone branch: stretch for a stress.

    Vectorised bracketing and bisection to machine precision (robust, no starting guess).

    Parameters
    ----------
    stress : float or array_like
        Nominal stress, Pa (finite; negative values give ``lambda < 1``).
    material : YeohMaterial
        Coefficients in Pa.
    include_c3 : bool, default False
        Use the C3 term (the paper omits it).

    Returns
    -------
    float or ndarray
        Stretch ``lambda``, dimensionless, same shape as ``stress``.

    Raises
    ------
    ParameterError
        Non-finite stress, or a stress beyond the peak of a non-monotone law
        (Ecoflex 00-30 without C3): the message gives the reachable range.
    """
    s = np.asarray(stress, dtype=float)
    if not np.all(np.isfinite(s)):
        raise ParameterError("stress", float(s[~np.isfinite(s)].ravel()[0]), "a finite number")
    c = _coefficients(material, include_c3)
    lam_lo, lam_hi, s_lo, s_hi = monotone_branch(material, include_c3=include_c3)
    outside = (s > s_hi) | (s < s_lo)
    if np.any(outside):
        worst = float(s[outside].ravel()[0])
        raise ParameterError(
            "stress",
            worst,
            f"[{s_lo:.6g}, {s_hi:.6g}] Pa for {material.slug}"
            + ("" if include_c3 else " without C3"),
            f"no stretch gives this stress: the Yeoh curve turns at lambda = "
            f"{lam_hi if worst > 0 else lam_lo:.4g}",
        )
    flat = s.ravel()
    pos = flat >= 0
    lo = np.where(pos, 1.0, max(lam_lo, 0.0))
    hi = np.where(pos, lam_hi, 1.0)
    # open ends: expand the bracket geometrically until it holds the root
    if math.isinf(lam_hi):
        hi = np.where(pos, 2.0, hi)
        for _ in range(2000):
            grow = pos & (_sigma(hi, *c) < flat)
            if not grow.any():
                break
            hi = np.where(grow, hi * 2.0, hi)
    if lam_lo == 0.0:
        lo = np.where(pos, lo, 0.5)
        for _ in range(2000):
            shrink = ~pos & (_sigma(lo, *c) > flat)
            if not shrink.any():
                break
            lo = np.where(shrink, lo * 0.5, lo)
    for _ in range(200):
        mid = 0.5 * (lo + hi)
        below = _sigma(mid, *c) < flat
        lo = np.where(below, mid, lo)
        hi = np.where(below, hi, mid)
        if np.all(hi - lo <= 4.0 * np.finfo(float).eps * hi):
            break
    lam = np.where(flat == 0.0, 1.0, 0.5 * (lo + hi)).reshape(s.shape)
    return _out(lam, stress)
