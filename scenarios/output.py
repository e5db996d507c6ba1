"""What a run returns (:class:`RunOutput`) and the files it writes.

Files in the output folder, all values in SI:

- ``summary.json``: scenario, fidelity, solver, wall time, metrics, reference checks,
  the parameters (with ``parameter_sources`` when a parameter file is included: what each
  value was fitted to), provenance (sarcomere version, UTC time, scenario file) and the
  list of files;
- ``timeseries.csv`` (one result) or ``timeseries_<result>.csv`` (one per result of a
  multi-curve sweep): index column first, header cells ``name [unit]``.
"""

from __future__ import annotations

import json
import math
import re
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from sarcomere.dynamics.errors import SolverError
from sarcomere.dynamics.results import Result

from .catalog import version

if TYPE_CHECKING:  # the spec imports the model library: not needed to write files
    from .spec import Scenario


@dataclass
class RunOutput:
    """Everything a scenario run produced.

    Parameters
    ----------
    scenario : str
        Scenario name.
    fidelity : str
        Fidelity level actually used (``"auto"`` resolved).
    solver : str
        Solver actually used, e.g. ``"closed form"`` or ``"idas"``.
    wall_time_s : float
        Wall time of the kind runner (model build and solve, not file writing), s; set by
        :func:`sarcomere.scenarios.runner.run`.
    metrics : dict of str to float
        Named scalar results; each name ends in its unit (``theta_rest_deg``, ``h_m_mm``,
        ``force_0p1MPa_N``; a dimensionless name ends in what it is, e.g. ``_ratio``).
    results : dict of str to Result
        Result name (file-safe, e.g. ``"main"`` or ``"load_50g"``) to named signals.
    extra : dict
        Anything else worth recording in ``summary.json`` (JSON-serialisable values).
    incomplete : str, optional
        Why the run stopped before its end (``summary.json``: ``"status": "incomplete"``
        and this ``reason``); None for a run that finished.
    """

    scenario: str
    fidelity: str
    solver: str
    wall_time_s: float = math.nan
    metrics: dict[str, float] = field(default_factory=dict)
    results: dict[str, Result] = field(default_factory=dict)
    extra: dict = field(default_factory=dict)
    incomplete: str | None = None


def quantity_tag(value: float, unit: str) -> str:
    """A metric-name fragment for a value: ``quantity_tag(0.1, "MPa")`` -> ``"0p1MPa"``.

    Parameters
    ----------
    value : float
        The value in ``unit`` (not SI).
    unit : str
        Unit written after the number (``"MPa"``, ``"g"``).

    Examples
    --------
    >>> quantity_tag(0.1, "MPa"), quantity_tag(50, "g"), quantity_tag(-2.5, "mm")
    ('0p1MPa', '50g', 'm2p5mm')
    """
    return f"{value:g}".replace("-", "m").replace(".", "p") + unit


def check_finite(output: RunOutput) -> None:
    """Refuse NaN or infinite metrics and signals.

    Raises
    ------
    SolverError
        Naming the metric, or the result, signal, count and first bad index value.
    """
    for name, value in output.metrics.items():
        if not math.isfinite(value):
            raise SolverError(f"metric '{name}' is {value}")
    for key, result in output.results.items():
        for name, values in {result.index_name: result.index, **result.signals}.items():
            bad = ~np.isfinite(values)
            if bad.any():
                first = result.index[np.argmax(bad)]
                raise SolverError(
                    f"result '{key}': signal '{name}' has {int(bad.sum())} non-finite values "
                    f"(first at {result.index_name} = {first:.6g} {result.index_unit})",
                    time=float(first) if result.index_unit == "s" else None,
                )


def _jsonable(obj: object) -> object:
    """``obj`` with numpy scalars and arrays as Python values, NaN as None, the rest as str."""
    if isinstance(obj, dict):
        return {str(k): _jsonable(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple | np.ndarray):
        return [_jsonable(v) for v in obj]
    if isinstance(obj, bool | str) or obj is None:
        return obj
    if isinstance(obj, int | np.integer):
        return int(obj)
    if isinstance(obj, float | np.floating):
        return float(obj) if math.isfinite(obj) else None
    return str(obj)


def timeseries_name(key: str, count: int) -> str:
    """File name of result ``key`` when ``count`` results are written."""
    if count == 1:
        return "timeseries.csv"
    return f"timeseries_{re.sub(r'[^A-Za-z0-9._=-]+', '_', key)}.csv"


#: CSV bytes per value (a float's ``repr`` and a comma), for size estimates.
CSV_BYTES_PER_VALUE = 21

#: Rows formatted and written at a time: memory stays flat however long the run.
CSV_CHUNK_ROWS = 10_000


def write_timeseries(results: dict[str, Result], out_dir: Path) -> list[Path]:
    """Write each result as CSV: index first, then its signals; header ``name [unit]``.
    Values are Python's shortest round-trip ``repr``, written in chunks of
    :data:`CSV_CHUNK_ROWS` rows.

    Returns
    -------
    list of pathlib.Path
        The files written, in the order of ``results``.
    """
    paths = []
    for key, result in results.items():
        path = out_dir / timeseries_name(key, len(results))
        table = np.column_stack([result.index, *result.signals.values()]).astype(float)
        header = [f"{result.index_name} [{result.index_unit}]"]
        header += [f"{name} [{result.units[name]}]" for name in result.signals]
        with path.open("w", encoding="utf-8") as f:
            f.write(",".join(header) + "\n")
            for start in range(0, len(table), CSV_CHUNK_ROWS):
                rows = table[start : start + CSV_CHUNK_ROWS].tolist()
                f.writelines(repr(row)[1:-1].replace(", ", ",") + "\n" for row in rows)
        paths.append(path)
    return paths


def write_summary(
    output: RunOutput, scenario: Scenario, out_dir: Path, files: list[Path], checks: dict
) -> Path:
    """Write ``summary.json``.

    Parameters
    ----------
    output : RunOutput
    scenario : Scenario
    out_dir : pathlib.Path
    files : list of pathlib.Path
        Other files written by the run (listed by name).
    checks : dict
        Metric name -> ``{"value", "reference", "rtol", "atol", "ok"}``.

    Returns
    -------
    pathlib.Path
    """
    status = {} if output.incomplete is None else {"status": "incomplete"}
    summary = {
        **status,
        "scenario": output.scenario,
        "kind": scenario.kind,
        "fidelity": output.fidelity,
        "solver": output.solver,
        "wall_time_s": output.wall_time_s,
        "metrics": output.metrics,
        "checks": checks,
        "model": {
            "name": scenario.model.name,
            "n": scenario.model.n,
            "material": scenario.model.material,
            "geometry": scenario.model.geometry,
            "options": dict(scenario.model.options),
        },
        "parameters": dict(scenario.parameters),
        **({"parameter_sources": src} if (src := scenario.parameter_sources()) else {}),
        "results": {
            key: {
                "file": timeseries_name(key, len(output.results)),
                "index": f"{r.index_name} [{r.index_unit}]",
                "points": len(r.index),
                "signals": {name: r.units[name] for name in r.signals},
                "meta": r.meta,
            }
            for key, r in output.results.items()
        },
        "extra": output.extra,
        **({} if output.incomplete is None else {"reason": output.incomplete}),
        "files": sorted(p.name for p in files),
        "scenario_file": scenario.file,
        "sarcomere_version": version(),
        "created_utc": datetime.now(UTC).isoformat(timespec="seconds"),
    }
    path = out_dir / "summary.json"
    path.write_text(json.dumps(_jsonable(summary), indent=2) + "\n", encoding="utf-8")
    return path
