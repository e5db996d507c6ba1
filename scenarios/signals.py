"""Scenario input tables (``[inputs.<name>]``) turned into signals.

The signal classes live in :mod:`sarcomere.dynamics.signals` (the model layer consumes
them); this module reads them from scenario data.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path

from sarcomere.dynamics.errors import ParameterError
from sarcomere.dynamics.signals import (
    SIGNAL_TYPES,
    Chirp,
    Ramp,
    Signal,
    Sine,
    Staircase,
    Step,
    Table,
)
from sarcomere.dynamics.units import to_si

from .spec import did_you_mean

__all__ = [
    "SIGNAL_TYPES",
    "Chirp",
    "Ramp",
    "Signal",
    "Sine",
    "Staircase",
    "Step",
    "Table",
    "signal_from_spec",
]


def signal_from_spec(
    spec: Mapping[str, object],
    unit: str,
    name: str,
    base_dir: Path | None = None,
    bare: str = "all",
) -> Signal:
    """Build a signal from a table such as ``{"type": "step", "final": "0.1 MPa"}``.

    Parameters
    ----------
    spec : mapping
        ``type`` (one of :data:`SIGNAL_TYPES`) and that type's keys. Quantities are numbers
        (taken as SI) or strings with units; ``levels`` is a list of them. A ``table``
        takes ``file`` (CSV, relative to ``base_dir``) and optionally ``column``.
    unit : str
        SI unit of the signal's value, e.g. ``"Pa"``.
    name : str
        Dotted name of the input, e.g. ``"inputs.pressure"``, used in error messages.
    base_dir : pathlib.Path, optional
        Directory relative to which a table's ``file`` is found (the scenario's folder).
    bare : {"all", "values", "none"}
        Which dimensioned keys may be bare numbers (taken in ``unit``, or s for times):
        ``"all"`` (Python), ``"values"`` (a scenario table that writes its ``unit``: the
        value keys are in it) or ``"none"`` (a file whose unit is implied: ``final = 50``
        could be Pa as well as kPa). Zero is always allowed.

    Returns
    -------
    Signal

    Raises
    ------
    ParameterError
        Unknown type or key, missing key, a quantity of the wrong dimension or out of range,
        an unreadable table file; ``.name`` is the dotted key.
    ScenarioError
        A malformed row in a table's CSV file (naming that file and line).

    Examples
    --------
    >>> s = signal_from_spec({"type": "step", "final": "0.1 MPa", "time": "2 s"}, "Pa", "p")
    >>> s(3.0)
    100000.0
    """
    kind = spec.get("type")
    if kind not in SIGNAL_TYPES:
        raise ParameterError(f"{name}.type", kind, "one of " + ", ".join(SIGNAL_TYPES))
    cls = SIGNAL_TYPES[kind]
    allowed = ["type", *cls.spec_keys]
    for key in spec:
        if key not in allowed:
            raise ParameterError(
                f"{name}.{key}",
                spec[key],
                "keys " + ", ".join(allowed),
                "unknown key" + did_you_mean(key, allowed),
            )
    if cls is Table:
        if not isinstance(spec.get("file"), str):
            raise ParameterError(f"{name}.file", spec.get("file"), "a CSV file name")
        column = spec.get("column")
        if column is not None and not isinstance(column, str):
            raise ParameterError(f"{name}.column", column, "a column name")
        path = Path(spec["file"])
        path = path if path.is_absolute() or base_dir is None else base_dir / path
        return Table.from_csv(path, unit, column, f"{name}.file")
    for key in cls.required_keys():
        if key not in spec:
            raise ParameterError(f"{name}.{key}", None, f"a value (required for type '{kind}')")
    kwargs: dict[str, object] = {}
    for key, value in spec.items():
        if key == "type":
            continue
        is_value = cls.spec_keys[key] == "value"
        key_unit = unit if is_value else cls.spec_keys[key]
        bare_ok = bare == "all" or (bare == "values" and is_value)
        if key == "levels":
            if not isinstance(value, list):
                raise ParameterError(f"{name}.levels", value, f"a list of values in {unit}")
            kwargs[key] = tuple(
                to_si(v, key_unit, f"{name}.levels[{i}]", bare_ok) for i, v in enumerate(value)
            )
        else:
            kwargs[key] = to_si(value, key_unit, f"{name}.{key}", bare_ok)
    try:
        return cls(unit=unit, **kwargs)
    except ParameterError as exc:
        raise ParameterError(f"{name}.{exc.name}", exc.value, exc.allowed) from None
