"""Scenario kinds on the lumped dynamic model: "equilibrium" sweeps and "transient" runs.

``[model]`` for ``name = "myofibril"``: ``n``, ``material``, ``fidelity`` (one of
:data:`~sarcomere.dynamics.assemblies.FIDELITIES`, or ``"auto"`` for transients), and
``[model.options]``:

- ``setup``: ``"hanging"`` (a load hangs from the chain end, default) or ``"isometric"``
  (the chain end is held by a force sensor on a fixture);
- ``load``: the hanging mass ("50 g", hanging only); ``regulator_tau``: the regulator lag;
- ``fixture_stiffness`` ("2000 N/m", default rigid) and ``fixture_gap`` ("1 mm"),
  isometric only;
- ``flow_law``: the restriction's law, ``"iso6358"`` (exact, default) or ``"smooth"`` (C1,
  for optimisers; :data:`~sarcomere.dynamics.assemblies.FLOW_LAWS`).

Nothing is ignored: an option the set-up does not read, ``[model] geometry``, a section the
kind does not use, ``n`` above the level's measured limit (:data:`N_LIMITS`), a pressure
command outside the regulator's ``[0, p_max]`` and an output above ``[outputs]
max_values`` are refused before anything is solved.

``[parameters]``: ``aps.<field>`` sets an :class:`~sarcomere.dynamics.components.aps.APSParams`
field for every unit ("aps.k_s" = "400 N/m", "aps.thermal" = "adiabatic"; the material is
``[model] material``); "regulator.p_max" sets the regulator's range (built into the model:
the input's bound and the clamp); any other key is a model parameter path ("load.m",
"myofibril.tube1.C"; "load.m" beside ``[model.options] load`` is refused). Dimensioned
values need their unit (a bare ``50`` is refused), and an implausible load or APS geometry
gets a :class:`~.spec.ScenarioWarning` (the rule of
:mod:`sarcomere.dynamics.plausibility`, the Python API's too).
"""

from __future__ import annotations

import dataclasses
import math
import re
import time
import warnings
from pathlib import Path

import casadi as cs
import numpy as np

from sarcomere.dynamics import fidelity as ladder
from sarcomere.dynamics.assemblies import (
    FIDELITIES,
    FLOW_LAWS,
    GROUPS,
    N_LIMITS,
    N_WHY,
    hanging_load,
    isometric,
)
from sarcomere.dynamics.components.aps import APSParams
from sarcomere.dynamics.equilibrium import Equilibrium, solve_equilibrium
from sarcomere.dynamics.errors import ParameterError
from sarcomere.dynamics.modeling.model import Model
from sarcomere.dynamics.plausibility import (
    PLAUSIBLE_LOAD_KG,
    PlausibilityWarning,
    implausible_aps,
    implausible_load,
)
from sarcomere.dynamics.results import Result
from sarcomere.dynamics.signals import Table
from sarcomere.dynamics.simulation.simulate import PausableRun, SolverSettings, simulate
from sarcomere.dynamics.units import to_si

from .output import RunOutput, quantity_tag
from .runner import register_runner
from .spec import Scenario, SimulationSpec, describe, did_you_mean, dotted, unknown_key

P_CMD = "regulator.p_cmd"
OPTIONS = {  # option -> (SI unit, "" for text; lowest allowed value; inclusive)
    "setup": ("", None, True),
    "load": ("kg", 0.0, True),
    "regulator_tau": ("s", 0.0, False),
    "fixture_stiffness": ("N/m", 0.0, False),
    "fixture_gap": ("m", 0.0, True),
    "flow_law": ("", None, True),
}
INPUT_ALIASES = {"pressure": P_CMD}
#: Set-up -> options the other set-up reads and this one would ignore.
SETUP_ONLY = {"hanging": ("fixture_stiffness", "fixture_gap"), "isometric": ("load",)}


#: Where a set-up argument's ParameterError (``exc.name``) is written in the scenario.
_BUILD_KEYS = {
    "regulator.tau": ("model", "options", "regulator_tau"),
    "regulator_tau": ("model", "options", "regulator_tau"),
    "load_kg": ("model", "options", "load"),
    "fixture_stiffness": ("model", "options", "fixture_stiffness"),
    "fixture_gap": ("model", "options", "fixture_gap"),
}


@dataclasses.dataclass(frozen=True)
class Binding:
    """A scenario's model settings in SI: what to build and the parameter overrides.

    ``scenario`` (if given) names the file, key and line of a setting the build refuses.
    """

    setup: str
    n: int
    aps: APSParams
    load_kg: float
    regulator_tau: float
    fixture_stiffness: float | None
    fixture_gap: float
    overrides: dict
    flow_law: str = "iso6358"
    regulator_p_max: float | None = None
    scenario: Scenario | None = dataclasses.field(default=None, compare=False, repr=False)

    def build(
        self,
        fidelity: str,
        n: int | None = None,
        flow_law: str | None = None,
        saturate: bool = True,
        groups: int = GROUPS,
    ) -> Model:
        """Flatten the model for one fidelity level (optionally another n, another flow law,
        an unclamped regulator for optimisers, or another number of groups of the
        "grouped" level)."""
        n = self.n if n is None else n
        common = {
            "regulator_tau": self.regulator_tau,
            "saturate": saturate,
            "flow_law": self.flow_law if flow_law is None else flow_law,
            "groups": groups,
            "regulator_p_max": self.regulator_p_max,
        }
        try:
            with warnings.catch_warnings():
                if self.scenario is not None:  # bind warned at the scene's keys
                    warnings.simplefilter("ignore", PlausibilityWarning)
                if self.setup == "isometric":
                    model = isometric(
                        n, self.aps, fidelity, self.fixture_stiffness, self.fixture_gap, **common
                    )
                else:
                    model = hanging_load(n, self.aps, self.load_kg, fidelity, **common)
        except ParameterError as exc:
            if self.scenario is None:
                raise
            sc = self.scenario
            path = _BUILD_KEYS.get(exc.name)
            raise (
                sc.error(path, describe(exc))
                if path
                else sc.parameter_error(exc.name, describe(exc))
            ) from None
        self._check_units(model)
        return model

    def _check_units(self, model: Model) -> None:
        """Refuse a bare non-zero number for a dimensioned model parameter in the file."""
        if self.scenario is None:
            return
        for key, raw in self.overrides.items():
            var = model.variables.get(key)
            if var is None or isinstance(raw, str):
                continue
            try:
                to_si(raw, var.unit, key, bare_ok=False)
            except ParameterError as exc:
                raise self.scenario.parameter_error(key, describe(exc)) from None


def _options(sc: Scenario) -> dict:
    """``[model.options]`` in SI, each checked against :data:`OPTIONS`."""
    opts = {}
    for key, raw in sc.model.options.items():
        if key not in OPTIONS:
            raise sc.error(("model", "options", key), unknown_key(key, list(OPTIONS)))
        unit, low, inclusive = OPTIONS[key]
        try:
            opts[key] = raw if unit == "" else to_si(raw, unit, key, bare_ok=False)
        except ParameterError as exc:
            raise sc.error(("model", "options", key), describe(exc)) from None
        if low is not None and not (opts[key] >= low if inclusive else opts[key] > low):
            interval = f"[{low:g}, inf)" if inclusive else f"({low:g}, inf)"
            raise sc.error(("model", "options", key), f"{raw!r} is outside {interval} {unit}")
    setup = opts.setdefault("setup", "hanging")
    if setup not in ("hanging", "isometric"):
        raise sc.error(("model", "options", "setup"), f"'{setup}': use 'hanging' or 'isometric'")
    flow_law = opts.setdefault("flow_law", "iso6358")
    if flow_law not in FLOW_LAWS:
        raise sc.error(
            ("model", "options", "flow_law"), f"'{flow_law}': use {' or '.join(FLOW_LAWS)}"
        )
    for key in SETUP_ONLY[setup]:
        if key in opts:
            raise sc.error(
                ("model", "options", key), f"set-up '{setup}' does not use '{key}'; remove it"
            )
    return opts


def _aps_parameter(sc: Scenario, key: str, name: str, raw: object) -> object:
    """One ``[parameters] aps.<name>`` in SI (a numeric field) or as text (``thermal``)."""
    numeric = set(APSParams.numeric_fields())
    if name == "material":
        raise sc.parameter_error(
            key, "set the material with [model] material (it also sets C1, C2, C3)"
        )
    if name == "thermal":
        if not isinstance(raw, str):
            raise sc.parameter_error(key, f"expected a string, got {raw!r}")
        return raw
    if name not in numeric:
        raise sc.parameter_error(key, unknown_key(name, sorted(numeric | {"thermal"})))
    try:
        return to_si(raw, APSParams.unit(name), key, bare_ok=False)
    except ParameterError as exc:
        raise sc.parameter_error(key, describe(exc)) from None


def _warn_implausible(sc: Scenario, opts: dict, model_over: dict, aps: APSParams) -> None:
    """A ScenarioWarning for a load or an APS parameter far outside what the model was
    made for (the rule of :mod:`sarcomere.dynamics.plausibility`)."""
    loads = [(("model", "options", "load"), opts.get("load"))]
    if "load.m" in model_over:
        loads.append((sc.parameter_path("load.m"), _si_or_none(model_over["load.m"], "kg")))
    for path, kg in loads:
        if kg is not None and (why := implausible_load(kg)):
            sc.warn(path, why)
    for name, why in implausible_aps(aps).items():
        sc.warn(sc.parameter_path(f"aps.{name}"), why)


def _si_or_none(raw: object, unit: str) -> float | None:
    try:
        return to_si(raw, unit)
    except ParameterError:
        return None  # the model's own check reports it


def bind(sc: Scenario) -> Binding:
    """Read ``[model]`` and ``[parameters]`` (see the module docstring)."""
    if sc.model.name != "myofibril":
        raise sc.error(("model", "name"), f"'{sc.model.name}' is not a model; use 'myofibril'")
    if sc.model.geometry is not None:
        raise sc.error(
            ("model", "geometry"),
            f"kind '{sc.kind}' does not use a geometry set (the paper model's, kind 'static'); "
            "set APS dimensions with [parameters] aps.<field>",
        )
    opts = _options(sc)
    aps_over, model_over = {}, {}
    p_max = None
    for key, raw in sc.parameters.items():
        group, _, name = key.partition(".")
        if group == "aps":
            aps_over[name] = _aps_parameter(sc, key, name, raw)
        elif key == "regulator.p_max":  # the range is structural: the input's bound too
            try:
                p_max = to_si(raw, "Pa", key, bare_ok=False)
            except ParameterError as exc:
                raise sc.parameter_error(key, describe(exc)) from None
            if not p_max > 0:
                raise sc.parameter_error(key, f"{raw!r} is outside (0, inf) Pa")
        else:
            model_over[key] = raw
    if "load.m" in model_over and "load" in sc.model.options:
        raise sc.parameter_error(
            "load.m",
            "[parameters] load.m and [model.options] load both set the hanging mass; keep "
            "one (load.m is the whole end mass with the 1 g hook, load the payload alone)",
        )
    try:
        aps = APSParams.from_paper(sc.model.material, **aps_over)
    except ParameterError as exc:
        raise sc.parameter_error(f"aps.{exc.name}", describe(exc)) from None
    _warn_implausible(sc, opts, model_over, aps)
    return Binding(
        opts["setup"],
        sc.model.n,
        aps,
        opts.get("load", 0.0),
        opts.get("regulator_tau", 0.05),
        opts.get("fixture_stiffness"),
        opts.get("fixture_gap", 0.0),
        model_over,
        opts["flow_law"],
        p_max,
        sc,
    )


def fidelity_level(sc: Scenario, allow_auto: bool) -> str:
    """``[model] fidelity``, checked: a level of the set-ups (or ``"auto"`` where
    allowed)."""
    fid = sc.model.fidelity
    allowed = FIDELITIES + (("auto",) if allow_auto else ())
    if fid not in allowed:
        raise sc.error(("model", "fidelity"), f"'{fid}' is not one of {', '.join(allowed)}")
    return fid


def command_range(model: Model, overrides: dict) -> tuple[float, float]:
    """The pressure commands the regulator follows, Pa gauge: ``[0, p_max]``.

    The regulator clamps its command to ``[0, p_max]``; a command outside would run as the
    clamped value under the requested one's name. The bounds of the input
    ``regulator.p_cmd`` narrow the range where they are finite.
    """
    var = model.variables[P_CMD]
    p_max = model.parameters(overrides)[model.index("regulator.p_max")[1]]
    return max(var.low, 0.0), min(var.high, float(p_max))


def _range_error(sc: Scenario, path: tuple, value: float, rng: tuple, when: str = ""):
    low, high = (v / 1e6 for v in rng)
    return sc.error(
        path,
        f"{distinct(value / 1e6, (low, high))} MPa{when} is outside the pressure regulator's "
        f"range [{low:g}, {high:g}] MPa (regulator.p_cmd; it would clamp the command)",
    )


def distinct(value: float, bounds: tuple[float, ...]) -> str:
    """``value`` with as few significant digits (at least 6) as keep it apart from each of
    ``bounds`` it differs from: 0.6000001 next to 0.6 is not shown as "0.6"."""
    for digits in range(6, 18):
        text = f"{value:.{digits}g}"
        if all(float(text) != b for b in bounds if b != value):
            return text
    return repr(value)


def _check_commands(sc: Scenario, model: Model, overrides: dict, inputs: dict, grid) -> None:
    """Refuse a pressure command outside the regulator's range, at its first time (on the
    output grid, the breakpoints and every row of a table)."""
    if P_CMD not in inputs:
        return
    rng = command_range(model, overrides)
    sig = inputs[P_CMD]
    bps = sig.breakpoints(grid[0], grid[-1]) if hasattr(sig, "breakpoints") else []
    rows = np.asarray(sig.times) if isinstance(sig, Table) else np.empty(0)
    rows = rows[(rows >= grid[0]) & (rows <= grid[-1])]
    t = np.unique(np.concatenate([grid, bps, rows]))
    values = np.asarray(sig(t), dtype=float) * np.ones_like(t)
    bad = np.flatnonzero((values < rng[0]) | (values > rng[1]))
    if bad.size:
        name = next(k for k, v in sc.inputs.items() if v is sig)
        when = f" at t = {t[bad[0]]:g} s"
        raise _range_error(sc, ("inputs", name), float(values[bad[0]]), rng, when)


def _solve(sc: Scenario, model: Model, pressure: float, over: dict, guess):
    try:
        return solve_equilibrium(model, {P_CMD: pressure}, over, guess=guess)
    except ParameterError as exc:
        raise sc.parameter_error(exc.name, describe(exc)) from None


# --- kind "equilibrium" -------------------------------------------------------------
def run_equilibrium(sc: Scenario, out_dir: Path) -> RunOutput:
    """Sweep pressure (first axis) for each value of the other axes (``n`` or ``load``).

    Isometric: the tared force ``force`` = F(P) - F(0) [N]. Hanging: ``length`` [m],
    ``length_ratio`` = L / L' with L' = L(0 MPa, no load, same n) and the paper's
    actuation strain ``strain`` = (L[P, load] - L[0, load]) / L[0, 0].
    """
    sc.refuse_unused("inputs", "simulation", "solver", "outputs.tolerance", "control", "cosim")
    b = bind(sc)
    fid = fidelity_level(sc, allow_auto=False)
    check_n(sc, ("model", "n"), b.n, fid)
    if not sc.sweep or sc.sweep[0].name != "pressure":
        raise sc.error(("sweep",), "the first sweep axis must be 'pressure'")
    pressures = np.asarray(sc.sweep[0].values)
    others = sc.sweep[1:]
    if len(others) > 1 or (others and others[0].name not in ("n", "load")):
        raise sc.error(("sweep",), "at most one more axis, 'n' or 'load'")
    axis = others[0] if others else None
    if axis is not None and axis.name == "n":
        if ("model", "n") in sc.key_lines or sc.model.n != 1:
            raise sc.error(("model", "n"), "[sweep.n] sets n; remove it")
        for v in axis.values:
            check_n(sc, ("sweep", "n", "values"), v, fid)
    if axis is not None and axis.name == "load" and b.setup == "isometric":
        raise sc.error(("sweep", "load"), "the isometric set-up holds no load; sweep 'n' instead")
    if axis is not None and axis.name == "load" and "load" in sc.model.options:
        raise sc.error(("model", "options", "load"), "[sweep.load] sets the load; remove it")
    if axis is not None and axis.name == "load" and "load.m" in b.overrides:
        raise sc.parameter_error("load.m", "[sweep.load] sets the load; remove it")
    if axis is not None and axis.name == "load" and min(axis.values) < 0:
        bad = min(axis.values)
        raise sc.error(("sweep", "load", "values"), f"{bad * 1e3:g} g: a load is >= 0 kg")
    if axis is not None and axis.name == "load" and max(axis.values) > PLAUSIBLE_LOAD_KG[1]:
        sc.warn(
            ("sweep", "load"),
            f"{max(axis.values):.6g} kg is above the plausible {PLAUSIBLE_LOAD_KG[1]:g} kg "
            "(the paper's loads are 0 to 100 g)",
        )
    cases = axis.values if axis else (None,)
    check_output_size(sc, len(pressures) * len(cases), 5, ("sweep", "pressure"))
    results, metrics = {}, {}
    for value in cases:
        n = round(value) if axis is not None and axis.name == "n" else b.n
        load = value if axis is not None and axis.name == "load" else b.load_kg
        prefix = f"n{n}_" if axis is not None and axis.name == "n" else ""
        key, res, mets = _equilibrium_case(sc, b, fid, pressures, n, load, prefix)
        results[key] = res
        metrics.update(mets)
    return RunOutput(
        sc.name,
        fid,
        "damped Newton on the exact sparse Jacobian, continuation",
        metrics=metrics,
        results=results,
        extra={"aps_params": _aps_dict(b.aps), "setup": b.setup},
    )


def check_n(sc: Scenario, path: tuple, n: float, fidelity: str) -> None:
    """Refuse an n that is not a whole number >= 1, above the level's :data:`N_LIMITS`,
    or (grouped) not above 2 GROUPS."""
    if n != round(n) or n < 1:
        raise sc.error(path, f"{n:g} is not a whole number of units >= 1")
    level = "full" if fidelity == "auto" else fidelity  # auto may end at full
    if fidelity == "grouped" and n <= 2 * GROUPS:
        raise sc.error(
            path,
            f"grouped needs n > {2 * GROUPS}: at n = {n:g} its {GROUPS} groups of two "
            "half-groups are the chain itself (use 'full', which names every unit)",
        )
    if n > N_LIMITS[level]:
        others = ", ".join(f"{k} {v}" for k, v in N_LIMITS.items())
        raise sc.error(
            path,
            f"n = {n:g} is above {N_LIMITS[level]}, the longest chain the '{level}' level "
            f"handles ({N_WHY[level]}); limits: {others}",
        )


def _equilibrium_case(sc, b: Binding, fid, pressures, n, load, prefix=""):
    """One curve against pressure; ``prefix`` (``"n2_"``) names the swept n in its key
    and metrics when n is an axis."""
    model = b.build(fid, n)
    over = dict(b.overrides)
    rng = command_range(model, over)
    for p in pressures:
        if not rng[0] <= p <= rng[1]:
            raise _range_error(sc, ("sweep", "pressure"), float(p), rng)
    if b.setup == "hanging":
        over["load.m"] = model.variables["load.m"].value - b.load_kg + load
    rest = _solve(sc, model, 0.0, {**over, **_no_load(model, b)}, None)
    base = _solve(sc, model, 0.0, over, rest)
    rows, guess = [], base
    for p in pressures:
        guess = _solve(sc, model, float(p), over, guess)
        rows.append(guess)
    chamber = np.array([e["myofibril.aps1.chamber.p_gauge"] for e in rows])
    tag_p = quantity_tag(pressures[-1] / 1e6, "MPa")
    if b.setup == "isometric":
        force = np.array([e["sensor.f"] for e in rows]) - base["sensor.f"]
        key = f"n{n}"
        res = Result(
            "pressure",
            "Pa",
            pressures,
            {"force": force, "chamber_pressure": chamber},
            {"force": "N", "chamber_pressure": "Pa"},
        )
        return key, res, {f"force_n{n}_{tag_p}_N": float(force[-1])}
    L = np.array([e["myofibril.length"] for e in rows])
    L00, L0 = rest["myofibril.length"], base["myofibril.length"]
    grams = quantity_tag(load * 1e3, "g")
    res = Result(
        "pressure",
        "Pa",
        pressures,
        {
            "length": L,
            "length_ratio": L / L00,
            "strain": (L - L0) / L00,
            "chamber_pressure": chamber,
        },
        {"length": "m", "length_ratio": "1", "strain": "1", "chamber_pressure": "Pa"},
    )
    mets = {
        f"rest_length_n{n}_mm": L00 * 1e3,
        f"length_ratio_{prefix}{grams}_0MPa": L0 / L00,
        f"length_ratio_{prefix}{grams}_{tag_p}": float(L[-1] / L00),
        f"strain_{prefix}{grams}_{tag_p}": float((L[-1] - L0) / L00),
    }
    return f"{prefix}load_{grams}", res, mets


def _no_load(model: Model, b: Binding) -> dict:
    if b.setup != "hanging":
        return {}
    return {"load.m": model.variables["load.m"].value - b.load_kg}


def _aps_dict(p: APSParams) -> dict:
    return dataclasses.asdict(p)


# --- kind "transient" ---------------------------------------------------------------
def _inputs(sc: Scenario, model: Model) -> dict:
    """The scenario's signals by model input; an input given twice (by its alias and its
    full name) is refused naming both keys."""
    out, given = {}, {}
    for name, sig in sc.inputs.items():
        target = INPUT_ALIASES.get(name, name)
        if target not in model.input_names:
            raise sc.error(
                ("inputs", name), unknown_key(name, [*INPUT_ALIASES, *model.input_names])
            )
        if target in given:
            raise sc.error(
                ("inputs", name),
                f"[inputs.{given[target]}] already drives '{target}'; keep one of "
                f"[inputs.{given[target]}] and [inputs.{dotted((name,))}]",
            )
        given[target] = dotted((name,))
        unit = model.variables[target].unit
        if sig.unit != unit:
            raise sc.error(
                ("inputs", name, "unit"),
                f"the signal is in '{sig.unit}' but input '{target}' is in '{unit}'",
            )
        out[target] = sig
    return out


#: CasADi's names of settings that ``[solver]`` spells its own way.
SUNDIALS_ALIASES = {"abstol": "atol", "reltol": "rtol", "max_num_steps": "max_steps"}


def _settings(sc: Scenario, model: Model) -> SolverSettings:
    """``[solver]`` as SolverSettings; every key is checked before anything runs: the
    settings' own fields (``max_steps``) become fields, the rest must be options the
    method accepts (CVODES and IDAS options are checked against CasADi's)."""
    s = sc.solver
    method = s.method or "cvodes"
    if method == "cvodes" and model.nz:  # a DAE level (static_chain): same BDF, DAE form
        method = "idas"
    kw = {k: v for k, v in (("rtol", s.rtol), ("atol", s.atol), ("step", s.step)) if v}
    options = dict(s.options)
    if "max_steps" in options:
        steps = options.pop("max_steps")
        if isinstance(steps, bool) or not isinstance(steps, int) or steps < 1:
            raise sc.error(("solver", "max_steps"), f"{steps!r}: expected an integer >= 1")
        kw["max_steps"] = steps
    try:
        settings = SolverSettings(method=method, options=tuple(options.items()), **kw)
    except ParameterError as exc:
        raise sc.error(("solver", exc.name.split(".")[-1]), describe(exc)) from None
    if method in ("cvodes", "idas"):
        for key, value in options.items():
            _check_sundials_option(sc, method, key, value)
    return settings


def _check_sundials_option(sc: Scenario, method: str, key: str, value: object) -> None:
    """Refuse an option CasADi's ``method`` integrator would reject, in one line."""
    path = ("solver", key)
    if key in SUNDIALS_ALIASES:
        raise sc.error(path, f"set it as [solver] {SUNDIALS_ALIASES[key]}")
    x = cs.SX.sym("x")
    try:
        cs.integrator("probe", method, {"x": x, "ode": -x}, 0.0, [1.0], {key: value})
    except RuntimeError as exc:
        text = str(exc)
        if "Unknown option" in text:
            close = re.findall(r'> "([^"]+)"', text) + list(SUNDIALS_ALIASES.values())
            hint = did_you_mean(key, close)
            raise sc.error(path, f"'{key}' is not a setting or {method} option{hint}") from None
        lines = [ln.strip() for ln in text.strip().splitlines() if ln.strip()]
        raise sc.error(path, f"{value!r} refused by {method}: {lines[-1][:200]}") from None


def _default_signals(model: Model) -> list[str]:
    keep = ("regulator.p_cmd", "regulator.p_out", "myofibril.length", "load.s", "sensor.f")
    suffix = (".chamber.p_gauge", ".expansion.s", ".T", ".e")
    return [
        n
        for n in model.signal_names
        if n in keep or (n.startswith("myofibril.") and n.endswith(suffix))
    ]


def _intervals(sim: SimulationSpec) -> tuple[float, int]:
    """Output spacing, s (default 500 intervals), and whole intervals in the span."""
    span = sim.stop_time - sim.start_time
    dt = sim.output_interval or span / 500
    return dt, math.floor(span / dt * (1 + 1e-12))


def time_grid(sim: SimulationSpec) -> np.ndarray:
    """Output times from ``start_time`` to ``stop_time``, s: ``output_interval`` apart
    (default 500 intervals), both ends included."""
    dt, count = _intervals(sim)
    return np.unique(np.append(sim.start_time + dt * np.arange(count + 1), sim.stop_time))


#: Bytes per value of a CSV file (``repr`` of a float and a comma), for the estimate.
CSV_BYTES_PER_VALUE = 21


def check_output_size(sc: Scenario, points: int, columns: int, path: tuple) -> None:
    """Refuse a result above ``[outputs] max_values`` before computing it, with numbers;
    ``path`` names the key that sets the number of points."""
    values = points * columns
    limit = sc.outputs.max_values
    if values > limit:
        raise sc.error(
            path,
            f"the run would keep up to {points} points x {columns} signals = {values:.3g} values "
            f"({values * 8 / 1e6:.0f} MB in memory, about "
            f"{values * CSV_BYTES_PER_VALUE / 1e6:.0f} MB of CSV), above [outputs] max_values "
            f"= {limit:.3g}; use fewer points or raise max_values",
        )


def _prepare(sc: Scenario, b: Binding, model: Model) -> tuple[dict, list[str], np.ndarray]:
    """The inputs, the signals to keep and the output grid of a transient, checked."""
    inputs = _inputs(sc, model)
    sim = sc.simulation
    if sim is None:
        raise sc.error(("simulation",), "a transient needs [simulation] stop_time")
    wanted = list(dict.fromkeys(_default_signals(model) + list(sc.outputs.signals)))
    missing = [n for n in wanted if n not in model.signal_names]
    if missing:
        raise sc.error(("outputs", "signals"), f"unknown signals {missing}")
    points = _intervals(sim)[1] + 2  # at most: the stop time may add one
    check_output_size(sc, points, len(wanted) + 1, ("simulation", "output_interval"))
    grid = time_grid(sim)
    _check_commands(sc, model, b.overrides, inputs, grid)
    return inputs, wanted, grid


def _simulate(
    sc: Scenario,
    b: Binding,
    fid: str,
    model: Model | None = None,
    guess: Equilibrium | None = None,
):
    """Build (unless given) and simulate from the start equilibrium, found by
    continuation from ``guess`` (an equilibrium of ``model``) where one is known."""
    model = b.build(fid) if model is None else model
    inputs, wanted, grid = _prepare(sc, b, model)
    sim = sc.simulation
    u0 = {k: float(sig(sim.start_time)) for k, sig in inputs.items()}
    start = solve_equilibrium(model, u0, b.overrides, guess=guess)
    res = simulate(
        model,
        sim.stop_time,
        inputs,
        b.overrides,
        x0=start.x,
        z0=start.z,
        settings=_settings(sc, model),
        t_out=grid,
        signals=wanted,
        max_values=sc.outputs.max_values,
    )
    sel = res.select(wanted)
    sel.meta.update(res.meta)
    return model, sel


def run_transient(sc: Scenario, out_dir: Path) -> RunOutput:
    """Simulate from the equilibrium at the inputs' start values (see module docstring).

    ``fidelity = "auto"``: the cheapest level predicted within ``[outputs] tolerance``
    of "full" runs, and only that one (see :func:`choose_fidelity`).
    """
    sc.refuse_unused("sweep", "control", "cosim")
    if sc.model.fidelity != "auto":
        sc.refuse_unused("outputs.tolerance")
    b = bind(sc)
    fid = fidelity_level(sc, allow_auto=True)
    check_n(sc, ("model", "n"), b.n, fid)
    extra = {"aps_params": _aps_dict(b.aps), "setup": b.setup}
    metrics = {}
    if fid == "auto":
        fid, res, report = choose_fidelity(sc, b)
        extra["fidelity_auto"] = report
        metrics["fidelity_predicted_error"] = report["predicted_error"][fid]
    else:
        _, res = _simulate(sc, b, fid)
    found, left_out = transient_metrics(res)
    metrics.update(found)
    if left_out:
        extra["metrics_left_out"] = left_out
    return RunOutput(
        sc.name, fid, res.meta["method"], metrics=metrics, results={"main": res}, extra=extra
    )


#: Smallest net length stroke (|final - initial|, m) with a rise time: below it the
#: change is not told from numerical noise (rtol 1e-6 on a 0.1 m chain is 0.1 um); the
#: packaged steps and ramps move about 15 mm.
RISE_MIN_STROKE_M = 1e-5


def transient_metrics(res: Result) -> tuple[dict[str, float], dict[str, str]]:
    """Final and initial length and pressure, rise time, slack time, solver statistics;
    and the metrics left out, each with why (``rise_time_10_90_s`` of a run that does not
    move, or whose output grid does not resolve the rise)."""
    m, left_out = {}, {}
    if "myofibril.length" in res:
        L = res["myofibril.length"]
        m["length_initial_mm"] = float(L[0] * 1e3)
        m["length_final_mm"] = float(L[-1] * 1e3)
        rise, why = rise_time(res.index, L, RISE_MIN_STROKE_M, "m")
        if rise is None:
            left_out["rise_time_10_90_s"] = why
        else:
            m["rise_time_10_90_s"] = rise
    chamber = next(n for n in res.names if n.endswith(".chamber.p_gauge"))  # the top unit
    m["pressure_final_kPa"] = res.final(chamber) / 1e3
    if "sensor.f" in res:
        m["force_final_N"] = res.final("sensor.f")
    stretches = [n for n in res.names if n.endswith(".e") and ".actin" in n]
    if stretches:
        slack = np.any(np.array([res[n] < 0 for n in stretches]), axis=0)
        m["slack_time_s"] = float(np.sum(np.diff(res.index) * slack[:-1]))
    m["solver_steps"] = float(res.meta.get("n_steps", math.nan))
    return m, left_out


def rise_time(
    t: np.ndarray, y: np.ndarray, min_stroke: float, unit: str = ""
) -> tuple[float | None, str]:
    """10-90 % rise time [s] of ``y(t)`` from ``y[0]`` to ``y[-1]``, on the linearly
    interpolated signal: the first times ``y`` crosses ``y0 + 0.1 dy`` and ``y0 + 0.9 dy``
    (``dy = y[-1] - y[0]``), each interpolated between its two samples.

    Returns ``(None, why)`` when ``|dy| < min_stroke`` (``unit``: the signal's, for the
    message) or when both crossings fall in one sample interval (the grid does not
    resolve the rise); else ``(rise, "")``.
    """
    t, y = np.asarray(t, float), np.asarray(y, float)
    dy = y[-1] - y[0]
    if not abs(dy) >= min_stroke:
        return None, (
            f"the net stroke |final - initial| = {abs(dy):.3g} {unit} is below the noise "
            f"level {min_stroke:g} {unit}: no rise to time"
        )
    frac = (y - y[0]) / dy
    crossings = []
    for level in (0.1, 0.9):
        i = int(np.argmax(frac >= level))  # >= 1: frac[0] = 0; frac[-1] = 1 reaches it
        w = (level - frac[i - 1]) / (frac[i] - frac[i - 1])
        crossings.append((i, t[i - 1] + w * (t[i] - t[i - 1])))
    (i10, t10), (i90, t90) = crossings
    if i10 == i90:
        return None, (
            f"the output grid ({t[i90] - t[i90 - 1]:.3g} s there) does not resolve the rise: "
            "both crossings fall in one interval"
        )
    return float(t90 - t10), ""


def choose_fidelity(sc: Scenario, b: Binding) -> tuple[str, Result, dict]:
    """Bind the scene to the auto policy (:func:`sarcomere.dynamics.fidelity.choose`:
    the cheapest level predicted within ``[outputs] tolerance``, default 1 %, of
    "full", over ``[outputs] signals``, default ``myofibril.length``) and run the
    chosen level alone; at n <= 6 the full run is handed to the policy to run first, in
    pieces it may pause between ("full first"). The auto run's wall time is in the
    report."""
    tic = time.perf_counter()
    if sc.simulation is None:
        raise sc.error(("simulation",), "a transient needs [simulation] stop_time")
    grid = time_grid(sc.simulation)
    first = "symmetric" if ladder.grouped_units(b.n) < b.n else "full"
    cheap = b.build(first)  # the first model the ladder needs: inputs checked on it
    inputs = _inputs(sc, cheap)
    _check_commands(sc, cheap, b.overrides, inputs, grid)
    care = list(sc.outputs.signals) or ["myofibril.length"]
    # what linear and equilibrium_path return: full's signals (they run at n <= 6 only)
    wanted = _prepare(sc, b, cheap)[1] if first == "full" else care
    full = _pausable_full(sc, b, cheap, inputs, wanted, grid) if first == "full" else None
    models = {(first, GROUPS): cheap}

    def build(level: str, groups: int = GROUPS) -> Model:
        key = (level, groups if level == "grouped" else GROUPS)
        if key not in models:
            models[key] = b.build(level, groups=groups)
        return models[key]

    scene = ladder.Scene(
        n=b.n,
        build=build,
        inputs=inputs,
        t_out=grid,
        params=b.overrides,
        signals=care,
        named={*care, *(n for names in sc.outputs.plots.values() for n in names)},
        keep=wanted,
        tolerance=sc.outputs.tolerance if sc.outputs.tolerance is not None else 0.01,
        full=full,
    )
    choice = ladder.choose(scene)
    res = choice.result
    if res is None:
        res = _simulate(sc, b, choice.level, choice.model, choice.start)[1]
    res.require_finite(choice.level)
    report = choice.report(scene)
    report["wall_time_s"] = time.perf_counter() - tic
    return choice.level, res, report


def _pausable_full(sc: Scenario, b: Binding, model: Model, inputs, wanted, grid) -> PausableRun:
    """The full model's run from the start equilibrium as auto's "full first" runs it
    (:data:`~sarcomere.dynamics.fidelity.policy.FULL_FIRST_BUDGET_S`), not yet started."""
    u0 = {k: float(sig(grid[0])) for k, sig in inputs.items()}
    start = solve_equilibrium(model, u0, b.overrides)
    settings = _settings(sc, model)
    return PausableRun(model, inputs, b.overrides, start.x, start.z, settings, grid, wanted)


register_runner("equilibrium", run_equilibrium)
register_runner("transient", run_transient)
