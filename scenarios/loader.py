"""Read a scenario TOML file into a :class:`~sarcomere.scenarios.spec.Scenario`.

Every quantity is converted to SI with :func:`~sarcomere.dynamics.units.to_si`. Anything
wrong raises :class:`~sarcomere.dynamics.errors.ScenarioError` naming the file, the dotted
key and its line; unknown keys are listed with the valid ones and the closest match.
"""

from __future__ import annotations

import dataclasses
import math
import re
import tomllib
from collections.abc import Sequence
from importlib import resources
from importlib.resources.abc import Traversable
from pathlib import Path

import numpy as np

from sarcomere.dynamics.errors import ParameterError, ScenarioError
from sarcomere.dynamics.files import path_kind, read_text
from sarcomere.dynamics.units import si_unit, to_si

from .catalog import packaged_scenarios
from .keylines import key_lines, key_parts
from .signals import SIGNAL_TYPES, signal_from_spec
from .spec import (
    FIDELITIES,
    KNOWN_UNITS,
    MAX_VALUES,
    MAX_VALUES_CEILING,
    SI_UNITS,
    Included,
    KeyPath,
    MetricCheck,
    ModelSpec,
    OutputSpec,
    Scenario,
    SimulationSpec,
    SolverSpec,
    SweepAxis,
    describe,
    did_you_mean,
    dotted,
    line_of,
    unknown_key,
)

SECTIONS = (
    "scenario",
    "model",
    "parameters",
    "inputs",
    "sweep",
    "simulation",
    "solver",
    "outputs",
    "metrics",
    "control",
    "cosim",
)

_REQUIRED = object()
_NAME = re.compile(r"^[A-Za-z0-9_.-]+$")

# ---------------------------------------------------------------------------- resolution


def resolve_scenario(source: str | Path) -> Traversable:
    """Find a scenario: an existing file path, or the bare name of a packaged scenario.

    Parameters
    ----------
    source : str or pathlib.Path
        ``"path/to/file.toml"`` or a bare name such as ``"paper-static"``.

    Raises
    ------
    ScenarioError
        No such file, or no packaged scenario of that name (listing the packaged ones);
        a path that is not a regular file (a directory, a FIFO, a device) says what it is
        and is never opened.
    """
    path = Path(source)
    kind = path_kind(path)
    if kind is None:
        return path
    text = str(source)
    bare = not ("/" in text or "\\" in text or path.suffix == ".toml")
    packaged = packaged_scenarios()
    if bare and text in packaged:  # a folder named like a scene (an --out) does not hide it
        return packaged[text]
    if kind != "missing":
        raise ScenarioError(text, "scenario", f"is {kind}; expected a scenario TOML file")
    if not bare:
        raise ScenarioError(text, "scenario", "no such file")
    hint = did_you_mean(text, list(packaged))
    raise ScenarioError(
        text,
        "scenario",
        f"no such file or packaged scenario{hint} (packaged: {', '.join(packaged)})",
    )


def load_scenario(source: str | Path) -> Scenario:
    """Read and check a scenario given as a file path or a packaged scenario's name.

    Examples
    --------
    >>> load_scenario("paper-static").kind
    'static'
    """
    res = resolve_scenario(source)
    with resources.as_file(res) as path:
        try:
            text = read_text(path)
        except ValueError as exc:
            raise ScenarioError(str(path), "scenario", str(exc)) from None
        return parse_scenario(text, str(path))


# ---------------------------------------------------------------------------- parsing


class Reader:
    """Typed access to parsed TOML, turning every problem into a ScenarioError (of
    ``error_class``: a study's is a StudyError)."""

    def __init__(
        self,
        file: str,
        lines: dict[KeyPath, int],
        error_class: type[ScenarioError] = ScenarioError,
    ) -> None:
        self.file, self.lines, self.error_class = file, lines, error_class

    def error(self, path: KeyPath, message: str, key: str | None = None) -> ScenarioError:
        """An ``error_class`` at ``path`` (shown as ``key`` if given)."""
        where = key or dotted(path)
        return self.error_class(self.file, where, message, line_of(self.lines, path))

    def table(
        self,
        value: object,
        path: KeyPath,
        allowed: Sequence[str] | None = None,
        required: Sequence[str] = (),
    ) -> dict:
        """``value`` as a table, its keys checked against ``allowed`` (None: any)."""
        if not isinstance(value, dict):
            raise self.error(path, f"expected a table, got {value!r}")
        for key in value:
            if allowed is not None and key not in allowed:
                raise self.error((*path, key), unknown_key(key, allowed))
        for key in required:
            if key not in value:
                raise self.error(path, f"missing required key '{key}'")
        return value

    def text(self, tbl: dict, path: KeyPath, key: str, default: object = _REQUIRED) -> str:
        value = tbl.get(key, default)
        if value is _REQUIRED:
            raise self.error(path, f"missing required key '{key}'")
        if not isinstance(value, str):
            raise self.error((*path, key), f"expected a string, got {value!r}")
        return value

    def choice(
        self,
        tbl: dict,
        path: KeyPath,
        key: str,
        choices: Sequence[str],
        default: object = _REQUIRED,
    ) -> str:
        value = self.text(tbl, path, key, default)
        if value not in choices:
            hint = did_you_mean(value, list(choices))
            raise self.error((*path, key), f"'{value}' is not one of {', '.join(choices)}{hint}")
        return value

    def quantity(self, value: object, path: KeyPath, unit: str, bare_ok: bool = False) -> float:
        """``value`` in SI; a bare non-zero number of a dimensioned unit only if ``bare_ok``
        (the table states its ``unit``)."""
        try:
            return to_si(value, unit, dotted(path), bare_ok)
        except ParameterError as exc:
            raise self.error(path, describe(exc)) from None

    def opt_quantity(self, tbl: dict, path: KeyPath, key: str, unit: str) -> float | None:
        return None if key not in tbl else self.quantity(tbl[key], (*path, key), unit)

    def integer(self, tbl: dict, path: KeyPath, key: str, low: int, default=None) -> int | None:
        """``tbl[key]``, a whole number >= ``low`` (``default`` when absent)."""
        value = tbl.get(key, default)
        if value is None:
            return None
        if isinstance(value, bool) or not isinstance(value, int) or value < low:
            raise self.error((*path, key), f"{value!r}: expected an integer >= {low}")
        return value

    def number(self, value: object, path: KeyPath, minimum: float | None = None) -> float:
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise self.error(path, f"expected a number, got {value!r}")
        if minimum is not None and value < minimum:
            raise self.error(path, f"must be >= {minimum}")
        return float(value)

    def strings(self, value: object, path: KeyPath) -> tuple[str, ...]:
        if not (isinstance(value, list) and all(isinstance(v, str) for v in value)):
            raise self.error(path, f"expected a list of strings, got {value!r}")
        return tuple(value)

    def unit(self, tbl: dict, path: KeyPath, variable: str, any_si: bool = False) -> str:
        """The SI unit of ``variable``: the ``unit`` key, or a known default; ``any_si``:
        any unit of an SI unit's dimension ("kPa": a signal takes its values to SI)."""
        unit = self.text(tbl, path, "unit", KNOWN_UNITS.get(variable, _REQUIRED))
        if unit not in SI_UNITS and not (any_si and si_unit(unit)[0] in SI_UNITS):
            raise self.error((*path, "unit"), f"'{unit}' is not an SI unit ({', '.join(SI_UNITS)})")
        return unit


def _syntax_error(exc: tomllib.TOMLDecodeError, text: str, file: str) -> ScenarioError:
    match = re.search(r"at line (\d+)", str(exc))
    line = int(match[1]) if match else None
    message = re.sub(r"\s*\(at .*\)$", "", str(exc))
    lines = key_lines(text)
    before = [p for p, n in lines.items() if line and n <= line]
    key = dotted(max(before, key=lines.__getitem__)) if before else "(toml syntax)"
    return ScenarioError(file, key, f"TOML syntax error: {message}", line)


def parse_scenario(text: str, file: str = "<string>") -> Scenario:
    """Parse scenario TOML ``text``; ``file`` names it in errors and anchors relative paths.

    Raises
    ------
    ScenarioError
        Syntax error, unknown or missing key, wrong type, wrong dimension or bad value.
    """
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise _syntax_error(exc, text, file) from None
    return scenario_from_dict(data, file, key_lines(text))


def scenario_from_dict(
    data: dict, file: str = "<string>", lines: dict[KeyPath, int] | None = None
) -> Scenario:
    """Check parsed scenario TOML ``data`` (a study's base merged with its overrides);
    ``lines`` (key path -> line in ``file``) place its errors."""
    lines = {} if lines is None else lines
    r = Reader(file, lines)
    r.table(data, (), SECTIONS, required=("scenario",))
    head = r.table(data["scenario"], ("scenario",), ("name", "kind", "description"), ("kind",))
    stem = Path(file).stem if file != "<string>" else "scenario"
    name = r.text(head, ("scenario",), "name", stem)
    if not _NAME.match(name) or set(name) == {"."}:
        raise r.error(
            ("scenario", "name"),
            f"'{name}': use letters, digits, '_', '-' and '.' only, not only dots "
            "(it names the output folder)",
        )
    params, included = _scene_parameters(r, data.get("parameters", {}), Path(file).parent)
    return Scenario(
        name=name,
        kind=r.text(head, ("scenario",), "kind"),
        description=r.text(head, ("scenario",), "description", ""),
        model=_model(r, data.get("model", {})),
        parameters=params,
        inputs=_inputs(r, data.get("inputs", {}), Path(file).parent),
        sweep=_sweep(r, data.get("sweep", {})),
        simulation=_simulation(r, data["simulation"]) if "simulation" in data else None,
        solver=_solver(r, data.get("solver", {})),
        outputs=_outputs(r, data.get("outputs", {})),
        metrics=_metrics(r, data.get("metrics", {})),
        control=r.table(data.get("control", {}), ("control",)),
        cosim=r.table(data.get("cosim", {}), ("cosim",)),
        file=file,
        key_lines=lines,
        included=included,
    )


def _model(r: Reader, value: object) -> ModelSpec:
    path = ("model",)
    keys = ("name", "fidelity", "n", "material", "geometry", "options")
    tbl = r.table(value, path, keys)
    n = tbl.get("n", 1)
    if isinstance(n, bool) or not isinstance(n, int) or n < 1:
        raise r.error((*path, "n"), f"expected an integer >= 1, got {n!r}")
    default = ModelSpec()
    return ModelSpec(
        name=r.text(tbl, path, "name", default.name),
        fidelity=r.choice(tbl, path, "fidelity", FIDELITIES, default.fidelity),
        n=n,
        material=r.text(tbl, path, "material", default.material),
        geometry=r.text(tbl, path, "geometry") if "geometry" in tbl else None,
        options=r.table(tbl.get("options", {}), (*path, "options")),
    )


def _parameters(r: Reader, value: object, path: KeyPath) -> dict[str, object]:
    """Flatten nested tables into dotted names: ``[parameters.load] m`` -> ``load.m``."""
    out: dict[str, object] = {}
    for key, item in r.table(value, path).items():
        if isinstance(item, dict):
            for sub, v in _parameters(r, item, (*path, key)).items():
                out[f"{key}.{sub}"] = v
        elif isinstance(item, str | int | float):
            out[key] = item
        else:
            raise r.error((*path, key), f"expected a number or a string with a unit, got {item!r}")
    return out


# ---------------------------------------------------------------------------- parameter files

#: Tables of a parameter file (``docs/scenarios.md``; written by ``sarcomere fit``).
PARAMETER_FILE_TABLES = ("fitted", "parameters", "sources")


def _scene_parameters(r: Reader, value: object, base_dir: Path) -> tuple[dict, dict]:
    """``[parameters]`` with its ``include`` (a file, or a list of files, relative to the
    scene's folder; later files override earlier ones, the scene's own entries all)."""
    tbl = dict(r.table(value, ("parameters",)))
    files = tbl.pop("include", [])
    files = [files] if isinstance(files, str) else files
    if not (isinstance(files, list) and all(isinstance(f, str) for f in files)):
        raise r.error(("parameters", "include"), f"expected a file name, got {files!r}")
    params, included = {}, {}
    for name in files:
        path = Path(name) if Path(name).is_absolute() else base_dir / name
        if (kind := path_kind(path)) is not None:
            what = "no such file" if kind == "missing" else f"is {kind}"
            raise r.error(("parameters", "include"), f"'{name}': {what} ({path})")
        values, sources = read_parameter_file(path)
        params.update(values)
        included.update(sources)
    explicit = _parameters(r, tbl, ("parameters",))
    included = {k: v for k, v in included.items() if k not in explicit}
    return {**params, **explicit}, included


def read_parameter_file(path: str | Path) -> tuple[dict[str, object], dict[str, Included]]:
    """A parameter file's ``[parameters]`` (dotted name -> value as written) and, per
    entry, its :class:`~.spec.Included` (file, line, ``[sources]`` text).

    Raises
    ------
    ScenarioError
        Naming the parameter file: not a regular file, a TOML syntax error, an unknown
        table, a value that is neither a number nor a string, an ``include`` (files do
        not nest), a ``[sources]`` entry naming no parameter or not text.
    """
    file = str(path)
    try:
        text = read_text(Path(path))
    except ValueError as exc:
        raise ScenarioError(file, "parameters", str(exc)) from None
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise _syntax_error(exc, text, file) from None
    lines = key_lines(text)
    r = Reader(file, lines)
    r.table(data, (), PARAMETER_FILE_TABLES, required=("parameters",))
    r.table(data.get("fitted", {}), ("fitted",))
    if "include" in data["parameters"]:
        raise r.error(("parameters", "include"), "a parameter file cannot include another")
    values = _parameters(r, data["parameters"], ("parameters",))
    sources = r.table(data.get("sources", {}), ("sources",), list(values))
    for key in sources:
        r.text(sources, ("sources",), key)
    where = {".".join(p): n for p, n in lines.items()}
    included = {
        k: Included(file, where.get(f"parameters.{k}"), f"{file}: {sources.get(k, 'no source')}")
        for k in values
    }
    return values, included


def with_parameter_file(sc: Scenario, path: str | Path) -> Scenario:
    """``sc`` with the parameter file ``path`` included last (``--parameters FILE``): its
    entries override the scene's included ones; the scene's own ``[parameters]`` stay."""
    if (kind := path_kind(Path(path))) is not None:
        what = "no such file" if kind == "missing" else f"is {kind}"
        raise ScenarioError(str(path), "--parameters", f"{what}; expected a parameter TOML file")
    values, included = read_parameter_file(path)
    own = {k: v for k, v in sc.parameters.items() if k not in sc.included}
    inherited = {k: v for k, v in sc.parameters.items() if k in sc.included}
    new = {k: v for k, v in included.items() if k not in own}
    return dataclasses.replace(
        sc,
        parameters={**inherited, **values, **own},
        included={**sc.included, **new},
    )


def _inputs(r: Reader, value: object, base_dir: Path) -> dict:
    out = {}
    for name, item in r.table(value, ("inputs",)).items():
        path = ("inputs", name)
        spec = dict(r.table(item, path))
        cls = SIGNAL_TYPES[r.choice(spec, path, "type", list(SIGNAL_TYPES), _REQUIRED)]
        if why := _misspelt(spec, name):
            raise r.error(path, why)
        r.table(spec, path, ["type", "unit", *cls.spec_keys], cls.required_keys())
        unit = r.unit(spec, path, name, any_si=True)
        bare = "none" if spec.pop("unit", None) is None else "values"  # in the stated unit
        try:
            out[name] = signal_from_spec(spec, unit, dotted(path), base_dir, bare)
        except ParameterError as exc:
            raise r.error(key_parts(exc.name.split("[")[0]), describe(exc), exc.name) from None
    return out


def _misspelt(tbl: dict, name: str) -> str | None:
    """Why a signal or axis ``name`` without a ``unit`` is refused when it is named like a
    known variable (``presure``): an unknown name, not a missing unit."""
    hint = "unit" not in tbl and name not in KNOWN_UNITS and did_you_mean(name, [*KNOWN_UNITS])
    return f"unknown key '{name}'{hint} (or give its 'unit')" if hint else None


def _sweep(r: Reader, value: object) -> tuple[SweepAxis, ...]:
    axes = []
    for name, item in r.table(value, ("sweep",)).items():
        path = ("sweep", name)
        tbl = r.table(item, path, ("unit", "values", "start", "stop", "step"))
        if why := _misspelt(tbl, name):
            raise r.error(path, why)
        unit = r.unit(tbl, path, name)
        stated = "unit" in tbl  # bare numbers are in the stated unit
        if "values" in tbl:
            if {"start", "stop", "step"} & set(tbl):
                raise r.error(path, "give either 'values' or 'start', 'stop', 'step', not both")
            if not isinstance(tbl["values"], list) or not tbl["values"]:
                raise r.error((*path, "values"), "expected a non-empty list of quantities")
            values = [r.quantity(v, (*path, "values"), unit, stated) for v in tbl["values"]]
        else:
            r.table(tbl, path, required=("start", "stop", "step"))
            start, stop, step = (
                r.quantity(tbl[k], (*path, k), unit, stated) for k in ("start", "stop", "step")
            )
            if step <= 0 or stop < start:
                raise r.error((*path, "step"), "need step > 0 and stop >= start")
            count = (stop - start) / step
            if abs(count - round(count)) > 1e-9 * max(1.0, count):
                raise r.error((*path, "step"), "step must divide stop - start")
            values = list(np.linspace(start, stop, round(count) + 1))
        if np.any(np.diff(values) <= 0):
            raise r.error((*path, "values"), "values must be strictly increasing")
        axes.append(SweepAxis(name, unit, tuple(float(v) for v in values)))
    return tuple(axes)


def _simulation(r: Reader, value: object) -> SimulationSpec:
    path = ("simulation",)
    tbl = r.table(value, path, ("start_time", "stop_time", "output_interval"), ("stop_time",))
    start = r.opt_quantity(tbl, path, "start_time", "s") or 0.0
    stop = r.quantity(tbl["stop_time"], (*path, "stop_time"), "s")
    if stop <= start:
        raise r.error((*path, "stop_time"), f"must be later than start_time ({start} s)")
    interval = r.opt_quantity(tbl, path, "output_interval", "s")
    if interval is not None and interval <= 0:
        raise r.error((*path, "output_interval"), "must be > 0 s")
    return SimulationSpec(stop, interval, start)


def _solver(r: Reader, value: object) -> SolverSpec:
    path = ("solver",)
    tbl = dict(r.table(value, path))
    method = r.text(tbl, path, "method") if "method" in tbl else None
    tols = {}
    for key in ("rtol", "atol"):
        tols[key] = r.opt_quantity(tbl, path, key, "1")
        if tols[key] is not None and tols[key] <= 0:
            raise r.error((*path, key), "must be > 0")
    step = r.opt_quantity(tbl, path, "step", "s")
    if step is not None and step <= 0:
        raise r.error((*path, "step"), "must be > 0 s")
    rest = {k: v for k, v in tbl.items() if k not in ("method", "rtol", "atol", "step")}
    return SolverSpec(method, tols["rtol"], tols["atol"], step, rest)


def _outputs(r: Reader, value: object) -> OutputSpec:
    path = ("outputs",)
    tbl = r.table(value, path, ("signals", "tolerance", "plots", "max_values"))
    signals = r.strings(tbl.get("signals", []), (*path, "signals"))
    tolerance = r.opt_quantity(tbl, path, "tolerance", "1")
    if tolerance is not None and tolerance <= 0:
        raise r.error((*path, "tolerance"), "must be > 0")
    plots = {
        group: r.strings(names, (*path, "plots", group))
        for group, names in r.table(tbl.get("plots", {}), (*path, "plots")).items()
    }
    return OutputSpec(signals, tolerance, plots, _max_values(r, tbl.get("max_values", MAX_VALUES)))


def _max_values(r: Reader, value: object) -> float:
    """``[outputs] max_values``: a whole number in ``[1, MAX_VALUES_CEILING]`` (nan, inf
    or a fraction would disable or blur the size guard)."""
    path = ("outputs", "max_values")
    ok = isinstance(value, int | float) and not isinstance(value, bool)
    if not (ok and math.isfinite(value) and value == round(value)):
        raise r.error(
            path, f"{value!r} is not a whole number (allowed: 1 to {MAX_VALUES_CEILING:g})"
        )
    if not 1 <= value <= MAX_VALUES_CEILING:
        raise r.error(
            path,
            f"{value:g} is outside [1, {MAX_VALUES_CEILING:g}] values ({MAX_VALUES_CEILING:g} "
            f"values are {MAX_VALUES_CEILING * 8 / 1e9:g} GB in memory)",
        )
    return float(value)


def _metrics(r: Reader, value: object) -> tuple[MetricCheck, ...]:
    checks = []
    for name, item in r.table(value, ("metrics",)).items():
        path = ("metrics", name)
        if not isinstance(item, dict):
            checks.append(MetricCheck(name, r.number(item, path)))
            continue
        tbl = r.table(item, path, ("reference", "rtol", "atol", "source"), ("reference",))
        numbers = {
            key: r.number(tbl[key], (*path, key), minimum)
            for key, minimum in (("reference", None), ("rtol", 0.0), ("atol", 0.0))
            if key in tbl
        }
        checks.append(MetricCheck(name, source=r.text(tbl, path, "source", ""), **numbers))
    return tuple(checks)
