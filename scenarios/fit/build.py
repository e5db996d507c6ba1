"""A fit file bound to the model: each experiment's ``[model]`` through the scene binding
(:func:`..binding.bind`), its data read and checked against the model (names, units,
input ranges), the estimated parameters placed in each model, and the engine's
:class:`~sarcomere.dynamics.identification.problem.Problem` of the fitted experiments (and
one of the held-out ones). Every refusal is a one-line :class:`~.spec.FitError`.

A parameter name is any a scene's ``[parameters]`` takes: a model parameter path
(``"regulator.tau"``, ``"myofibril.tube1.C"``, ``"load.m"``) or ``"aps.<field>"``, one APS
field for every unit; the latter enters the model where the field sets a model parameter
in proportion (found by building the set-up with the field changed; a field that enters
otherwise, e.g. through a start value, is refused).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from sarcomere.dynamics.components.aps import APSParams
from sarcomere.dynamics.errors import ParameterError, ScenarioError
from sarcomere.dynamics.identification.experiments import (
    Estimated,
    Noise,
    StaticPoint,
    TimeSeries,
    measured,
)
from sarcomere.dynamics.identification.problem import Problem
from sarcomere.dynamics.modeling.model import Model
from sarcomere.dynamics.units import to_si

from ..binding import INPUT_ALIASES, bind, command_range, fidelity_level
from ..loader import scenario_from_dict
from ..spec import did_you_mean
from .data import Table, read_table
from .reference import is_ratio, output_unit, reference_inputs, relative
from .spec import ExperimentSpec, FitError, FitSpec, ParameterSpec

_PROBE = 1.25  # the factor an aps.<field> is changed by to find where it enters

FIXTURE = "fixture.s0"
"""The isometric fixture's position: in a static experiment, linked to the hanging chain's
rest equilibrium (the set-up's definition, :func:`~sarcomere.dynamics.assemblies.isometric`),
so that it follows the estimated parameters as in the calibration."""


@dataclass
class Bound:
    """One experiment bound: its spec, model, binding, data table and the estimated
    parameters' uses (model parameter -> (estimated name, factor))."""

    spec: ExperimentSpec
    model: Model
    table: Table
    binding: object
    fidelity: str
    uses: dict = dataclasses.field(default_factory=dict)
    fixed: dict = dataclasses.field(default_factory=dict)

    @property
    def linked(self) -> bool:
        """Whether the fixture position is linked to a rest equilibrium (a static
        experiment on the isometric set-up)."""
        return self.spec.kind == "static" and FIXTURE in self.model.param_names


@dataclass
class Built:
    """A bound fit: the estimated parameters (per-experiment ones named ``name@experiment``),
    which fit-file parameter each is, the experiments, and the problems of the fitted and
    the held-out experiments."""

    spec: FitSpec
    params: list[Estimated]
    origin: list[str]
    experiments: list[Bound]
    problem: Problem
    validation: Problem | None


def _scene(spec: FitSpec, exp: ExperimentSpec, table: dict):
    prefix = ("experiments", exp.index)
    lines = {p[2:]: n for p, n in spec.lines.items() if p[:2] == prefix and len(p) > 2}
    data = {"scenario": {"name": "fit", "kind": "transient"}, "model": table}
    try:
        return scenario_from_dict(data, spec.file, lines)
    except ScenarioError as exc:
        raise _prefixed(exc, exp) from None


def _prefixed(exc: ScenarioError, exp: ExperimentSpec) -> FitError:
    message = str(exc).split(f"key '{exc.key}': ", 1)[-1]
    return FitError(exc.file, f"experiments[{exp.index + 1}].{exc.key}", message, exc.line)


def _model(spec: FitSpec, exp: ExperimentSpec, table: dict | None = None):
    sc = _scene(spec, exp, exp.model if table is None else table)
    try:
        fid = fidelity_level(sc, allow_auto=False)
        binding = bind(sc)
        return binding, binding.build(fid), fid
    except ScenarioError as exc:
        raise _prefixed(exc, exp) from None


def model_of(spec: FitSpec, exp: ExperimentSpec, table: dict):
    """The binding and model of experiment ``exp``'s set-up with ``[model]`` = ``table``
    (a candidate experiment)."""
    binding, model, _ = _model(spec, exp, table)
    return binding, model


def place(built: Built, binding, model: Model, like: Bound) -> dict:
    """Where the shared estimated parameters enter ``model`` (a set-up like ``like``'s)."""
    b = Bound(like.spec, model, like.table, binding, like.fidelity)
    uses = {}
    for p in built.spec.parameters:
        if not p.per_experiment:
            uses.update(_uses(built.spec, b, p, p.name)[0])
    return uses


def _uses(spec: FitSpec, b: Bound, p: ParameterSpec, name: str) -> tuple[dict, str]:
    """Where parameter ``p`` enters the experiment's model and its SI unit."""
    binding, model, exp = b.binding, b.model, b.spec
    group, _, field = p.name.partition(".")
    if group == "aps":
        if field not in APSParams.numeric_fields():
            hint = did_you_mean(field, list(APSParams.numeric_fields()))
            raise spec.error(p.path, f"'{p.name}' is not an APS field{hint}")
        base = getattr(binding.aps, field)
        if not base:
            raise spec.error(p.path, f"'{p.name}' is 0 in this set-up: it cannot be scaled")
        aps = dataclasses.replace(binding.aps, **{field: base * _PROBE})
        other = dataclasses.replace(binding, aps=aps, scenario=None).build(b.fidelity)
        p0, p1 = model.parameters(), other.parameters()
        moved = np.flatnonzero(~np.isclose(p0, p1, rtol=1e-14, atol=0))
        if b.linked:  # the fixture follows its rest equilibrium, and the hook's start with it
            moved = moved[moved != model.param_names.index(FIXTURE)]
        if not moved.size or not np.allclose(p1[moved] / p0[moved], _PROBE, rtol=1e-12):
            raise spec.error(
                p.path,
                f"'{p.name}' does not enter model '{model.name}' as a parameter in proportion "
                "(it sets a start value or a derived quantity): fit the model parameters it "
                "sets instead",
            )
        if not b.linked and not np.allclose(model.x0(), other.x0(p0), rtol=1e-12, atol=1e-15):
            raise spec.error(p.path, f"'{p.name}' also sets start values of model '{model.name}'")
        uses = {model.param_names[i]: (name, float(p0[i] / base)) for i in moved}
        return uses, APSParams.unit(field)
    if p.name not in model.param_names:
        hint = did_you_mean(
            p.name, [*model.param_names, *(f"aps.{f}" for f in APSParams.numeric_fields())]
        )
        raise spec.error(
            p.path,
            f"'{p.name}' is not a parameter of model '{model.name}' "
            f"(experiment '{exp.name}'){hint}",
        )
    return {p.name: (name, 1.0)}, model.variables[p.name].unit


def _estimated(spec: FitSpec, p: ParameterSpec, unit: str, model: Model, name: str) -> Estimated:
    vals = []
    for key, raw in (("start", p.start), ("bounds", p.bounds[0]), ("bounds", p.bounds[1])):
        try:
            vals.append(to_si(raw, unit, p.name, bare_ok=False))
        except ParameterError as exc:
            raise spec.error((*p.path, key), f"{raw!r}: {exc.allowed} ({unit})") from None
    start, low, high = vals
    if not low < high:
        raise spec.error((*p.path, "bounds"), f"{list(p.bounds)}: low must be below high")
    if not low <= start <= high:
        raise spec.error(
            (*p.path, "start"), f"{p.start!r} is outside the bounds [{p.bounds[0]}, {p.bounds[1]}]"
        )
    var = model.variables.get(p.name)
    if var is not None and not (var.contains(low) and var.contains(high)):
        raise spec.error(
            (*p.path, "bounds"),
            f"{list(p.bounds)} leave the parameter's range [{var.low:g}, {var.high:g}] {unit}",
        )
    log = p.scale == "log" if p.scale else low > 0
    if log and not low > 0:
        raise spec.error((*p.path, "scale"), f"'log' needs bounds above 0, got {list(p.bounds)}")
    return Estimated(name, unit, start, low, high, log)


def _column_inputs(spec: FitSpec, b: Bound) -> dict[str, np.ndarray]:
    exp, model = b.spec, b.model
    out = {}
    for name in exp.inputs:
        target = INPUT_ALIASES.get(name, name)
        if target not in model.input_names:
            hint = did_you_mean(name, [*INPUT_ALIASES, *model.input_names])
            raise spec.error(
                (*exp.path, "inputs"), f"'{name}' is not an input of model '{model.name}'{hint}"
            )
        if name not in b.table.columns:
            raise FitError(
                b.table.file,
                name,
                f"no column '{name} [unit]' (listed in inputs)",
                b.table.header_line,
            )
        values = b.table.si(name, model.variables[target].unit)
        if target == "regulator.p_cmd":
            lo, hi = command_range(model, {})
        else:
            lo, hi = model.variables[target].low, model.variables[target].high
        bad = np.flatnonzero((values < lo) | (values > hi))
        if bad.size:
            k = int(bad[0])
            raise FitError(
                b.table.file,
                name,
                f"{b.table.columns[name][1][k]:g} "
                f"{b.table.columns[name][0]} is outside the input's range "
                f"[{lo:g}, {hi:g}] {model.variables[target].unit}",
                b.table.rows[k],
            )
        out[target] = values
    return out


def _outputs(spec: FitSpec, b: Bound) -> np.ndarray:
    exp, model = b.spec, b.model
    cols = []
    for s in exp.outputs:
        if s not in model.signal_names:
            hint = did_you_mean(s, model.signal_names)
            raise spec.error(
                (*exp.path, "outputs"), f"'{s}' is not a signal of model '{model.name}'{hint}"
            )
        if s not in b.table.columns:
            raise FitError(
                b.table.file, s, f"no column '{s} [unit]' (listed in outputs)", b.table.header_line
            )
        why = "a ratio to the reference: write [1] or [%]" if is_ratio(exp) else None
        cols.append(b.table.si(s, output_unit(exp, model, s), why))
    used = {"time", *exp.inputs, *exp.outputs}
    extra = [c for c in b.table.columns if c not in used]
    if extra:
        raise FitError(
            b.table.file,
            extra[0],
            "a column that is neither time, an input nor an "
            "output of the experiment: list it or remove it",
            b.table.header_line,
        )
    return np.column_stack(cols)


def build(spec: FitSpec) -> Built:
    """Bind every experiment, read its data and make the problems (FitError on any bad
    input, before any solve)."""
    bound: list[Bound] = []
    for exp in spec.experiments:
        binding, model, fid = _model(spec, exp)
        table = read_table(exp.data, exp.kind == "time-series")
        bound.append(Bound(exp, model, table, binding, fid))
    fitted = [b for b in bound if not b.spec.validation]
    params, origin = [], []
    for p in spec.parameters:
        names = [f"{p.name}@{b.spec.name}" for b in fitted] if p.per_experiment else [p.name]
        for k, name in enumerate(names):
            owners = [fitted[k]] if p.per_experiment else bound
            est = None
            for b in owners:
                uses, unit = _uses(spec, b, p, name)
                b.uses.update(uses)
                est = est or _estimated(spec, p, unit, b.model, name)
            params.append(est)
            origin.append(p.name)
        if p.per_experiment:  # held-out experiments take the start value
            for b in bound:
                if b.spec.validation:
                    uses, unit = _uses(spec, b, p, p.name)
                    est = _estimated(spec, p, unit, b.model, p.name)
                    for pname, (_, factor) in uses.items():
                        b.fixed[pname] = factor * est.start
    series, points, targets = _experiments(spec, bound, fitted)
    noise = _noise(spec, bound)
    problem = Problem(params, series, points, targets, noise)
    held = [b for b in bound if b.spec.validation]
    validation = None
    if held:
        s2, p2, t2 = _experiments(spec, bound, held)
        validation = Problem(params, s2, p2, t2, noise)
    return Built(spec, params, origin, bound, problem, validation)


def _noise(spec: FitSpec, bound: list[Bound]) -> dict[str, Noise]:
    out = {}
    for signal, nz in spec.noise.items():
        b = next(b for b in bound if signal in b.spec.outputs)
        unit = output_unit(b.spec, b.model, signal)
        sigma = None
        if nz.sigma is not None:
            try:
                sigma = to_si(nz.sigma, unit, signal, bare_ok=False)
            except ParameterError as exc:
                raise spec.error(
                    (*nz.path, "sigma"), f'{nz.sigma!r}: {exc.allowed} ({unit}), or "estimate"'
                ) from None
            if not sigma > 0:
                raise spec.error((*nz.path, "sigma"), f"{nz.sigma!r} is not above 0")
        out[signal] = Noise(sigma, nz.relative)
    return out


def _experiments(spec: FitSpec, bound: list[Bound], which: list[Bound]):
    series, points, targets = [], [], []
    statics = _Statics(spec, bound, points)
    for b in which:
        model = b.model
        uses = b.uses
        p = model.parameters({**b.binding.overrides, **b.fixed})
        inputs = _column_inputs(spec, b)
        data = _outputs(spec, b)
        n = len(data)
        u = np.tile(model.u0(p), (n, 1))
        for name, values in inputs.items():
            u[:, model.input_names.index(name)] = values
        if b.spec.kind == "time-series":
            interval = spec.interval if spec.method == "multiple-shooting" else None
            series.append(
                TimeSeries(
                    b.spec.name,
                    model,
                    b.table.time,
                    u,
                    b.spec.outputs,
                    data,
                    p,
                    uses,
                    interval,
                    spec.step,
                )
            )
            continue
        ref = b.spec.reference
        ref_point = statics.reference(b) if ref is not None else None
        for i in range(n):
            pt = statics.add(f"{b.spec.name}#{i + 1}", b, u[i])
            for j, s in enumerate(b.spec.outputs):
                value = float(data[i, j])
                targets.append(
                    measured(pt, s, value)
                    if ref_point is None
                    else relative(pt, ref_point, s, value, ref.form)
                )
    return series, points, targets


class _Statics:
    """The static points of one problem, in solve order: each experiment's, a reference
    equilibrium once per set-up and inputs, and before an isometric experiment's points
    the hanging chain's rest equilibrium its fixture position links to (:data:`FIXTURE`)."""

    def __init__(self, spec: FitSpec, bound: list[Bound], points: list) -> None:
        self.spec, self.bound, self.points = spec, bound, points
        self.names: dict[tuple, str] = {}

    def add(self, name: str, b: Bound, u: np.ndarray) -> str:
        p = b.model.parameters({**b.binding.overrides, **b.fixed})
        links = {FIXTURE: (self._rest(b), "load.s")} if b.linked else {}
        self.points.append(StaticPoint(name, b.model, u, p, b.uses, links))
        return name

    def reference(self, b: Bound) -> str:
        """The reference point of static experiment ``b`` (made on first use)."""
        ref = b.spec.reference
        of = next(x for x in self.bound if x.spec.name == (ref.experiment or b.spec.name))
        p = of.model.parameters({**of.binding.overrides, **of.fixed})
        u = reference_inputs(self.spec, ref, of.model, of.model.u0(p))
        key = ("reference", of.spec.name, u.tobytes())
        if key not in self.names:
            k = sum(1 for x in self.names if x[:2] == key[:2]) + 1
            self.names[key] = self.add(f"{of.spec.name}#reference{k}", of, u)
        return self.names[key]

    def _rest(self, b: Bound) -> str:
        """The rest point of isometric experiment ``b``: its chain hanging at 0 Pa with no
        load (the 1 g hook only), the estimated parameters entering as in ``b``'s model."""
        key = ("rest", b.spec.name)
        if key not in self.names:
            rest = dataclasses.replace(b.binding, setup="hanging", load_kg=0.0, scenario=None)
            model = rest.build(b.fidelity)
            uses = {k: v for k, v in b.uses.items() if k in model.param_names}
            p = model.parameters({k: v for k, v in b.fixed.items() if k in model.param_names})
            u = np.zeros_like(model.u0(p))  # 0 Pa (every input at 0)
            name = f"{b.spec.name}#rest"
            self.points.append(StaticPoint(name, model, u, p, uses))
            self.names[key] = name
        return self.names[key]
