"""The public scene binding: a scene's ``[model]``, ``[parameters]``, inputs, solver and
output grid bound to the lumped dynamic model, and :func:`run`, the one simulation of a
bound scene from its start equilibrium.

Every kind on the dynamic model goes through it (the equilibrium sweep,
:mod:`.equilibrium`; the transient, :mod:`.transient`; the closed loop, co-simulation,
``linearize``, ``export-fmu``) and so does the study evaluator
(:mod:`.explore.evaluate`). The API, for code that binds scenes (fitting, robots):

- :func:`bind` -> :class:`Binding` (``Binding.build(level)`` -> ``Model``);
- :func:`fidelity_level`, :func:`check_n`: the level and the chain length, checked;
- :func:`inputs`: the scene's signals by model input (the ``pressure`` alias, units);
- :func:`solver_settings`: ``[solver]`` as :class:`SolverSettings`, every key checked;
- :func:`time_grid`, :func:`prepare`: the output grid; inputs, signals and grid checked;
- :func:`run`: simulate a model from its equilibrium at the inputs' first values;
  :func:`simulate_scene`: the same for a bound scene at one level.

``[model]`` for ``name = "myofibril"``: ``n``, ``material``, ``fidelity`` (one of
:data:`~sarcomere.dynamics.assemblies.FIDELITIES`, or ``"auto"`` for transients), and
``[model.options]``:

- ``setup``: ``"hanging"`` (a load hangs from the chain end, default) or ``"isometric"``
  (the chain end is held by a force sensor on a fixture);
- ``load``: the hanging mass ("50 g", hanging only); ``regulator_tau``: the regulator lag;
- ``fixture_stiffness`` ("2000 N/m", default rigid) and ``fixture_gap`` ("1 mm"),
  isometric only;
- ``flow_law``: the restriction's law, ``"iso6358"`` (exact, default) or ``"smooth"`` (C1,
  for optimisers; :data:`~sarcomere.dynamics.assemblies.FLOW_LAWS`);
- ``supply`` (``"regulator"``, default, or ``"valve_pwm"``) and ``valve`` (its options),
  transients only: :mod:`.valve_supply`.

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
import warnings
from collections.abc import Mapping, Sequence

import numpy as np

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
from sarcomere.dynamics.errors import ParameterError, SarcomereError
from sarcomere.dynamics.modeling.model import Model
from sarcomere.dynamics.plausibility import (
    PlausibilityWarning,
    implausible_aps,
    implausible_load,
)
from sarcomere.dynamics.results import Result
from sarcomere.dynamics.schema import WITHOUT_MODEL
from sarcomere.dynamics.signals import Table
from sarcomere.dynamics.simulation import radau, sundials
from sarcomere.dynamics.simulation.simulate import MAX_VALUES, SolverSettings, simulate
from sarcomere.dynamics.simulation.simulator import Simulator
from sarcomere.dynamics.units import to_si

from .output import CSV_BYTES_PER_VALUE
from .robot_binding import ROBOT_MODELS, RobotBinding, robot_options
from .spec import (
    Scenario,
    SimulationSpec,
    check_overrides,
    describe,
    did_you_mean,
    dotted,
    unknown_key,
)
from .valve_supply import supply_options

P_CMD = "regulator.p_cmd"
OPTIONS = {  # option -> (SI unit, "" for text; lowest allowed value; inclusive)
    "setup": ("", None, True),
    "load": ("kg", 0.0, True),
    "regulator_tau": ("s", 0.0, False),
    "fixture_stiffness": ("N/m", 0.0, False),
    "fixture_gap": ("m", 0.0, True),
    "flow_law": ("", None, True),
    "supply": ("", None, True),
    "valve": ("", None, True),
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
    supply: str = "regulator"
    valve: object = None  # ValveOptions with supply = "valve_pwm"

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
            "supply": self.supply,
            "valve": self.valve,
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
        check_overrides(self.scenario, self.overrides, model)
        return model


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
    """Read ``[model]`` and ``[parameters]`` (see the module docstring; the robot models
    :data:`~.robot_binding.ROBOT_MODELS` in :mod:`.robot_binding`)."""
    if sc.model.name not in ("myofibril", *ROBOT_MODELS):
        models = ", ".join(("myofibril", *ROBOT_MODELS))
        raise sc.error(("model", "name"), f"'{sc.model.name}' is not a model; use one of {models}")
    if sc.model.geometry is not None:
        raise sc.error(
            ("model", "geometry"),
            f"kind '{sc.kind}' does not use a geometry set (the paper model's, kind 'static'); "
            "set APS dimensions with [parameters] aps.<field>",
        )
    robot = sc.model.name in ROBOT_MODELS
    opts = robot_options(sc) if robot else _options(sc)
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
    _warn_implausible(sc, {} if robot else opts, model_over, aps)
    if robot:
        return RobotBinding(sc.model.name, sc.model.n, aps, opts, model_over, p_max, sc)
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
        **supply_options(sc, opts, p_max),
    )


def fidelity_level(sc: Scenario, allow_auto: bool, without_model: bool = False) -> str:
    """``[model] fidelity``, checked: a level of the set-ups (or ``"auto"``, and the
    levels without a model of their own, :data:`WITHOUT_MODEL`, where allowed)."""
    fid = sc.model.fidelity
    allowed = FIDELITIES + (WITHOUT_MODEL if without_model else ())
    allowed += ("auto",) if allow_auto else ()
    if fid not in allowed:
        raise sc.error(("model", "fidelity"), f"'{fid}' is not one of {', '.join(allowed)}")
    return fid


def command_range(model: Model, overrides: dict, name: str = P_CMD) -> tuple[float, float]:
    """The pressure commands the regulator of the input ``name`` follows, Pa gauge:
    ``[0, p_max]``.

    The regulator clamps its command to ``[0, p_max]``; a command outside would run as the
    clamped value under the requested one's name. The bounds of the input narrow the
    range where they are finite.
    """
    var = model.variables[name]
    p_max = model.parameters(overrides)[model.index(name.replace("p_cmd", "p_max"))[1]]
    return max(var.low, 0.0), min(var.high, float(p_max))


def range_error(sc: Scenario, path: tuple, value: float, rng: tuple, when: str = ""):
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


def check_commands(sc: Scenario, model: Model, overrides: dict, inputs: dict, grid) -> None:
    """Refuse a pressure command outside its regulator's range, at its first time (on the
    output grid, the breakpoints and every row of a table)."""
    for name, sig in inputs.items():
        if name.endswith(".p_cmd"):
            _check_command(sc, command_range(model, overrides, name), sig, grid)


def _check_command(sc: Scenario, rng: tuple, sig, grid) -> None:
    bps = sig.breakpoints(grid[0], grid[-1]) if hasattr(sig, "breakpoints") else []
    rows = np.asarray(sig.times) if isinstance(sig, Table) else np.empty(0)
    rows = rows[(rows >= grid[0]) & (rows <= grid[-1])]
    t = np.unique(np.concatenate([grid, bps, rows]))
    values = np.asarray(sig(t), dtype=float) * np.ones_like(t)
    bad = np.flatnonzero((values < rng[0]) | (values > rng[1]))
    if bad.size:
        name = next(k for k, v in sc.inputs.items() if v is sig)
        when = f" at t = {t[bad[0]]:g} s"
        raise range_error(sc, ("inputs", name), float(values[bad[0]]), rng, when)


def check_n(sc: Scenario, path: tuple, n: float, fidelity: str) -> None:
    """Refuse an n that is not a whole number >= 1, above the level's :data:`N_LIMITS`,
    or (grouped) not above 2 GROUPS."""
    if n != round(n) or n < 1:
        raise sc.error(path, f"{n:g} is not a whole number of units >= 1")
    level = "full" if fidelity in ("auto", *WITHOUT_MODEL) else fidelity  # on full
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


def aps_dict(p: APSParams) -> dict:
    """The APS fields of ``p`` (``summary.json``'s ``aps_params``)."""
    return dataclasses.asdict(p)


def scene_inputs(sc: Scenario, model: Model) -> dict:
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


def solver_settings(sc: Scenario, model: Model) -> SolverSettings:
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
    try:
        sundials.check_option(method, key, value)
    except sundials.UnknownOption as exc:
        hint = did_you_mean(key, [*exc.close, *SUNDIALS_ALIASES.values()])
        raise sc.error(path, f"'{key}' is not a setting or {method} option{hint}") from None
    except ParameterError as exc:
        raise sc.error(path, f"{value!r} refused by {method}: {exc.allowed}") from None


def default_signals(model: Model) -> list[str]:
    """The signals a transient keeps besides ``[outputs] signals``: the commands, the
    regulators' outlets and the valves' openings, the length, the load's position, the
    force sensor, a joint's angle, torque, stiffness and tendon tensions, and each unit's
    chamber pressure, expansion, thread tension and stretch."""
    keep = ("myofibril.length", "load.s", "sensor.f", "joint.theta", "joint.tau", "stiffness.K")
    chains = ("myofibril.", "flexor.", "extensor.", "fibre")
    suffix = (".chamber.p_gauge", ".expansion.s", ".T", ".e")
    return [
        n
        for n in model.signal_names
        if n in keep
        or n.endswith((".p_cmd", ".p_out", ".cmd", "_tendon.T", "fibre1.length"))
        or (n.endswith(".x") and "valve" in n)  # a valve's opening
        or (n.startswith(chains) and n.endswith(suffix))
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


def prepare(sc: Scenario, b: Binding, model: Model) -> tuple[dict, list[str], np.ndarray]:
    """The inputs (:func:`scene_inputs`), the signals to keep and the output grid of a
    transient on ``model``, checked (output size, commands in the regulator's range)."""
    inputs = scene_inputs(sc, model)
    sim = sc.simulation
    if sim is None:
        raise sc.error(("simulation",), "a transient needs [simulation] stop_time")
    wanted = list(dict.fromkeys(default_signals(model) + list(sc.outputs.signals)))
    missing = [n for n in wanted if n not in model.signal_names]
    if missing:
        raise sc.error(("outputs", "signals"), f"unknown signals {missing}")
    points = _intervals(sim)[1] + 2  # at most: the stop time may add one
    check_output_size(sc, points, len(wanted) + 1, ("simulation", "output_interval"))
    grid = time_grid(sim)
    check_commands(sc, model, b.overrides, inputs, grid)
    return inputs, wanted, grid


def run(
    model: Model,
    inputs: Mapping[str, object],
    params: Mapping[str, object],
    t_out: np.ndarray,
    settings: SolverSettings,
    signals: Sequence[str],
    *,
    guess: Equilibrium | None = None,
    max_values: float = MAX_VALUES,
) -> Result:
    """Simulate ``model`` through ``t_out`` [s] from its equilibrium at the inputs' values
    at ``t_out[0]``: the one simulation of a bound scene (every kind and the studies).

    ``inputs``: input name to signal (:func:`scene_inputs`); ``params``: parameter
    overrides (``Binding.overrides`` or a study sample's); ``settings``:
    :func:`solver_settings`; ``signals``: those returned; ``guess``: an equilibrium of
    ``model`` to continue the start from (where that fails, the start is found from the
    model's start values); ``max_values``: the largest output (points x signals). Returns
    the :class:`Result` on ``t_out``, solver statistics in ``meta``.
    """
    u0 = {k: float(sig(t_out[0])) for k, sig in inputs.items()}
    try:
        start = solve_equilibrium(model, u0, params, guess=guess)
    except SarcomereError:
        if guess is None:
            raise
        start = solve_equilibrium(model, u0, params)
    return simulate(
        model,
        float(t_out[-1]),
        inputs,
        params,
        x0=start.x,
        z0=start.z,
        settings=settings,
        t_out=t_out,
        signals=signals,
        max_values=max_values,
    )


def simulate_scene(
    sc: Scenario, b: Binding, fid: str, model: Model | None = None, guess: Equilibrium | None = None
) -> Result:
    """The transient of scene ``sc`` (bound as ``b``) at level ``fid``: :func:`prepare`
    and :func:`run` on ``model`` (built when not given), the start continued from
    ``guess`` where one is known."""
    model = b.build(fid) if model is None else model
    inputs, wanted, grid = prepare(sc, b, model)
    settings, limit, reason = solver_settings(sc, model), sc.outputs.max_values, None
    if sc.solver.method is None and not sc.solver.options and not sc.solver.step:
        sim = Simulator(model, settings, params=b.overrides, t0=float(grid[0]))
        method, reason = radau.default_method(model, sim.input_law(inputs))
        settings = dataclasses.replace(settings, method=method)
    res = run(model, inputs, b.overrides, grid, settings, wanted, guess=guess, max_values=limit)
    if reason:
        res.meta["method_reason"] = reason
    return res
