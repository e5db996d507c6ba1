"""Parameters with units, ranges and sources, and immutable named sets of them.

A :class:`Quantity` is a unit and an allowed range (the one record of them, with the one
refusal text); a :class:`Param` is one SI value with its quantity and where the number
comes from. A :class:`ParameterSet` is an ordered, immutable collection of them that
also knows

* which parameters are *derived* from others (they are recomputed on every override and
  cannot be set directly), and
* which *cross checks* must hold between parameters (for example, the thread anchors
  of an APS must fit inside the thread).

Example
-------
>>> from sarcomere.dynamics.params import experimental_geometry
>>> g = experimental_geometry()
>>> round(g["h_m"] * 1e3, 6)
28.0
>>> g2 = g.with_overrides({"a_ch": "9.0 mm"})
>>> round(g2["a_ch"], 12)
0.009
"""

from __future__ import annotations

import dataclasses
import difflib
import math
from collections.abc import Callable, Iterable, Iterator, Mapping
from dataclasses import KW_ONLY, dataclass

from ..errors import ParameterError
from ..units import to_si

__all__ = ["Check", "Derived", "Param", "ParameterSet", "Quantity"]

Check = Callable[[Mapping[str, float]], None]
"""A cross check: receives ``{name: SI value}`` and raises ParameterError if violated."""


def _fmt(x: float) -> str:
    if math.isinf(x):
        return "inf" if x > 0 else "-inf"
    return f"{x:.6g}"


_ABOVE_ZERO = math.nextafter(0.0, 1.0)


@dataclass(frozen=True, kw_only=True)
class Quantity:
    """The unit and allowed range of a value: the one record behind a :class:`Param`, a
    model variable (``modeling.variables.Var``), an ``APSParams`` field and a study
    factor's target, with the one refusal text (:meth:`refuse`).

    Attributes
    ----------
    unit : str, default "1"
        SI unit string ("m", "Pa", "kg/m^3"; "1" for dimensionless).
    low, high : float, default -inf, inf
        Bounds of the range [unit].
    low_open, high_open : bool, default False
        Whether a bound is excluded (an infinite bound always reads as open).
    """

    unit: str = "1"
    low: float = -math.inf
    high: float = math.inf
    low_open: bool = False
    high_open: bool = False

    @property
    def range_str(self) -> str:
        """The range as text with its unit: ``"(0, inf) m"``, ``"[0, 1]"`` (no unit when
        dimensionless). A closed bound at the float next to 0 reads as open at 0 (the
        same floats)."""
        low, left = self.low, "(" if self.low_open or math.isinf(self.low) else "["
        if low == _ABOVE_ZERO and not self.low_open:
            low, left = 0.0, "("
        right = ")" if self.high_open or math.isinf(self.high) else "]"
        unit = "" if self.unit == "1" else f" {self.unit}"
        return f"{left}{_fmt(low)}, {_fmt(self.high)}{right}{unit}"

    def contains(self, x: float) -> bool:
        """Whether ``x`` [unit] lies in the range (NaN never does)."""
        above = x > self.low if self.low_open else x >= self.low
        below = x < self.high if self.high_open else x <= self.high
        return bool(above and below)

    def refuse(self, name: str, value: object, reason: str = "") -> ParameterError:
        """The error refusing ``value`` for ``name``: it names both and the range."""
        return ParameterError(name, value, self.range_str, reason)


@dataclass(frozen=True)
class Param(Quantity):
    """One model parameter: an SI value with unit, allowed range (:class:`Quantity`,
    keywords) and source.

    Attributes
    ----------
    name : str
        Symbol used everywhere (code, tables, docs), e.g. ``"h_ch"``.
    value : float
        Value in SI units.
    source : str, default "estimate"
        Where the number comes from: a paper equation or section, a data sheet,
        ``"calibrated against ..."`` or ``"estimate"``.
    description : str, default ""
        One line saying what the parameter is.

    Raises
    ------
    ParameterError
        If the value is not a finite number inside the allowed range.
    """

    name: str
    value: float
    _: KW_ONLY
    source: str = "estimate"
    description: str = ""

    def __post_init__(self) -> None:
        v = self.value
        if isinstance(v, bool) or not isinstance(v, int | float):
            raise self.refuse(self.name, v, "not a number")
        object.__setattr__(self, "value", float(v))
        if not math.isfinite(self.value):
            raise self.refuse(self.name, v, "not finite")
        if not self.contains(self.value):
            raise self.refuse(self.name, v, "outside the allowed range")

    def with_value(self, value: object) -> Param:
        """Return a copy with a new value (float in SI, or a string with a unit)."""
        return dataclasses.replace(self, value=to_si(value, self.unit, self.name))


@dataclass(frozen=True)
class Derived:
    """Rule for a derived parameter.

    Attributes
    ----------
    fn : callable
        ``fn(values) -> float``: the SI value from the other parameters' SI values.
    formula : str
        Human-readable formula, used in error messages and docs.
    inputs : tuple of str
        Names of the parameters the value depends on.
    """

    fn: Callable[[Mapping[str, float]], float]
    formula: str
    inputs: tuple[str, ...] = ()


class ParameterSet:
    """Immutable ordered collection of :class:`Param`, indexed by name.

    ``ps["h_m"]`` returns the SI float, ``ps.param("h_m")`` the :class:`Param`;
    ``ps.values()`` returns a new ``dict`` of name -> SI float (note: a dict, not a view);
    iterating over a set yields the names in order.

    Parameters
    ----------
    params : iterable of Param
        The parameters, in display order; names must be unique.
    checks : iterable of callables, default ()
        Cross checks ``check(values)`` raising :class:`ParameterError`; run on
        construction and after every override.
    derived : mapping of str to Derived, default None
        Parameters computed from others. Each must also appear in ``params`` (its
        ``Param`` carries unit, range and source); the value given there must agree with
        the rule (relative tolerance 1e-9), which makes the stated number a check.
    name : str, default ""
        Name of the set (e.g. ``"experimental_geometry"``), shown in messages.

    Raises
    ------
    ParameterError
        On duplicate names, a derived value that disagrees with its rule, or a failed
        cross check.
    """

    def __init__(
        self,
        params: Iterable[Param],
        *,
        checks: Iterable[Check] = (),
        derived: Mapping[str, Derived] | None = None,
        name: str = "",
    ) -> None:
        plist = tuple(params)
        by_name: dict[str, Param] = {}
        for p in plist:
            if not isinstance(p, Param):
                raise ParameterError("params", p, "Param instances")
            if p.name in by_name:
                raise ParameterError(p.name, p.value, "unique names", "duplicate parameter")
            by_name[p.name] = p
        self._params = by_name
        self._checks = tuple(checks)
        self._derived = dict(derived or {})
        self.name = name
        for dname, rule in self._derived.items():
            if dname not in by_name:
                raise ParameterError(dname, None, "a name listed in params", "derived rule")
            computed = float(rule.fn(self.values()))
            given = by_name[dname].value
            if not math.isclose(given, computed, rel_tol=1e-9, abs_tol=0.0):
                raise ParameterError(
                    dname,
                    given,
                    f"{computed:.9g} {by_name[dname].unit} (derived: {rule.formula})",
                    "stated value disagrees with its derivation",
                )
        self._run_checks()

    # -- mapping-like access -------------------------------------------------------
    def __getitem__(self, name: str) -> float:
        return self.param(name).value

    def __contains__(self, name: object) -> bool:
        return name in self._params

    def __iter__(self) -> Iterator[str]:
        return iter(self._params)

    def __len__(self) -> int:
        return len(self._params)

    def keys(self) -> list[str]:
        """Parameter names in order."""
        return list(self._params)

    def values(self) -> dict[str, float]:
        """Return a new dict name -> SI value (a dict, unlike ``Mapping.values``)."""
        return {k: p.value for k, p in self._params.items()}

    def items(self) -> list[tuple[str, float]]:
        """(name, SI value) pairs in order."""
        return [(k, p.value) for k, p in self._params.items()]

    def get(self, name: str, default: float | None = None) -> float | None:
        """SI value of ``name``, or ``default`` if the set has no such parameter."""
        return self._params[name].value if name in self._params else default

    def param(self, name: str) -> Param:
        """Return the :class:`Param` called ``name`` (ParameterError if unknown)."""
        try:
            return self._params[name]
        except KeyError:
            raise self._unknown(name, None) from None

    @property
    def params(self) -> tuple[Param, ...]:
        """All parameters in order."""
        return tuple(self._params.values())

    # -- overrides -----------------------------------------------------------------
    def with_overrides(self, overrides: Mapping[str, object] | None = None) -> ParameterSet:
        """Return a new set with some values replaced.

        Parameters
        ----------
        overrides : mapping of str to float or str, default None
            New values: floats are SI, strings carry a unit (``"9.5 mm"``).

        Returns
        -------
        ParameterSet
            New set; derived parameters are recomputed and all cross checks re-run.

        Raises
        ------
        ParameterError
            Unknown name (the message lists the valid names and the closest match),
            derived name, wrong dimension, value out of range, failed cross check.
        """
        overrides = dict(overrides or {})
        new = dict(self._params)
        for key, val in overrides.items():
            if key not in new:
                raise self._unknown(key, val)
            if key in self._derived:
                rule = self._derived[key]
                inputs = ", ".join(rule.inputs) or "its inputs"
                raise ParameterError(
                    key,
                    val,
                    f"not settable; derived as {rule.formula} (set {inputs} instead)",
                    "derived parameter",
                )
            new[key] = new[key].with_value(val)
        values = {k: p.value for k, p in new.items()}
        for dname, rule in self._derived.items():
            new[dname] = dataclasses.replace(new[dname], value=float(rule.fn(values)))
            values[dname] = new[dname].value
        return ParameterSet(
            new.values(), checks=self._checks, derived=self._derived, name=self.name
        )

    def __repr__(self) -> str:
        body = ", ".join(f"{p.name}={p.value:.6g} {p.unit}" for p in self._params.values())
        return f"ParameterSet({self.name!r}: {body})"

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, ParameterSet):
            return NotImplemented
        return self._params == other._params

    __hash__ = None  # type: ignore[assignment]

    # -- internals -----------------------------------------------------------------
    def _run_checks(self) -> None:
        values = self.values()
        for check in self._checks:
            check(values)

    def _unknown(self, key: str, value: object) -> ParameterError:
        valid = list(self._params)
        close = difflib.get_close_matches(str(key), valid, n=3, cutoff=0.5)
        hint = f"unknown parameter of {self.name or 'this set'}"
        if close:
            hint += "; did you mean " + " or ".join(repr(c) for c in close) + "?"
        return ParameterError(key, value, "one of " + ", ".join(valid), hint)
