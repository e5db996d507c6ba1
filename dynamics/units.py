"""Quantities written with units ("0.1 MPa", "20 g", "9.5 mm") converted to SI floats.

Plain numbers are taken to be in the SI unit asked for already (``bare_ok=False``, as for
scenario files, refuses a bare non-zero number of a dimensioned unit instead). Strings are
parsed by pint; a wrong dimension raises :class:`~sarcomere.dynamics.errors.ParameterError`.
The common case, a plain number and one of the units in :data:`_UNITS` ("0.1 MPa",
"50 g", "10 ms", "694 N/m"), is converted without pint (pint's import and registry cost
0.35 s of every CLI run: BENCHMARKS.md, start-up), with pint's own arithmetic (the
magnitude times the unit's factor: the same float, tested against pint); anything else
goes to pint.
"""

from __future__ import annotations

import functools
import math
import re

from .errors import ParameterError

_UNITS = {
    "Pa": ("pressure", 1.0),
    "kPa": ("pressure", 1e3),
    "MPa": ("pressure", 1e6),
    "bar": ("pressure", 1e5),
    "m": ("length", 1.0),
    "mm": ("length", 1e-3),
    "cm": ("length", 1e-2),
    "um": ("length", 1e-6),
    "kg": ("mass", 1.0),
    "g": ("mass", 1e-3),
    "mg": ("mass", 1e-6),
    "s": ("time", 1.0),
    "ms": ("time", 1e-3),
    "us": ("time", 1e-6),
    "min": ("time", 60.0),
    "N": ("force", 1.0),
    "mN": ("force", 1e-3),
    "m^2": ("area", 1.0),
    "N/m": ("stiffness", 1.0),
    "Hz": ("frequency", 1.0),
    "kHz": ("frequency", 1e3),
    "%": ("1", 1e-2),
    "1": ("1", 1.0),
    "": ("1", 1.0),
}
"""Units converted without pint: symbol -> (dimension, factor to its SI unit)."""

_PLAIN = re.compile(
    r"\s*([+-]?(?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d+)?)\s*([A-Za-z%]*(?:\^2|/[A-Za-z]+)?|1)\s*"
)


@functools.cache
def _registry():
    import pint  # on first use only: CLI start-up

    return pint.UnitRegistry()


@functools.cache
def _dimensionless(unit: str) -> bool:
    if unit in _UNITS:
        return _UNITS[unit][0] == "1"
    return _registry().Unit(unit or "dimensionless").dimensionless


def _fast(text: str, unit: str) -> float | None:
    """``text`` in ``unit`` without pint, or None where pint must decide (another unit or
    form, or a dimension mismatch, which pint words)."""
    m = _PLAIN.fullmatch(text)
    if m is None or unit not in _UNITS or m.group(2) not in _UNITS:
        return None
    (dim, factor), (target_dim, target_factor) = _UNITS[m.group(2)], _UNITS[unit]
    if dim != target_dim or target_factor != 1.0:
        return None
    if m.group(2) in ("", "1") and dim != "1":  # a bare number: pint's and the caller's rule
        return None
    return float(m.group(1)) * factor


def to_si(value: object, unit: str, name: str = "value", bare_ok: bool = True) -> float:
    """Return ``value`` as a float in ``unit`` (an SI unit string such as "Pa", "m", "kg").

    ``value`` is a number (already in ``unit``) or a string with a unit ("0.1 MPa").
    ``unit`` "1" or "" means dimensionless. ``bare_ok=False`` refuses a number without a
    unit (``50`` or ``"50"``) when ``unit`` has a dimension, except 0 (the same in every
    unit): ``load = 50`` in a file could mean 50 g as well as 50 kg.
    """
    if isinstance(value, bool):
        raise ParameterError(name, value, f"a number in {unit or '1'} or a string with a unit")
    if isinstance(value, int | float):  # no unit registry: tables convert a million of these
        out = float(value)
        _check_bare(out, value, unit, name, bare_ok)
    elif isinstance(value, str) and (fast := _fast(value, unit)) is not None:
        out = fast
    elif isinstance(value, str):
        import pint

        ureg = _registry()
        target = ureg.Unit(unit or "dimensionless")
        try:
            q = ureg.Quantity(value.strip())
        except Exception as exc:  # pint raises several unrelated types for bad text
            why = str(exc).strip() or "not a number followed by a unit"
            example = f"'1.5 {unit}'" if not _dimensionless(unit) else "'1.5'"
            raise ParameterError(
                name, value, f"a quantity such as {example}", f"cannot parse: {why}"
            ) from None
        if not isinstance(q, pint.Quantity):
            q = ureg.Quantity(float(q), "dimensionless")
        if q.dimensionless and not target.dimensionless and q.units == ureg.dimensionless:
            out = float(q.magnitude)  # a bare number in a string: take it as SI
            _check_bare(out, value, unit, name, bare_ok)
        else:
            try:
                out = float(q.to(target).magnitude)
            except pint.DimensionalityError:
                raise ParameterError(
                    name, value, f"a quantity convertible to {unit}", "wrong dimension"
                ) from None
    else:
        raise ParameterError(name, value, f"a number in {unit or '1'} or a string with a unit")
    if not math.isfinite(out):
        raise ParameterError(name, value, "a finite number")
    return out


_SI_SYMBOLS = ("Pa", "m", "kg", "s", "N", "Hz")
"""SI units :func:`si_unit` maps another unit of the same dimension onto."""


@functools.cache
def si_unit(unit: str) -> tuple[str, float]:
    """The SI unit of ``unit``'s dimension and the factor taking a number in ``unit`` to it:
    ``si_unit("kPa") == ("Pa", 1000.0)``, ``si_unit("psi")`` through pint. A unit of
    another dimension (or with an offset, degC) is returned as it is, with factor 1."""
    if unit in _UNITS:
        dim, factor = _UNITS[unit]
        si = next(k for k, (d, f) in _UNITS.items() if d == dim and f == 1.0)
        return (unit, 1.0) if dim == "1" else (si, factor)
    import pint

    try:
        q = _registry().Quantity(1.0, unit)
    except Exception:  # pint raises several unrelated types for bad text
        return unit, 1.0
    for si in _SI_SYMBOLS:
        try:
            return si, float(q.to(si).magnitude)
        except (pint.DimensionalityError, pint.OffsetUnitCalculusError):
            continue
    return unit, 1.0


def _check_bare(out: float, value: object, unit: str, name: str, bare_ok: bool) -> None:
    """Refuse a bare non-zero number of a dimensioned ``unit`` unless ``bare_ok``."""
    if bare_ok or out == 0 or not math.isfinite(out) or _dimensionless(unit):
        return
    raise ParameterError(
        name,
        value,
        f"a quantity with its unit, e.g. '{out:g} {unit}'",
        "a bare number needs a unit here",
    )
