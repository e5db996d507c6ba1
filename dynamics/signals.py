"""Input signals: step, ramp, staircase, sine, chirp and CSV table.

Every signal is a frozen dataclass holding SI values. It can be evaluated three ways:

- ``signal(t)`` with numpy (scalar or array ``t`` in s; a scalar ``t`` gives a float);
- ``signal.casadi(t)`` with a CasADi symbol ``t``, to embed the signal in a model;
- ``signal.breakpoints(t0, tf)``: the times where the value or its slope jumps, so an
  integrator can be restarted there instead of stepping across a discontinuity.

:func:`sarcomere.scenarios.signals.signal_from_spec` builds one from a scenario's
``[inputs.<name>]`` table.
"""

from __future__ import annotations

import csv
import math
import re
from abc import ABC, abstractmethod
from dataclasses import MISSING, dataclass, fields
from pathlib import Path
from typing import TYPE_CHECKING, ClassVar

import numpy as np

from .errors import ParameterError, ScenarioError
from .files import read_text
from .units import si_unit, to_si

if TYPE_CHECKING:
    import casadi as ca


def _inside(times: list[float], t0: float, tf: float) -> list[float]:
    """Sorted unique ``times`` strictly between ``t0`` and ``tf`` (s)."""
    return sorted({float(t) for t in times if t0 < t < tf})


def _shaped(t: object, out: np.ndarray) -> float | np.ndarray:
    """A float for a scalar ``t``, else the array ``out``."""
    return float(out) if np.ndim(t) == 0 else out


@dataclass(frozen=True, kw_only=True)
class Signal(ABC):
    """Base of all signals.

    Parameters
    ----------
    unit : str
        Unit of the value, e.g. ``"Pa"``; ``"1"`` if dimensionless. Another unit of a
        dimension with an SI unit (``"kPa"``, ``"bar"``, ``"psi"``) is the unit of bare
        numbers: the values are taken to SI and ``unit`` becomes the SI unit.
    """

    unit: str = "1"

    #: Key of the scenario table -> its SI unit; ``"value"`` means the signal's own unit
    #: and ``""`` a key that is not a quantity.
    spec_keys: ClassVar[dict[str, str]] = {}

    def __post_init__(self) -> None:
        """Take every quantity field to SI (numbers or quantity strings), then check it."""
        si_value_unit, factor = si_unit(self.unit)
        for f in fields(self):
            kind = self.spec_keys.get(f.name, "")
            if not kind:
                continue
            unit, scale = (self.unit, factor) if kind == "value" else (kind, 1.0)
            value = getattr(self, f.name)
            if f.name == "levels":
                if isinstance(value, str) or not hasattr(value, "__iter__"):
                    raise ParameterError("levels", value, f"a list of values in {unit}")
                si = tuple(to_si(v, unit, f"levels[{i}]") * scale for i, v in enumerate(value))
            else:
                si = to_si(value, unit, f.name) * scale
            object.__setattr__(self, f.name, si)
        self._check()
        if factor != 1.0 or si_value_unit != self.unit:
            object.__setattr__(self, "unit", si_value_unit)

    def _check(self) -> None:  # noqa: B027  (a hook; most types override it)
        """Check the SI fields against each other (override; default: nothing to check)."""

    @classmethod
    def required_keys(cls) -> tuple[str, ...]:
        """Keys a scenario table must give for this type."""
        return tuple(
            f.name for f in fields(cls) if f.name in cls.spec_keys and f.default is MISSING
        )

    @abstractmethod
    def __call__(self, t: float | np.ndarray) -> float | np.ndarray:
        """Value at time ``t`` (s), in ``unit``."""

    @abstractmethod
    def breakpoints(self, t0: float, tf: float) -> list[float]:
        """Times (s) strictly inside ``(t0, tf)`` where the value or its slope jumps."""

    @abstractmethod
    def casadi(self, t: ca.SX | ca.MX) -> ca.SX | ca.MX:
        """CasADi expression of the value for a symbolic time ``t`` (s)."""


@dataclass(frozen=True, kw_only=True)
class Step(Signal):
    """``initial`` before ``time``, ``final`` from ``time`` on (right-continuous).

    Parameters
    ----------
    final : float
        Value from ``time`` on, in ``unit``.
    initial : float
        Value before ``time``, in ``unit``.
    time : float
        Step time, s.

    Examples
    --------
    >>> Step(final=1e5, time=0.5, unit="Pa")(np.array([0.0, 0.5]))
    array([     0., 100000.])
    """

    final: float
    initial: float = 0.0
    time: float = 0.0
    spec_keys: ClassVar[dict[str, str]] = {"final": "value", "initial": "value", "time": "s"}

    def __call__(self, t: float | np.ndarray) -> float | np.ndarray:
        return _shaped(t, np.where(np.asarray(t, float) < self.time, self.initial, self.final))

    def breakpoints(self, t0: float, tf: float) -> list[float]:
        return _inside([self.time], t0, tf)

    def casadi(self, t: ca.SX | ca.MX) -> ca.SX | ca.MX:
        import casadi as ca

        return ca.if_else(t < self.time, self.initial, self.final)


@dataclass(frozen=True, kw_only=True)
class Ramp(Signal):
    """Linear change from ``initial`` at ``start`` to ``final`` at ``start + duration``.

    Parameters
    ----------
    final : float
        Value reached at ``start + duration`` and held after, in ``unit``.
    duration : float
        Ramp duration, s (> 0).
    initial : float
        Value held until ``start``, in ``unit``.
    start : float
        Ramp start time, s.

    Examples
    --------
    >>> Ramp(final=2.0, duration=2.0)(1.0)
    1.0
    """

    final: float
    duration: float
    initial: float = 0.0
    start: float = 0.0
    spec_keys: ClassVar[dict[str, str]] = {
        "final": "value",
        "duration": "s",
        "initial": "value",
        "start": "s",
    }

    def _check(self) -> None:
        if not self.duration > 0:
            raise ParameterError("duration", self.duration, "a duration > 0 s")

    def __call__(self, t: float | np.ndarray) -> float | np.ndarray:
        frac = np.clip((np.asarray(t, float) - self.start) / self.duration, 0.0, 1.0)
        return _shaped(t, self.initial + (self.final - self.initial) * frac)

    def breakpoints(self, t0: float, tf: float) -> list[float]:
        return _inside([self.start, self.start + self.duration], t0, tf)

    def casadi(self, t: ca.SX | ca.MX) -> ca.SX | ca.MX:
        import casadi as ca

        frac = ca.fmin(ca.fmax((t - self.start) / self.duration, 0.0), 1.0)
        return self.initial + (self.final - self.initial) * frac


@dataclass(frozen=True, kw_only=True)
class Staircase(Signal):
    """Levels held for ``dwell`` each: ``levels[k]`` from ``start + k dwell`` on.

    ``levels[0]`` also holds before ``start``; the last level holds for ever.

    Parameters
    ----------
    levels : tuple of float
        Successive values, in ``unit`` (at least one).
    dwell : float
        Time each level is held, s (> 0).
    start : float
        Time the first level begins, s.

    Examples
    --------
    >>> Staircase(levels=(0.0, 1.0, 2.0), dwell=1.0)(np.array([0.5, 1.0, 9.0]))
    array([0., 1., 2.])
    """

    levels: tuple[float, ...]
    dwell: float
    start: float = 0.0
    spec_keys: ClassVar[dict[str, str]] = {"levels": "value", "dwell": "s", "start": "s"}

    def _check(self) -> None:
        if not self.levels:
            raise ParameterError("levels", self.levels, "a non-empty list of values")
        if not self.dwell > 0:
            raise ParameterError("dwell", self.dwell, "a duration > 0 s")

    @property
    def switch_times(self) -> list[float]:
        """Times (s) at which ``levels[1:]`` begin."""
        return [self.start + k * self.dwell for k in range(1, len(self.levels))]

    def __call__(self, t: float | np.ndarray) -> float | np.ndarray:
        tt = np.asarray(t, float)
        out = np.full(tt.shape, self.levels[0])
        for level, ts in zip(self.levels[1:], self.switch_times, strict=True):
            out = np.where(tt >= ts, level, out)
        return _shaped(t, out)

    def breakpoints(self, t0: float, tf: float) -> list[float]:
        return _inside(self.switch_times, t0, tf)

    def casadi(self, t: ca.SX | ca.MX) -> ca.SX | ca.MX:
        import casadi as ca

        out = self.levels[0]
        for level, ts in zip(self.levels[1:], self.switch_times, strict=True):
            out = ca.if_else(t >= ts, level, out)
        return out


@dataclass(frozen=True, kw_only=True)
class Sine(Signal):
    """``offset + amplitude sin(2 pi frequency (t - start) + phase)`` from ``start`` on.

    Before ``start`` the value is held at ``offset + amplitude sin(phase)`` (continuous;
    the slope jumps at ``start``).

    Parameters
    ----------
    amplitude : float
        Amplitude, in ``unit``.
    frequency : float
        Frequency, Hz (>= 0).
    offset : float
        Mean value, in ``unit``.
    phase : float
        Phase at ``start``, rad.
    start : float
        Start time, s.

    Examples
    --------
    >>> round(Sine(amplitude=2.0, frequency=0.25, offset=1.0)(1.0), 12)
    3.0
    """

    amplitude: float
    frequency: float
    offset: float = 0.0
    phase: float = 0.0
    start: float = 0.0
    spec_keys: ClassVar[dict[str, str]] = {
        "amplitude": "value",
        "frequency": "Hz",
        "offset": "value",
        "phase": "rad",
        "start": "s",
    }

    def _check(self) -> None:
        if not self.frequency >= 0:
            raise ParameterError("frequency", self.frequency, "a frequency >= 0 Hz")

    def __call__(self, t: float | np.ndarray) -> float | np.ndarray:
        tau = np.maximum(np.asarray(t, float) - self.start, 0.0)
        arg = 2.0 * math.pi * self.frequency * tau + self.phase
        return _shaped(t, self.offset + self.amplitude * np.sin(arg))

    def breakpoints(self, t0: float, tf: float) -> list[float]:
        return _inside([self.start], t0, tf)

    def casadi(self, t: ca.SX | ca.MX) -> ca.SX | ca.MX:
        import casadi as ca

        tau = ca.fmax(t - self.start, 0.0)
        return self.offset + self.amplitude * ca.sin(
            2.0 * math.pi * self.frequency * tau + self.phase
        )


@dataclass(frozen=True, kw_only=True)
class Chirp(Signal):
    """Linear sine sweep from ``f0`` to ``f1`` over ``duration`` from ``start`` on.

    ``offset + amplitude sin(2 pi (f0 tau + (f1 - f0) tau^2 / (2 duration)))`` with
    ``tau = clamp(t - start, 0, duration)``; held at ``offset`` before ``start`` and at its
    end value after the sweep (the slope jumps at both ends).

    Parameters
    ----------
    amplitude, offset : float
        In ``unit``.
    f0, f1 : float
        Start and end frequency, Hz (>= 0).
    duration : float
        Sweep time, s (> 0).
    start : float
        Start time, s.

    Examples
    --------
    >>> round(Chirp(amplitude=1.0, f0=1.0, f1=1.0, duration=2.0)(0.25), 12)
    1.0
    """

    amplitude: float
    f0: float
    f1: float
    duration: float
    offset: float = 0.0
    start: float = 0.0
    spec_keys: ClassVar[dict[str, str]] = {
        "amplitude": "value",
        "f0": "Hz",
        "f1": "Hz",
        "duration": "s",
        "offset": "value",
        "start": "s",
    }

    def _check(self) -> None:
        if not (self.f0 >= 0 and self.f1 >= 0):
            raise ParameterError("f0/f1", (self.f0, self.f1), "frequencies >= 0 Hz")
        if not self.duration > 0:
            raise ParameterError("duration", self.duration, "a duration > 0 s")

    def _phase(self, tau):
        return 2.0 * math.pi * (self.f0 * tau + 0.5 * (self.f1 - self.f0) * tau**2 / self.duration)

    def __call__(self, t: float | np.ndarray) -> float | np.ndarray:
        tau = np.clip(np.asarray(t, float) - self.start, 0.0, self.duration)
        return _shaped(t, self.offset + self.amplitude * np.sin(self._phase(tau)))

    def breakpoints(self, t0: float, tf: float) -> list[float]:
        return _inside([self.start, self.start + self.duration], t0, tf)

    def casadi(self, t: ca.SX | ca.MX) -> ca.SX | ca.MX:
        import casadi as ca

        tau = ca.fmin(ca.fmax(t - self.start, 0.0), self.duration)
        return self.offset + self.amplitude * ca.sin(self._phase(tau))


#: Most rows a table may hold (about 16 MB of times and values in memory, 1-2 s to read a
#: CSV this long); a longer one is refused (resample it).
TABLE_MAX_ROWS = 1_000_000

#: Most rows of a table inside a run that are integrator restarts (its slope jumps); a
#: denser table (a recorded signal) is integrated as one continuous input, since a
#: restart at each of 500 000 rows takes many minutes.
TABLE_MAX_BREAKPOINTS = 1000


def _si_tuple(seq, unit: str, name: str) -> tuple[float, ...]:
    """``seq`` in SI: floats as they are (checked finite at once), else each by to_si."""
    items = list(seq)
    if all(type(v) is float for v in items):
        arr = np.asarray(items, dtype=float)
        bad = np.flatnonzero(~np.isfinite(arr))
        if bad.size:
            raise ParameterError(f"{name}[{bad[0]}]", items[bad[0]], "a finite number")
        return tuple(items)
    return tuple(to_si(v, unit, f"{name}[{i}]") for i, v in enumerate(items))


@dataclass(frozen=True, kw_only=True)
class Table(Signal):
    """Linear interpolation in a table of (time, value); end values held outside it.

    Parameters
    ----------
    times : tuple of float
        Strictly increasing times, s (at least two).
    values : tuple of float
        Values at ``times``, in ``unit``.
    source : str
        Where the table came from (a CSV path), for messages.

    Examples
    --------
    >>> Table(times=(0.0, 1.0), values=(0.0, 10.0))(np.array([-1.0, 0.25, 5.0]))
    array([ 0. ,  2.5, 10. ])
    """

    times: tuple[float, ...]
    values: tuple[float, ...]
    source: str = ""
    spec_keys: ClassVar[dict[str, str]] = {"file": "", "column": ""}

    def _check(self) -> None:
        for name in ("times", "values"):
            unit = "s" if name == "times" else self.unit
            seq = getattr(self, name)
            if isinstance(seq, str) or not hasattr(seq, "__iter__"):
                raise ParameterError(name, seq, f"a list of numbers in {unit}", self.source)
            si = _si_tuple(seq, unit, name)
            if name == "values" and (factor := si_unit(unit)[1]) != 1.0:
                si = tuple(v * factor for v in si)
            object.__setattr__(self, name, si)
        if len(self.times) < 2 or len(self.times) != len(self.values):
            raise ParameterError(
                "times", self.times, "at least two times, as many as values", self.source
            )
        if len(self.times) > TABLE_MAX_ROWS:
            raise ParameterError(
                "times",
                f"{len(self.times)} rows",
                f"at most {TABLE_MAX_ROWS} rows",
                f"{self.source or 'table'}: resample it",
            )
        if np.any(np.diff(self.times) <= 0):
            raise ParameterError("times", self.times, "strictly increasing times", self.source)

    @classmethod
    def required_keys(cls) -> tuple[str, ...]:
        return ("file",)

    def __call__(self, t: float | np.ndarray) -> float | np.ndarray:
        return _shaped(t, np.interp(np.asarray(t, float), self.times, self.values))

    def breakpoints(self, t0: float, tf: float) -> list[float]:
        """The rows inside ``(t0, tf)`` (slope jumps), if at most
        :data:`TABLE_MAX_BREAKPOINTS`; a denser table is integrated as a continuous input
        (no restart at each row: the step control follows its kinks)."""
        times = np.asarray(self.times)
        inside = times[(times > t0) & (times < tf)]
        return inside.tolist() if len(inside) <= TABLE_MAX_BREAKPOINTS else []

    def casadi(self, t: ca.SX | ca.MX) -> ca.SX | ca.MX:
        import casadi as ca

        lut = ca.interpolant("table", "linear", [list(self.times)], list(self.values))
        return lut(ca.fmin(ca.fmax(t, self.times[0]), self.times[-1]))

    @classmethod
    def from_csv(cls, path: Path, unit: str, column: str | None = None, key: str = "file") -> Table:
        """Read a table from a CSV file.

        The first row is a header. The first column is time; the value column is
        ``column`` (by header name) or else the second column. A header cell may state
        its unit in brackets, e.g. ``time [ms]`` or ``pressure [MPa]``. The time column
        without one is taken as s; a value column of a dimensioned ``unit`` must state its
        unit (a pressure table in MPa read as Pa would be a million times off, silently).
        Blank lines and lines starting with ``#`` are skipped. This reads the
        ``timeseries.csv`` files that runs write.

        Parameters
        ----------
        path : pathlib.Path
            CSV file.
        unit : str
            SI unit of the values.
        column : str, optional
            Header name of the value column (without its bracketed unit).
        key : str
            Dotted scenario key that named the file, for error messages.

        Raises
        ------
        ParameterError
            The file cannot be read (``.name`` is ``key``).
        ScenarioError
            A row is malformed, non-numeric or out of order (naming the CSV file and line).
        """
        try:
            text = read_text(path)
        except ValueError as exc:
            raise ParameterError(key, str(path), "a readable CSV text file", str(exc)) from None
        rows = [
            (lineno, row)
            for lineno, row in enumerate(csv.reader(text.splitlines()), start=1)
            if "".join(row).strip() and not row[0].lstrip().startswith("#")
        ]
        if len(rows) < 3:
            raise ScenarioError(str(path), key, "need a header row and at least two data rows")
        head_line, header = rows[0]
        names, units = zip(*(_header_cell(c) for c in header), strict=True)
        if column is None:
            col = 1
        elif column in names:
            col = names.index(column)
        else:
            raise ScenarioError(
                str(path), key, f"no column '{column}'; columns: {', '.join(names)}", head_line
            )
        if col == 0 or len(header) <= col:
            raise ScenarioError(str(path), key, "need a time column and a value column", head_line)
        if units[col] is None and unit not in ("1", ""):
            raise ScenarioError(
                str(path),
                key,
                f"column '{names[col]}' states no unit; write it in the header, e.g. "
                f"'{names[col]} [{unit}]' or '{names[col]} [MPa]' (a value column needs one)",
                head_line,
            )
        if len(rows) - 1 > TABLE_MAX_ROWS:
            raise ScenarioError(
                str(path), key, f"{len(rows) - 1} data rows, above {TABLE_MAX_ROWS}; resample it"
            )
        (t_scale, t_zero), (v_scale, v_zero) = (
            _affine(units[0], "s", key, path),
            _affine(units[col], unit, key, path),
        )
        raw = _numbers(rows[1:], col, path, key)
        lines = np.array([lineno for lineno, _ in rows[1:]])
        bad = np.flatnonzero(~np.all(np.isfinite(raw), axis=1))
        if bad.size:
            raise ScenarioError(str(path), key, "non-finite number", int(lines[bad[0]]))
        times, values = raw[:, 0] * t_scale + t_zero, raw[:, 1] * v_scale + v_zero
        bad = np.flatnonzero(np.diff(times) <= 0)
        if bad.size:
            line = int(lines[bad[0] + 1])
            raise ScenarioError(str(path), key, "times must be strictly increasing", line)
        return cls(
            times=tuple(times.tolist()), values=tuple(values.tolist()), unit=unit, source=str(path)
        )


def _numbers(rows: list, col: int, path: Path, key: str) -> np.ndarray:
    """Columns 0 and ``col`` of the data ``rows`` (line, cells) as floats, (rows, 2); the
    first row that is not two numbers is named by its line."""
    try:
        return np.array([(row[0], row[col]) for _, row in rows], dtype=float)
    except (ValueError, IndexError):
        pass  # find the bad row, one by one
    out = []
    for lineno, row in rows:
        try:
            out.append((float(row[0]), float(row[col])))
        except (ValueError, IndexError):
            raise ScenarioError(
                str(path), key, f"expected numbers in columns 1 and {col + 1}", lineno
            ) from None
    return np.array(out)


_HEADER = re.compile(r"^(?P<name>[^\[]*?)\s*\[(?P<unit>[^\]]*)\]$")


def _header_cell(cell: str) -> tuple[str, str | None]:
    """Split a header cell ``"name [unit]"`` into name and unit (None if no unit)."""
    match = _HEADER.match(cell.strip())
    return (match["name"], match["unit"].strip()) if match else (cell.strip(), None)


def _affine(unit: str | None, si_unit: str, key: str, path: Path) -> tuple[float, float]:
    """Scale and offset taking a column in ``unit`` to ``si_unit``."""
    if not unit:
        return 1.0, 0.0
    try:
        zero = to_si(f"0 {unit}", si_unit, key)
        return to_si(f"1 {unit}", si_unit, key) - zero, zero
    except ParameterError as exc:
        raise ScenarioError(str(path), key, f"column unit [{unit}]: {exc}") from None


#: Signal type name (the ``type`` key of an input table) -> class.
SIGNAL_TYPES: dict[str, type[Signal]] = {
    "step": Step,
    "ramp": Ramp,
    "staircase": Staircase,
    "sine": Sine,
    "chirp": Chirp,
    "table": Table,
}
