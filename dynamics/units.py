"""Quantities written with units ("0.1 MPa", "20 g", "9.5 mm") converted to SI floats.

Plain numbers are taken to be in the SI unit asked for already. Strings are parsed by
pint; a wrong dimension raises :class:`~sarcomere.dynamics.errors.ParameterError`.
"""

from __future__ import annotations

import functools
import math

import pint

from .errors import ParameterError


@functools.cache
def _registry() -> pint.UnitRegistry:
    return pint.UnitRegistry()


def to_si(value: object, unit: str, name: str = "value") -> float:
    """Return ``value`` as a float in ``unit`` (an SI unit string such as "Pa", "m", "kg").

    ``value`` is a number (already in ``unit``) or a string with a unit ("0.1 MPa").
    ``unit`` "1" or "" means dimensionless.
    """
    ureg = _registry()
    target = ureg.Unit(unit or "dimensionless")
    if isinstance(value, bool):
        raise ParameterError(name, value, f"a number in {unit or '1'} or a string with a unit")
    if isinstance(value, int | float):
        out = float(value)
    elif isinstance(value, str):
        try:
            q = ureg.Quantity(value.strip())
        except Exception as exc:  # pint raises several unrelated types for bad text
            raise ParameterError(
                name, value, f"a quantity such as '1.5 {unit}'", f"cannot parse: {exc}"
            ) from None
        if not isinstance(q, pint.Quantity):
            q = ureg.Quantity(float(q), "dimensionless")
        if q.dimensionless and not target.dimensionless and q.units == ureg.dimensionless:
            out = float(q.magnitude)  # a bare number in a string: take it as SI
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
