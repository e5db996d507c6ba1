"""Data CSV files of a fit: a header ``signal [unit]`` per column, ``#`` comment lines; a
time series starts with a strictly increasing ``time [...]`` column, a static table has
none (one row per steady state). Every problem is a one-line :class:`~.spec.FitError`
naming the file, line, column, value and what is allowed."""

from __future__ import annotations

import csv
import io
import math
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from sarcomere.dynamics.errors import ParameterError
from sarcomere.dynamics.files import read_text
from sarcomere.dynamics.units import to_si

from .spec import FitError

_HEADER = re.compile(r"^\s*([^\[\]]+?)\s*\[\s*([^\[\]]+?)\s*\]\s*$")


@dataclass
class Table:
    """A data file: column name -> (unit as written, values as written), the line of each
    data row, and the file."""

    file: str
    columns: dict[str, tuple[str, np.ndarray]]
    rows: list[int]
    header_line: int

    def si(self, name: str, unit: str, why: str | None = None) -> np.ndarray:
        """Column ``name`` in the model's unit ``unit`` (FitError for another dimension;
        ``why``: what sets ``unit``, default the model's unit of ``name``)."""
        written, values = self.columns[name]
        try:
            factor = to_si(f"1 {written}", unit, name, bare_ok=False)
        except ParameterError:
            why = why or f"the model's unit of '{name}'"
            raise FitError(
                self.file,
                name,
                f"unit '{written}' is not a unit of {unit} ({why})",
                self.header_line,
            ) from None
        return values * factor

    @property
    def time(self) -> np.ndarray:
        """The time column in s."""
        return self.si("time", "s")


def read_table(path: Path, time_series: bool) -> Table:
    """Read and check ``path`` (FitError on any bad entry)."""
    file = str(path)
    text = read_text(path)
    lines = [(n, ln) for n, ln in enumerate(text.splitlines(), start=1)]
    body = [(n, ln) for n, ln in lines if ln.strip() and not ln.lstrip().startswith("#")]
    if not body:
        raise FitError(file, "(header)", "empty file: expected a header 'signal [unit]' per column")
    header_line, header = body[0]
    names, units = [], []
    for cell in next(csv.reader(io.StringIO(header))):
        m = _HEADER.match(cell)
        if not m:
            raise FitError(
                file,
                cell.strip() or "(empty)",
                f"column '{cell.strip()}' has no unit: write "
                "'signal [unit]', e.g. 'myofibril.length [mm]'",
                header_line,
            )
        if m[1] in names:
            raise FitError(file, m[1], "column named twice", header_line)
        names.append(m[1])
        units.append(m[2])
    if time_series and names[0] != "time":
        raise FitError(
            file, names[0], "a time series' first column is 'time [s]' (any time unit)", header_line
        )
    if not time_series and "time" in names:
        raise FitError(
            file,
            "time",
            "a static table has no time column (one row per steady state)",
            header_line,
        )
    values, rows = [], []
    for n, ln in body[1:]:
        cells = next(csv.reader(io.StringIO(ln)))
        if len(cells) != len(names):
            raise FitError(
                file, "(row)", f"{len(cells)} values, expected {len(names)} ({', '.join(names)})", n
            )
        row = []
        for name, cell in zip(names, cells, strict=True):
            try:
                x = float(cell)
            except ValueError:
                raise FitError(file, name, f"'{cell.strip()}' is not a number", n) from None
            if not math.isfinite(x):
                raise FitError(
                    file,
                    name,
                    f"'{cell.strip()}': NaN or infinite values are not "
                    "allowed (drop the row, or leave it out)",
                    n,
                )
            row.append(x)
        values.append(row)
        rows.append(n)
    if len(values) < (2 if time_series else 1):
        raise FitError(
            file, "(rows)", f"{len(values)} data rows: a time series needs at least 2", header_line
        )
    arr = np.array(values, dtype=float)
    table = Table(
        file,
        {nm: (u, arr[:, j]) for j, (nm, u) in enumerate(zip(names, units, strict=True))},
        rows,
        header_line,
    )
    if time_series:
        t = table.time
        dt = np.diff(t)
        bad = np.flatnonzero(dt <= 0)
        if bad.size:
            k = int(bad[0]) + 1
            what = "duplicate time" if dt[bad[0]] == 0 else "time not increasing"
            raise FitError(
                file,
                "time",
                f"{what}: {table.columns['time'][1][k]:g} after "
                f"{table.columns['time'][1][k - 1]:g}; times must be strictly "
                "increasing",
                rows[k],
            )
    return table


def sampling_note(tables: dict[str, Table]) -> str:
    """The sampling intervals of the time series (different rates across files are
    allowed and stated)."""
    rates = {name: float(np.median(np.diff(t.time))) for name, t in tables.items()}
    if not rates:
        return ""
    distinct = sorted({round(v, 12) for v in rates.values()})
    parts = ", ".join(f"{n}: {1e3 * v:g} ms" for n, v in rates.items())
    return (
        "one sampling interval" if len(distinct) == 1 else "different sampling intervals (allowed)"
    ) + f": {parts}"
