"""The paper's static model, exactly as printed: the "paper" fidelity level.

This module evaluates the closed-form model of the source paper (Modeling: Inflation of
the Myosin, Output Force; Kinematic Analysis) with every known inconsistency exposed as
an explicit, documented switch of :class:`PaperOptions`. The defaults reproduce the
printed equations; :meth:`PaperOptions.corrected` applies the documented corrections.
See ``docs/paper.md`` for the numbers behind each switch.

Equations (SI inside; pressure ``P`` is gauge, Pa)
---------------------------------------------------
* wall factor ``K = h_ch / (2 t_w)`` if ``t_w < h_ch / 4`` (thin-walled), else
  ``K = 1 + h_ch^2 / (2 t_w (t_w + h_ch))``; wall stress ``sigma_w = P K``;
* ``F_e,wall = 2 sigma_w a_ch b_ch`` (eq. force-h-zone);
* ``lambda_jz = cauchyStress^-1(F_e,wall / (a_hz b_hz))`` (eq. cauchy-stress-inverse);
* ``c_m = -2.49 t_w/h_ch - 6.101 P[MPa] + 11.457`` (eq. adjustment-coeff; P in MPa);
* ``F_e = c_m P pi a_ch (lambda_jz h_jz + h_ch + 2 t_w)`` (eq. expansion-force-final);
* ``F_r = cauchyStress(lambda_jz) a_hz b_hz``; ``F_SPA = F_e - F_r`` (eq. spa-force);
* ``F_contr = F_SPA tan(theta)``, ``theta = arccos(span / l)`` (eq. contraction-force);
* kinematics: ``r1^2 + r2^2 = (l/2)^2`` with ``2 r2 = h_m - 2 t_w - h_ch`` (plus the
  junction-zone growth ``2 (lambda_jz - 1) h_jz``), ``L_mf = n (A + 2 r1)``.

Force scale
-----------
In any consistent unit system the printed force equations give ``F_SPA = 314 N`` at
0.1 MPa for the experimental APS, against 0.315 N measured. All of the paper's reported
forces (Table 1, the isometric experiment) equal the printed expressions times 1e-3.
``PaperOptions.force_scale = 1e-3`` multiplies *every* force (``F_e,wall``, ``F_e``,
``F_r``, ``F_SPA``, ``F_contr``) and nothing else: ``lambda_jz``, ``K``, ``sigma_w``,
``c_m`` and ``theta`` are unit-free or do not depend on the slip. The reading that gives
exactly this factor: forces evaluated with stress in kPa and lengths in m come out in
kN (1 kPa m^2 = 1 kN) and were reported as N, while ``c_m`` was fitted with P in MPa.
Scaling ``F_e`` (or ``c_m``) alone cannot work: ``F_r`` is 43.4 N at 0.1 MPa and would
make ``F_SPA`` negative.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, fields

import numpy as np
from scipy.optimize import brentq
from scipy.special import ellipe

from .errors import ParameterError
from .params.ambient import Ambient
from .params.core import ParameterSet
from .params.materials import (
    YeohMaterial,
    cauchy_stress,
    cauchy_stress_inverse,
    get_material,
)

__all__ = [
    "PaperOptions",
    "PaperResult",
    "max_length_ratio",
    "myofibril_length",
    "paper_static",
    "rest_length",
    "theta_rest",
    "wall_factor",
]

MPA = 1e6
_CM_PRESSURE_UNITS = {"MPa": 1e6, "kPa": 1e3, "bar": 1e5, "Pa": 1.0}
_THETA = ("printed", "corrected")
_KINEMATICS = ("triangle", "ellipse", "ellipse_corrected")
_REST_KINEMATICS = (*_KINEMATICS, "band_ratio")


# --------------------------------------------------------------------------------------
# Options and result
# --------------------------------------------------------------------------------------
@dataclass(frozen=True)
class PaperOptions:
    """Switches of the paper model; the defaults are the equations as printed.

    Attributes
    ----------
    force_scale : float, default 1.0
        Factor applied to every force output, dimensionless, > 0. ``1.0`` = as printed
        (forces about 1000x too large); ``1e-3`` = the documented unit correction, which
        reproduces Table 1 and the measured 0.315 N.
    theta : {"printed", "corrected"}, default "printed"
        Thread angle. ``"printed"``: ``cos(theta) = (2 t_w + h_ch + 2 lambda_jz h_jz)/l``
        (67.98 deg at rest for the experimental APS, one chamber short).
        ``"corrected"``: ``cos(theta) = (h_m - 2 t_w - h_ch + 2 (lambda_jz - 1) h_jz)/l``
        = ``2 r2 / l`` (51.32 deg at rest, the angle the paper states).
    kinematics : {"triangle", "ellipse", "ellipse_corrected"}, default "triangle"
        Thread shape giving ``r1`` from ``r2``. ``"triangle"``: the two legs of a taut
        V, ``r1^2 + r2^2 = (l/2)^2`` (what the paper uses "for simplicity", and exact for
        a taut inextensible thread pulled at mid-span). ``"ellipse"``: the paper's
        semi-ellipse system as printed (minor semi-axis ``h_m/2``); it has no real
        solution for the paper's geometry and raises :class:`ParameterError` saying why.
        ``"ellipse_corrected"``: semi-ellipse of arc length ``l`` over the anchor span,
        semi-axes ``r1`` and ``r2``.
    use_tan : bool, default True
        ``F_contr = F_SPA tan(theta)`` as printed; ``False`` gives ``F_contr = F_SPA``
        (the reading under which the measured 0.315 N is matched).
    include_c3 : bool, default False
        Use the Yeoh C3 term in cauchyStress and its inverse (the paper omits it).
    cm_pressure_unit : {"MPa", "kPa", "bar", "Pa"}, default "MPa"
        Unit in which ``P`` enters the fitted ``c_m``. MPa is the only reading
        consistent with the paper's correlations and with positive forces.

    Raises
    ------
    ParameterError
        An unknown option value, naming the allowed values.
    """

    force_scale: float = 1.0
    theta: str = "printed"
    kinematics: str = "triangle"
    use_tan: bool = True
    include_c3: bool = False
    cm_pressure_unit: str = "MPa"

    def __post_init__(self) -> None:
        fs = self.force_scale
        if (
            isinstance(fs, bool)
            or not isinstance(fs, int | float)
            or not (math.isfinite(fs) and fs > 0)
        ):
            raise ParameterError("force_scale", fs, "(0, inf) 1")
        object.__setattr__(self, "force_scale", float(fs))
        _choice("theta", self.theta, _THETA)
        _choice("kinematics", self.kinematics, _KINEMATICS)
        _choice("cm_pressure_unit", self.cm_pressure_unit, tuple(_CM_PRESSURE_UNITS))
        for name in ("use_tan", "include_c3"):
            if not isinstance(getattr(self, name), bool):
                raise ParameterError(name, getattr(self, name), "True or False")

    @classmethod
    def corrected(cls, **changes: object) -> PaperOptions:
        """The documented corrections: ``force_scale=1e-3``, ``theta="corrected"``.

        ``kinematics="triangle"`` and ``use_tan=True`` are kept; keyword arguments
        override any field.
        """
        base = {"force_scale": 1e-3, "theta": "corrected"}
        base.update(changes)
        return cls(**base)  # type: ignore[arg-type]


def _choice(name: str, value: object, allowed: tuple[str, ...]) -> None:
    if value not in allowed:
        raise ParameterError(name, value, "one of " + ", ".join(repr(a) for a in allowed))


@dataclass(frozen=True)
class PaperResult:
    """Outputs of :func:`paper_static`, each a numpy array shaped like the pressure.

    Names carry the SI unit (``_Pa``, ``_N``, ``_m``, ``_rad``); names without a unit
    are dimensionless. Thread outputs (``theta_rad``, ``r1_m``, ``r2_m``,
    ``F_contr_N``) are ``None`` when the geometry has no thread (the FEM set).

    Attributes
    ----------
    pressure_Pa : gauge pressure, Pa.
    K : wall factor, 1.
    sigma_w_Pa : wall stress ``P K``, Pa.
    sigma_jz_Pa : stress on the junction zone ``F_e,wall / (a_hz b_hz)`` (unscaled), Pa.
    lambda_jz : junction-zone stretch, 1.
    c_m : adjustment coefficient, 1.
    F_e_wall_N : expansion force ``2 sigma_w a_ch b_ch`` (eq. force-h-zone), N.
    F_e_N : expansion force ``c_m P pi a_ch (...)`` (eq. expansion-force-final), N.
    F_r_N : restoring force ``cauchyStress(lambda_jz) a_hz b_hz``, N (equals
        ``F_e_wall_N`` by construction).
    F_spa_N : SPA force ``F_e - F_r``, N.
    h_m_m : myosin height ``h_m + 2 (lambda_jz - 1) h_jz``, m.
    theta_rad : thread angle, rad.
    r1_m, r2_m : half I-band (thread bulge) and half anchor span, m.
    F_contr_N : contraction force (``F_SPA tan(theta)`` or ``F_SPA``), N.
    options : the :class:`PaperOptions` used.
    """

    pressure_Pa: np.ndarray
    K: np.ndarray
    sigma_w_Pa: np.ndarray
    sigma_jz_Pa: np.ndarray
    lambda_jz: np.ndarray
    c_m: np.ndarray
    F_e_wall_N: np.ndarray
    F_e_N: np.ndarray
    F_r_N: np.ndarray
    F_spa_N: np.ndarray
    h_m_m: np.ndarray
    theta_rad: np.ndarray | None
    r1_m: np.ndarray | None
    r2_m: np.ndarray | None
    F_contr_N: np.ndarray | None
    options: PaperOptions = field(default_factory=PaperOptions)

    @property
    def names(self) -> tuple[str, ...]:
        """Names of the signal fields (everything except ``options``)."""
        return tuple(f.name for f in fields(self) if f.name != "options")

    def __getitem__(self, name: str) -> np.ndarray | None:
        if name not in self.names:
            raise ParameterError("signal", name, "one of " + ", ".join(self.names))
        return getattr(self, name)


# --------------------------------------------------------------------------------------
# Pieces of the model
# --------------------------------------------------------------------------------------
def wall_factor(t_w: float, h_ch: float) -> float:
    """The paper's wall factor ``K`` (dimensionless) with ``sigma_w = P K``.

    Thin-walled if ``t_w < h_ch / 4`` (strict, as printed): ``K = h_ch / (2 t_w)``;
    otherwise thick-walled: ``K = 1 + h_ch^2 / (2 t_w (t_w + h_ch))``.

    Parameters
    ----------
    t_w, h_ch : float
        Wall thickness and chamber height, m, > 0.
    """
    if not (t_w > 0 and h_ch > 0):
        raise ParameterError("t_w, h_ch", (t_w, h_ch), "(0, inf) m")
    if t_w < h_ch / 4.0:
        return h_ch / (2.0 * t_w)
    return 1.0 + h_ch**2 / (2.0 * t_w * (t_w + h_ch))


def _pressure(pressure_Pa: object, ambient: Ambient) -> np.ndarray:
    try:
        p = np.asarray(pressure_Pa, dtype=float)
    except (TypeError, ValueError):
        raise ParameterError("pressure_Pa", pressure_Pa, "numbers in Pa (gauge)") from None
    allowed = f"[{-ambient.p_amb:.6g}, inf) Pa (gauge, finite)"
    bad = ~np.isfinite(p) | (p < -ambient.p_amb)
    if np.any(bad):
        raise ParameterError("pressure_Pa", float(p[bad].ravel()[0]), allowed)
    return p


def _need(geometry: ParameterSet, names: tuple[str, ...], what: str) -> None:
    missing = [n for n in names if n not in geometry]
    if missing:
        raise ParameterError(
            ", ".join(missing),
            None,
            f"a geometry with {', '.join(names)}",
            f"{what} needs them; {geometry.name or 'the geometry'} has none",
        )


def _span(g: ParameterSet, lam: np.ndarray, theta: str) -> np.ndarray:
    """Length whose ratio to ``l`` is cos(theta), m."""
    if theta == "printed":
        return 2.0 * g["t_w"] + g["h_ch"] + 2.0 * lam * g["h_jz"]
    return g["h_m"] - 2.0 * g["t_w"] - g["h_ch"] + 2.0 * (lam - 1.0) * g["h_jz"]


def _theta(g: ParameterSet, lam: np.ndarray, theta: str, p: np.ndarray) -> np.ndarray:
    span = _span(g, lam, theta)
    too_wide = span >= g["l"]
    if np.any(too_wide):
        i = np.flatnonzero(too_wide.ravel())[0]
        raise ParameterError(
            "pressure_Pa",
            float(np.broadcast_to(p, span.shape).ravel()[i]),
            f"pressures with span < l = {g['l'] * 1e3:.6g} mm",
            f"theta ({theta}): span = {span.ravel()[i] * 1e3:.6g} mm >= l, arccos undefined "
            "(the inextensible thread would have to stretch)",
        )
    return np.arccos(span / g["l"])


def _half_arc(r1: float, r2: float) -> float:
    """Arc length of a semi-ellipse with semi-axes r1 (height) and r2 (half base), m."""
    big, small = max(r1, r2), min(r1, r2)
    if big == 0.0:
        return 0.0
    return 2.0 * big * float(ellipe(1.0 - (small / big) ** 2))


def _r1(
    g: ParameterSet, r2: np.ndarray, h_m_now: np.ndarray, kinematics: str, p: np.ndarray
) -> np.ndarray:
    """Half I-band (thread bulge) r1 for half anchor span r2, m."""
    length = g["l"]
    too_wide = 2.0 * r2 >= length
    if np.any(too_wide):
        i = np.flatnonzero(too_wide.ravel())[0]
        raise ParameterError(
            "pressure_Pa",
            float(np.broadcast_to(p, r2.shape).ravel()[i]),
            f"pressures with anchor span 2 r2 < l = {length * 1e3:.6g} mm",
            f"2 r2 = {2 * r2.ravel()[i] * 1e3:.6g} mm: the thread would have to stretch",
        )
    if kinematics == "triangle":
        return np.sqrt((length / 2.0) ** 2 - r2**2)
    if kinematics == "ellipse":
        roots = []
        # as printed: e = sqrt(1 - (h_m' + dh_m)^2 / (4 r1^2)), l = r1 int_0^pi sqrt(...)
        for b in np.ravel(h_m_now / 2.0):
            if length < math.pi * b:
                raise ParameterError(
                    "kinematics",
                    "ellipse",
                    "'triangle' or 'ellipse_corrected'",
                    "the paper's semi-ellipse system has no real solution: its "
                    f"eccentricity uses h_m/2 = {b * 1e3:.4g} mm as the minor semi-axis, "
                    f"so a real eccentricity needs r1 >= {b * 1e3:.4g} mm, and the "
                    f"shortest such semi-ellipse (a semicircle) has arc pi h_m/2 = "
                    f"{math.pi * b * 1e3:.4g} mm > l = {length * 1e3:.4g} mm",
                )
            roots.append(brentq(lambda r, b=b: _half_arc(r, b) - length, b, length / 2))
        return np.reshape(roots, r2.shape)
    # ellipse_corrected: semi-ellipse of arc l over the anchor span 2 r2
    roots = [brentq(lambda r, b=b: _half_arc(r, b) - length, 0.0, length / 2) for b in r2.ravel()]
    return np.reshape(roots, r2.shape)


# --------------------------------------------------------------------------------------
# Public model
# --------------------------------------------------------------------------------------
def paper_static(
    pressure_Pa: object,
    geometry: ParameterSet,
    material: YeohMaterial | str = "dragonskin_30",
    options: PaperOptions | None = None,
    ambient: Ambient | None = None,
) -> PaperResult:
    """Evaluate the paper's static SPA and sarcomere model at given pressures.

    Parameters
    ----------
    pressure_Pa : float or array_like
        Gauge pressure, Pa, finite, ``>= -ambient.p_amb``.
    geometry : ParameterSet
        :func:`~sarcomere.dynamics.params.experimental_geometry` or
        :func:`~sarcomere.dynamics.params.fem_geometry` (lengths in m). Without a thread
        (no ``l``), the thread outputs of the result are ``None``.
    material : YeohMaterial or str, default "dragonskin_30"
        Yeoh material or its slug.
    options : PaperOptions, default None
        Switches; ``None`` means ``PaperOptions()``, the equations as printed.
    ambient : Ambient, default None
        Gives the lower pressure bound ``-p_amb``; ``None`` means ``Ambient()``.

    Returns
    -------
    PaperResult
        Named arrays with units in their names.

    Raises
    ------
    ParameterError
        Bad pressure, unknown material, a stress beyond a non-monotone Yeoh law, a
        thread span exceeding ``l``, or the printed (unsolvable) ellipse kinematics.

    Examples
    --------
    >>> from sarcomere.dynamics.params import experimental_geometry
    >>> r = paper_static(0.1e6, experimental_geometry(), "dragonskin_30",
    ...                  PaperOptions(force_scale=1e-3))
    >>> round(float(r.F_spa_N), 3)
    0.314
    """
    opts = options if options is not None else PaperOptions()
    amb = ambient if ambient is not None else Ambient()
    mat = get_material(material)
    p = _pressure(pressure_Pa, amb)
    _need(geometry, ("a_ch", "b_ch", "a_hz", "b_hz", "h_jz", "t_w", "h_ch", "h_m"), "the SPA")
    g = geometry
    t_w, h_ch, h_jz = g["t_w"], g["h_ch"], g["h_jz"]

    K = wall_factor(t_w, h_ch)
    sigma_w = p * K
    F_e_wall = 2.0 * sigma_w * g["a_ch"] * g["b_ch"]
    sigma_jz = F_e_wall / (g["a_hz"] * g["b_hz"])
    lam = np.asarray(cauchy_stress_inverse(sigma_jz, mat, include_c3=opts.include_c3))
    p_fit = p / _CM_PRESSURE_UNITS[opts.cm_pressure_unit]
    c_m = -2.49 * (t_w / h_ch) - 6.101 * p_fit + 11.457
    F_e = c_m * p * math.pi * g["a_ch"] * (lam * h_jz + h_ch + 2.0 * t_w)
    F_r = np.asarray(cauchy_stress(lam, mat, include_c3=opts.include_c3)) * g["a_hz"] * g["b_hz"]
    F_spa = F_e - F_r
    h_m_now = g["h_m"] + 2.0 * (lam - 1.0) * h_jz

    s = opts.force_scale
    theta = r1 = r2 = F_contr = None
    if "l" in g:
        theta = _theta(g, lam, opts.theta, p)
        r2 = (h_m_now - 2.0 * t_w - h_ch) / 2.0
        r1 = _r1(g, r2, h_m_now, opts.kinematics, p)
        F_contr = s * F_spa * (np.tan(theta) if opts.use_tan else 1.0)

    shape = p.shape
    return PaperResult(
        pressure_Pa=p,
        K=np.full(shape, K),
        sigma_w_Pa=sigma_w,
        sigma_jz_Pa=sigma_jz,
        lambda_jz=lam.reshape(shape),
        c_m=np.broadcast_to(c_m, shape).copy(),
        F_e_wall_N=s * F_e_wall,
        F_e_N=s * F_e,
        F_r_N=s * F_r,
        F_spa_N=s * F_spa,
        h_m_m=h_m_now,
        theta_rad=theta,
        r1_m=r1,
        r2_m=r2,
        F_contr_N=F_contr,
        options=opts,
    )


def theta_rest(geometry: ParameterSet, options: PaperOptions | None = None) -> float:
    """Thread angle at rest (``lambda_jz = 1``), rad.

    ``"printed"``: arccos(12/32) = 67.98 deg; ``"corrected"``: arccos(20/32) = 51.32 deg
    (experimental geometry).

    Parameters
    ----------
    geometry : ParameterSet
        Needs ``t_w``, ``h_ch``, ``h_jz``, ``h_m``, ``l`` (m).
    options : PaperOptions, default None
        Only ``options.theta`` is used; ``None`` = as printed.
    """
    opts = options if options is not None else PaperOptions()
    _need(geometry, ("t_w", "h_ch", "h_jz", "h_m", "l"), "theta")
    return float(_theta(geometry, np.array(1.0), opts.theta, np.array(0.0)))


def _n(n: object) -> int:
    if isinstance(n, bool) or not isinstance(n, int | np.integer) or n < 1:
        raise ParameterError("n", n, "integers >= 1", "number of sarcomeres in series")
    return int(n)


def rest_length(n: int, geometry: ParameterSet, kinematics: str = "triangle") -> float:
    """Rest length of a myofibril of ``n`` APS, m.

    Parameters
    ----------
    n : int
        Number of sarcomeres (APS) in series, >= 1.
    geometry : ParameterSet
        Needs ``A``, ``l``, ``h_m``, ``t_w``, ``h_ch`` (m).
    kinematics : {"triangle", "ellipse", "ellipse_corrected", "band_ratio"}
        ``"triangle"`` (default): ``L' = n (A + 2 r1')`` with
        ``r1' = sqrt((l/2)^2 - r2'^2)`` and ``2 r2' = h_m - 2 t_w - h_ch``: 164.9 mm for
        n = 3 (measured: 165 mm). ``"ellipse_corrected"``: semi-ellipse of arc ``l``
        over the anchors (152.2 mm). ``"ellipse"``: the printed system (raises: no real
        solution). ``"band_ratio"``: the paper's design rule ``L' = n (A' + I')`` with
        ``I' = 2/3 A'`` (150 mm).
    """
    n = _n(n)
    _choice("kinematics", kinematics, _REST_KINEMATICS)
    _need(geometry, ("A",), "the rest length")
    if kinematics == "band_ratio":
        return n * (geometry["A"] + 2.0 / 3.0 * geometry["A"])
    _need(geometry, ("l", "h_m", "t_w", "h_ch"), "the rest length")
    r2 = np.array((geometry["h_m"] - 2.0 * geometry["t_w"] - geometry["h_ch"]) / 2.0)
    r1 = _r1(geometry, r2, np.array(geometry["h_m"]), kinematics, np.array(0.0))
    return float(n * (geometry["A"] + 2.0 * r1))


def myofibril_length(
    n: int,
    pressure_Pa: object,
    geometry: ParameterSet,
    material: YeohMaterial | str = "dragonskin_30",
    options: PaperOptions | None = None,
) -> np.ndarray:
    """Unloaded myofibril length ``L_mf = n (A + 2 r1)`` at given pressures, m.

    ``r1`` follows from ``options.kinematics`` and the junction-zone stretch of
    :func:`paper_static` (the paper's model has no load: this is the free length).

    Parameters
    ----------
    n : int
        Number of APS in series, >= 1.
    pressure_Pa : float or array_like
        Gauge pressure, Pa.
    geometry : ParameterSet
        With thread and A-band (``l``, ``A``), lengths in m.
    material : YeohMaterial or str, default "dragonskin_30"
    options : PaperOptions, default None (as printed)
    """
    n = _n(n)
    _need(geometry, ("A", "l"), "the myofibril length")
    r = paper_static(pressure_Pa, geometry, material, options)
    return n * (geometry["A"] + 2.0 * r.r1_m)


def max_length_ratio(geometry: ParameterSet, kinematics: str = "triangle") -> float:
    """Upper bound of ``L_mf / L'_mf`` with an inextensible thread (dimensionless).

    The longest a sarcomere can get is ``A + l`` (thread straight along the fibre,
    ``r2 -> 0``), so ``L_max / L' = (A + l) / (A + 2 r1')``: 1.128 for the experimental
    APS, far below the paper's stretch bound 1.7.
    """
    return (geometry["A"] + geometry["l"]) / rest_length(1, geometry, kinematics)
