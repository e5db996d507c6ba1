"""Quantities written with units ("0.1 MPa", "20 g", "9.5 mm") converted to SI floats.

Plain numbers are taken to be in the SI unit asked for already (``bare_ok=False``, as for
scenario files, refuses a bare non-zero number of a dimensioned unit instead). Strings are
parsed by pint; a wrong dimension raises :class:`~sarcomere.dynamics.errors.ParameterError`.
"""

from __future__ import annotations

import functools
import math

import pint

from .errors import ParameterError


@functools.cache
def _registry() -> pint.UnitRegistry:
    return pint.UnitRegistry()


@functools.cache
def _dimensionless(unit: str) -> bool:
    return _registry().Unit(unit or "dimensionless").dimensionless


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
    elif isinstance(value, str):
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
