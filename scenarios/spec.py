"""The scenario schema: frozen dataclasses holding a parsed scenario file in SI units.

A scenario is data (see ``docs/scenarios.md``): what to model, which inputs drive it, what
to sweep or simulate, with which solver, and what to report. :mod:`.loader` builds these
objects from TOML; the runners of each ``kind`` read them.
"""

from __future__ import annotations

import difflib
import math
import re
import warnings
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from types import MappingProxyType
from typing import TYPE_CHECKING

from sarcomere.dynamics.errors import ParameterError, ScenarioError
from sarcomere.dynamics.schema import FIDELITIES as MODEL_LEVELS
from sarcomere.dynamics.schema import MAX_VALUES, WITHOUT_MODEL
from sarcomere.dynamics.units import to_si

if TYPE_CHECKING:
    from sarcomere.dynamics.modeling.model import Model
    from sarcomere.dynamics.signals import Signal

#: Allowed values of ``[model] fidelity``.
FIDELITIES = ("paper", *MODEL_LEVELS, *WITHOUT_MODEL, "auto")

#: SI units of well-known input and sweep variables; other variables state ``unit``.
KNOWN_UNITS: Mapping[str, str] = MappingProxyType(
    {"pressure": "Pa", "load.m": "kg", "load.F": "N", "time": "s"}
)

#: Largest ``[outputs] max_values`` a scenario may set: 1e9 values are 8 GB in memory
#: (and about 21 GB of CSV); the size guard cannot be switched off.
MAX_VALUES_CEILING = 1e9

#: SI units a signal or sweep axis may declare with ``unit``.
SI_UNITS = ("1", "Pa", "m", "kg", "N", "s", "rad", "Hz", "K", "m^3", "kg/s", "N/m", "J", "W")

KeyPath = tuple[str, ...]


class ScenarioWarning(UserWarning):
    """A setting that runs but is probably not what was meant (a 50 kg load on an APS);
    names the file, the key, its line and the value."""


_BARE_KEY = re.compile(r"^[A-Za-z0-9_-]+$")


def dotted(path: KeyPath) -> str:
    """Write a key path as TOML does: ``("parameters", "load.m")`` -> ``parameters."load.m"``."""
    return ".".join(p if _BARE_KEY.match(p) else f'"{p}"' for p in path)


def did_you_mean(word: str, choices: Sequence[str]) -> str:
    """``"; did you mean 'x'?"`` for the closest of ``choices``, or ``""``."""
    close = difflib.get_close_matches(word, choices, n=1)
    return f"; did you mean '{close[0]}'?" if close else ""


def unknown_key(key: str, allowed: Sequence[str]) -> str:
    """Message for an unknown key: the closest valid key, and all valid keys."""
    return f"unknown key '{key}'{did_you_mean(key, allowed)} (valid keys: {', '.join(allowed)})"


def describe(exc: ParameterError) -> str:
    """A ParameterError's message without its ``parameter 'name' =`` prefix."""
    return str(exc).removeprefix(f"parameter '{exc.name}' = ")


def quantity(sc: Scenario, value: object, path: KeyPath, unit: str, low: float | None = None):
    """``value`` (a scene key at ``path``; a bare non-zero number refused) in SI ``unit``,
    finite and >= ``low``; else ``sc``'s error at ``path``."""
    try:
        v = to_si(value, unit, ".".join(path), bare_ok=False)
    except ParameterError as exc:
        raise sc.error(path, describe(exc)) from None
    if not math.isfinite(v) or (low is not None and v < low):
        raise sc.error(path, f"{value!r} is outside [{low:g}, inf) {unit}")
    return v


def line_of(key_lines: Mapping[KeyPath, int], path: KeyPath) -> int | None:
    """Line of ``path``, or of its closest enclosing key or table; None if unknown."""
    for k in range(len(path), 0, -1):
        if path[:k] in key_lines:
            return key_lines[path[:k]]
    return None


def _freeze(obj: object, *names: str) -> None:
    """Replace the mapping fields ``names`` of a frozen dataclass by read-only copies."""
    for name in names:
        object.__setattr__(obj, name, MappingProxyType(dict(getattr(obj, name))))


@dataclass(frozen=True)
class ModelSpec:
    """``[model]``: which system, at which fidelity.

    Parameters
    ----------
    name : str
        The modelled system, e.g. ``"myofibril"`` (a chain of ``n`` APS).
    fidelity : str
        One of :data:`FIDELITIES`; default ``"full"``. ``"auto"`` picks the smallest level
        meeting ``[outputs] tolerance`` (transients only).
    n : int
        Number of units (APS) in series, >= 1.
    material : str
        Material slug, e.g. ``"dragonskin_30"``.
    geometry : str or None
        Geometry set name of the paper's model (kind "static"), e.g. ``"experimental"``;
        None if not given (the other kinds take their geometry from ``[parameters]``).
    options : mapping
        Model-specific switches, e.g. the paper model's options; passed through.
    """

    name: str = "myofibril"
    fidelity: str = "full"
    n: int = 1
    material: str = "dragonskin_30"
    geometry: str | None = None
    options: Mapping[str, object] = field(default_factory=dict)

    def __post_init__(self) -> None:
        _freeze(self, "options")


@dataclass(frozen=True)
class SweepAxis:
    """One ``[sweep.<name>]`` axis.

    Parameters
    ----------
    name : str
        Swept variable, e.g. ``"pressure"`` or ``"load.m"``.
    unit : str
        SI unit of ``values``.
    values : tuple of float
        Strictly increasing values, in ``unit``.
    """

    name: str
    unit: str
    values: tuple[float, ...]


@dataclass(frozen=True)
class SimulationSpec:
    """``[simulation]``: the time span of a transient run.

    Parameters
    ----------
    stop_time : float
        End time, s.
    output_interval : float or None
        Spacing of the output grid, s; None lets the runner choose.
    start_time : float
        Start time, s.
    """

    stop_time: float
    output_interval: float | None = None
    start_time: float = 0.0


@dataclass(frozen=True)
class SolverSpec:
    """``[solver]``: integrator or root-finder settings, passed through to the runner.

    Parameters
    ----------
    method : str or None
        Solver name, e.g. ``"idas"``, ``"cvodes"``, ``"rk4"``; None for the runner's default.
    rtol, atol : float or None
        Relative and absolute tolerances (absolute in the states' SI units).
    step : float or None
        Fixed or maximum step, s.
    options : mapping
        Any other keys of ``[solver]``, unconverted.
    """

    method: str | None = None
    rtol: float | None = None
    atol: float | None = None
    step: float | None = None
    options: Mapping[str, object] = field(default_factory=dict)

    def __post_init__(self) -> None:
        _freeze(self, "options")


@dataclass(frozen=True)
class OutputSpec:
    """``[outputs]``: what to write and how accurate it must be.

    Parameters
    ----------
    signals : tuple of str
        Signals to write and plot; empty means all the runner returns.
    tolerance : float or None
        Relative accuracy needed (``"1 %"`` -> 0.01); guides ``fidelity = "auto"``.
    plots : mapping of str to tuple of str
        Figure name -> signals drawn together (same unit); empty groups signals by unit.
    max_values : float
        Largest result a run may keep (points x signals, 8 bytes each in memory); a run
        estimated above it is refused before computing.
    """

    signals: tuple[str, ...] = ()
    tolerance: float | None = None
    plots: Mapping[str, tuple[str, ...]] = field(default_factory=dict)
    max_values: float = MAX_VALUES

    def __post_init__(self) -> None:
        _freeze(self, "plots")


@dataclass(frozen=True)
class MetricCheck:
    """One ``[metrics]`` entry: a reference value a computed metric is compared with.

    Parameters
    ----------
    name : str
        Metric name, ending in its unit (``theta_rest_deg``).
    reference : float
        Reference value, in the unit the name ends with.
    rtol : float
        Relative tolerance of the comparison.
    atol : float
        Absolute tolerance, in the metric's unit.
    source : str
        Where the reference comes from (free text).
    """

    name: str
    reference: float
    rtol: float = 0.01
    atol: float = 0.0
    source: str = ""

    def passes(self, value: float) -> bool:
        """True if ``value`` is within ``atol + rtol |reference|`` of the reference."""
        return abs(value - self.reference) <= self.atol + self.rtol * abs(self.reference)


@dataclass(frozen=True)
class Included:
    """Where an included ``[parameters]`` entry comes from (``[parameters] include`` or
    ``--parameters FILE``): the parameter file, the entry's line in it, and its
    ``[sources]`` text (what it was fitted to)."""

    file: str
    line: int | None
    source: str


@dataclass(frozen=True)
class Scenario:
    """A parsed scenario, every quantity in SI.

    Parameters
    ----------
    name : str
        Scenario name (defaults to the file stem); names the output folder.
    kind : str
        Runner kind, e.g. ``"static"``; see :func:`sarcomere.scenarios.runner.register_runner`.
    description : str
        One line shown by ``sarcomere list``.
    model : ModelSpec
    parameters : mapping of str to object
        Parameter overrides, dotted name -> value as written (numbers or strings with
        units), for ``ParameterSet.with_overrides``: the included files' entries with the
        file's own ``[parameters]`` on top.
    inputs : mapping of str to Signal
    sweep : tuple of SweepAxis
        The first axis is the index of each result; further axes give one result each.
    simulation : SimulationSpec or None
    solver : SolverSpec
    outputs : OutputSpec
    metrics : tuple of MetricCheck
    control : mapping
        ``[control]`` as written (kind "closed_loop" reads it, see
        :mod:`sarcomere.scenarios.control`); empty if absent.
    cosim : mapping
        ``[cosim]`` as written (kind "cosim" reads it, see :mod:`sarcomere.scenarios.cosim`);
        empty if absent.
    file : str
        Scenario file path, or a label such as ``"<string>"``.
    key_lines : mapping of tuple to int
        Key path -> line in ``file``, for error messages; see :meth:`error`.
    included : mapping of str to Included
        The entries of ``parameters`` taken from a parameter file (not overridden by the
        scene's own ``[parameters]``): their file, line and source.
    """

    name: str
    kind: str
    description: str = ""
    model: ModelSpec = field(default_factory=ModelSpec)
    parameters: Mapping[str, object] = field(default_factory=dict)
    inputs: Mapping[str, Signal] = field(default_factory=dict)
    sweep: tuple[SweepAxis, ...] = ()
    simulation: SimulationSpec | None = None
    solver: SolverSpec = field(default_factory=SolverSpec)
    outputs: OutputSpec = field(default_factory=OutputSpec)
    metrics: tuple[MetricCheck, ...] = ()
    control: Mapping[str, object] = field(default_factory=dict)
    cosim: Mapping[str, object] = field(default_factory=dict)
    file: str = "<string>"
    key_lines: Mapping[KeyPath, int] = field(default_factory=dict, repr=False, compare=False)
    included: Mapping[str, Included] = field(default_factory=dict)

    def __post_init__(self) -> None:
        _freeze(self, "parameters", "inputs", "control", "cosim", "key_lines", "included")

    @property
    def base_dir(self) -> Path:
        """Folder of the scenario file: relative paths inside it start here."""
        return Path(self.file).parent

    def axis(self, name: str) -> SweepAxis:
        """The sweep axis ``name``; ScenarioError naming ``[sweep]`` if there is none."""
        for ax in self.sweep:
            if ax.name == name:
                return ax
        have = ", ".join(ax.name for ax in self.sweep) or "none"
        raise self.error(("sweep",), f"needs a sweep axis '{name}' (axes: {have})")

    def error(self, path: KeyPath, message: str) -> ScenarioError:
        """A ScenarioError for ``path`` with this file and the key's line.

        Examples
        --------
        >>> raise Scenario("x", "static").error(("model", "n"), "must be 1")
        Traceback (most recent call last):
        ...
        sarcomere.dynamics.errors.ScenarioError: <string>: key 'model.n': must be 1
        """
        return ScenarioError(self.file, dotted(path), message, line_of(self.key_lines, path))

    def warn(self, path: KeyPath, message: str) -> None:
        """Issue a :class:`ScenarioWarning` ``key '<path>': message`` located at the
        scenario file and the key's line (shown as ``file:line: ScenarioWarning: ...``
        with that line of the file below it)."""
        line = line_of(self.key_lines, path) or 0
        text = f"key '{dotted(path)}': {message}"
        warnings.warn_explicit(text, ScenarioWarning, self.file, line)

    def refuse_unused(self, *sections: str) -> None:
        """Refuse any of ``sections`` the file gives: this kind would ignore it.

        ``sections`` are ``"inputs"``, ``"sweep"``, ``"simulation"``, ``"solver"``,
        ``"outputs.tolerance"``, ``"control"`` and ``"cosim"``.
        """
        given = {
            "inputs": bool(self.inputs),
            "sweep": bool(self.sweep),
            "simulation": self.simulation is not None,
            "solver": self.solver != SolverSpec(),
            "outputs.tolerance": self.outputs.tolerance is not None,
            "control": bool(self.control),
            "cosim": bool(self.cosim),
        }
        for section in sections:
            if given[section]:
                raise self.error(
                    tuple(section.split(".")),
                    f"kind '{self.kind}' does not use [{section}]; remove it",
                )

    def parameter_error(self, name: str, message: str) -> ScenarioError:
        """A ScenarioError for the ``[parameters]`` entry ``name`` (a dotted name).

        Finds the line whether the file wrote ``"geometry.h_ch" = ...`` or
        ``[parameters.geometry] h_ch = ...``; an included entry is placed in its
        parameter file.
        """
        if name in self.included:
            inc = self.included[name]
            return ScenarioError(inc.file, dotted(("parameters", name)), message, inc.line)
        return self.error(self.parameter_path(name), message)

    def parameter_sources(self) -> dict[str, str]:
        """Each parameter's source when any comes from a parameter file (``summary.json``):
        the file's ``[sources]`` text, or the scene file's ``[parameters]``; {} if none
        is included."""
        if not self.included:
            return {}
        own = f"[parameters] of {self.file}"
        return {k: self.included[k].source if k in self.included else own for k in self.parameters}

    def parameter_path(self, name: str) -> KeyPath:
        """The key path of the ``[parameters]`` entry ``name`` as the file wrote it."""
        flat = f"parameters.{name}"
        return next((p for p in self.key_lines if ".".join(p) == flat), ("parameters", name))


def check_overrides(sc: Scenario | None, overrides: dict, model: Model) -> None:
    """Refuse a name that is not a parameter of the model, a bare non-zero number for a
    dimensioned one and a text that is not a quantity of its unit, in the file (nothing
    without a scenario)."""
    if sc is None:
        return
    for key, raw in overrides.items():
        var = model.variables.get(key)
        if key not in model.param_names:
            hint = did_you_mean(key, model.param_names)
            why = f"{len(model.param_names)} parameters of model '{model.name}'"
            raise sc.parameter_error(key, f"unknown key '{key}'{hint} ({why})")
        try:
            to_si(raw, var.unit, key, bare_ok=False)
        except ParameterError as exc:
            raise sc.parameter_error(key, describe(exc)) from None
