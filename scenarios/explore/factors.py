"""What a study factor changes in its base scene, and the models a worker reuses.

:class:`SceneContext` binds a transient scene once (``[model]``, ``[parameters]``, inputs,
solver, output grid) and turns one sample's factor values into the model to simulate
(built once per process and structure: :func:`model_for`), its parameter overrides and
its inputs. Everything that a sample changes is a run-time input of the model:
``load``, model parameters and the APS fields (mapped onto the per-unit parameters they
set, see :func:`aps_map`) become parameter overrides, an input's factor (``pressure``, the
scene's name of ``regulator.p_cmd``) replaces the level of the scene's step or ramp on
it; only ``n`` (and an APS field whose parameters are not proportional to it) selects
another model. The caches are bounded (``functools.lru_cache``).
"""

from __future__ import annotations

import dataclasses
import difflib
import functools
import math
from dataclasses import KW_ONLY, dataclass

import numpy as np

from sarcomere.dynamics.assemblies import GROUPS, N_LIMITS
from sarcomere.dynamics.components.aps import APSParams
from sarcomere.dynamics.errors import ParameterError
from sarcomere.dynamics.fidelity import REDUCED_FROM_N
from sarcomere.dynamics.modeling.model import Model
from sarcomere.dynamics.params.core import Quantity
from sarcomere.dynamics.signals import Ramp, Step
from sarcomere.dynamics.units import to_si

from .. import binding as scene_binding
from ..transient import AUTO_WHY, study_level
from .designs import FAMILY, family_member

#: Parameters a factor may not set: structural (built into the model's bounds).
STRUCTURAL = {"regulator.p_max": "the regulator's range is built into the model"}

#: Long names of input factors (in the study's definition: kept as they were).
LONG_NAMES = {scene_binding.P_CMD: "regulator command level (gauge)"}

#: Relative perturbation of an APS field when probing its parameters (:func:`aps_map`).
PROBE_RATIOS = (1.25, 0.8)


@dataclass(frozen=True)
class Target(Quantity):
    """What a factor name sets: its SI unit and allowed range (a :class:`Quantity`,
    keywords), and how it is applied."""

    name: str
    category: str  # "n", "load", "input", "family", "aps", "parameter" (or "relative")
    _: KW_ONLY
    long_name: str = ""
    integer: bool = False
    levels: tuple[float, ...] = ()
    input: str = ""  # the input whose step or ramp level it sets (category "input")

    def allowed(self) -> str:
        """The allowed values, for messages."""
        if self.levels:
            return "one of " + ", ".join(f"{v:g} {self.unit}" for v in self.levels)
        text = ("whole numbers in " if self.integer else "") + self.range_str
        return f"{text} ({self.long_name})" if self.category == "relative" else text

    def refusal(self, value: float) -> str:
        """Why ``value`` is refused, naming what is allowed."""
        shown = f"{value:g}" if self.unit == "1" else f"{value:g} {self.unit}"
        if self.levels:
            return f"{shown} is not {self.allowed()}"
        return f"{shown} is outside {self.allowed()}"

    def contains(self, value: float) -> bool:
        if self.levels:
            return any(math.isclose(value, v, rel_tol=1e-9) for v in self.levels)
        if self.integer and value != round(value):
            return False
        return super().contains(value)


# ---------------------------------------------------------------------------- models

#: Models kept per process (a study over many structures keeps the latest).
MAX_MODELS = 32

BUILDS = {"models": 0, "probes": 0}
"""Models flattened in this process: study models and APS probes (tests count them)."""


@dataclass(frozen=True)
class Keyed:
    """``value`` under a hashable ``key`` (compared and hashed by the key alone): a cache
    argument whose value is not hashable."""

    key: tuple
    value: object = dataclasses.field(compare=False)


@functools.lru_cache(maxsize=MAX_MODELS)
def model_for(binding: Keyed, fidelity: str, n: int, aps: APSParams) -> Model:
    """The model of ``binding.value`` (a :class:`~..binding.Binding`, ``binding.key`` its
    scene's structure) at ``n`` with ``aps``, flattened once per process and reused."""
    BUILDS["models"] += 1
    return dataclasses.replace(binding.value, aps=aps).build(fidelity, n)


@functools.lru_cache(maxsize=4 * MAX_MODELS)
def aps_map(binding: Keyed, fidelity: str, n: int, field: str):
    """The model parameters ``field`` of APSParams sets, each as ``(name, value at the
    base field value)``: they are proportional to the field (checked by flattening once
    with the field scaled, and comparing every parameter and start value). None if they
    are not (or the base value is 0): the field is then structural (one model per value).
    """
    b = binding.value
    base = model_for(binding, fidelity, n, b.aps)
    v0 = getattr(b.aps, field)
    if v0 == 0 or not math.isfinite(v0):
        return None
    for ratio in PROBE_RATIOS:
        try:
            aps = dataclasses.replace(b.aps, **{field: v0 * ratio})
        except ParameterError:
            continue
        BUILDS["probes"] += 1
        return _proportional(base, dataclasses.replace(b, aps=aps).build(fidelity, n), ratio)
    return None


def _proportional(base: Model, probe: Model, ratio: float):
    """The parameters that differ between ``base`` and ``probe`` if each is ``ratio``
    times its base value and the start states follow the parameters; else None."""
    if base.param_names != probe.param_names or base.state_names != probe.state_names:
        return None
    p0, p1 = base.parameters(), probe.parameters()
    changed = np.flatnonzero(p0 != p1)
    if not np.allclose(p1[changed], ratio * p0[changed], rtol=1e-12, atol=0):
        return None
    if not np.allclose(base.x0(p1), probe.x0(), rtol=1e-12, atol=1e-15):
        return None
    return tuple((base.param_names[i], float(p0[i])) for i in changed)


# ---------------------------------------------------------------------------- scene


@functools.lru_cache(maxsize=8)
def _bound(scene: Keyed) -> SceneContext:
    return SceneContext(scene.value)


def scene_context(sc) -> SceneContext:
    """The :class:`SceneContext` of a scene, bound once per process and scene (it builds
    the base model; the latest few are kept)."""
    return _bound(Keyed((sc.file, repr(sc)), sc))


class SceneContext:
    """A transient scene bound for a study: targets of factor names, and samples applied.

    Raises ScenarioError (via the scene) for a scene a study cannot use.
    """

    def __init__(self, sc) -> None:
        if sc.kind != "transient":
            raise sc.error(("scenario", "kind"), f"'{sc.kind}': a study runs kind 'transient'")
        sc.refuse_unused("sweep", "control", "cosim")
        if sc.model.fidelity != "auto":
            sc.refuse_unused("outputs.tolerance")
        self.scene = sc
        self.binding = scene_binding.bind(sc)
        fid = scene_binding.fidelity_level(sc, allow_auto=True)
        self.level_note = fid  # what the study states of its level (summary.json)
        if fid == "auto":
            fid = study_level(sc, self.binding.n)
            self.level_note = f"auto: {fid} in every sample ({AUTO_WHY})"
        scene_binding.check_n(sc, ("model", "n"), self.binding.n, fid)
        self.fidelity = fid
        key = (sc.name, repr(sc.model), repr(sorted(sc.parameters.items())))
        self.structure = Keyed(key, self.binding)
        self._targets: dict[str, Target] = {}
        self.model = self.model_at(self.binding.n)
        self.inputs, self.signals, self.grid = scene_binding.prepare(sc, self.binding, self.model)
        self.settings = scene_binding.solver_settings(sc, self.model)

    def model_at(self, n: int, aps: APSParams | None = None) -> Model:
        return model_for(self.structure, self.fidelity, n, aps or self.binding.aps)

    def aps_parameters(self, field: str, n: int | None = None):
        """:func:`aps_map` of ``field`` at ``n`` (default: the scene's)."""
        return aps_map(self.structure, self.fidelity, n or self.binding.n, field)

    # --- names -------------------------------------------------------------------
    def target(self, name: str) -> Target:
        """The target of factor ``name``; ParameterError (with the nearest names) if none."""
        if name not in self._targets:
            self._targets[name] = self._target(name)
        return self._targets[name]

    def sets(self, name: str) -> tuple[str, ...]:
        """The model parameters or input that factor ``name`` sets (at the scene's n)."""
        t = self.target(name)
        if t.category == "aps":
            mapped = self.aps_parameters(name.removeprefix("aps."))
            return (name,) if mapped is None else tuple(p for p, _ in mapped)
        return {"load": ("load.m",), "parameter": (name,), "input": (t.input,)}.get(t.category, ())

    def _target(self, name: str) -> Target:
        b = self.binding
        if name == "n":
            low = 2 * GROUPS + 1 if self.fidelity == "grouped" else 1
            auto = self.level_note != self.fidelity  # n stays where the auto rule runs full
            high = REDUCED_FROM_N - 1 if auto else N_LIMITS[self.fidelity]
            return Target(name, "n", low=low, high=high, long_name="APS in the chain", integer=True)
        if name == "load":
            why = "set-up 'isometric' holds no load" if b.setup != "hanging" else ""
            if "load.m" in b.overrides:
                why = "the scene sets load.m in [parameters]"
            if why:
                raise ParameterError(name, name, "a factor of this scene", why)
            return Target(name, "load", unit="kg", low=0.0, long_name="hanging load (payload)")
        if scene_binding.INPUT_ALIASES.get(name, name) in self.model.input_names:
            return self._input_target(name, scene_binding.INPUT_ALIASES.get(name, name))
        if name == "family":
            levels = tuple(m.L_r for m in FAMILY)
            what = "calibration family member (its L_r)"
            low, high = min(levels), max(levels)
            return Target(
                name, "family", unit="m", low=low, high=high, long_name=what, levels=levels
            )
        group, _, field = name.partition(".")
        if group == "aps" and field in APSParams.numeric_fields():
            meta = next(f.metadata for f in dataclasses.fields(APSParams) if f.name == field)
            return Target(
                name,
                "aps",
                **vars(APSParams.quantity(field)),
                long_name=f"APS {meta['description']} (every unit)",
            )
        if name in self.model.param_names and name not in STRUCTURAL:
            var = self.model.variables[name]
            return Target(
                name,
                "parameter",
                unit=var.unit,
                low=var.low,
                high=var.high,
                long_name=var.description or name,
            )
        why = STRUCTURAL.get(name, "")
        names = [
            *("n", "load", *scene_binding.INPUT_ALIASES, "family"),
            *(f"aps.{f}" for f in APSParams.numeric_fields()),
            *self.model.param_names,
        ]
        close = difflib.get_close_matches(name, names, n=3)
        near = f"nearest: {', '.join(close)}" if close else "no close name"
        raise ParameterError(
            name,
            name,
            "n, load, pressure, family, aps.<field> or a model parameter path",
            why or f"unknown factor; {near}",
        )

    def _input_target(self, name: str, input_name: str) -> Target:
        """A factor on an input: the level of the scene's step or ramp on it."""
        sig = self.inputs.get(input_name)
        if not isinstance(sig, Step | Ramp):
            what = "no input" if sig is None else f"a {type(sig).__name__.lower()}"
            raise ParameterError(
                name,
                name,
                f"a scene with a step or ramp on {input_name}",
                f"the scene has {what} there",
            )
        var = self.model.variables[input_name]
        low, high = var.low, var.high
        if input_name == scene_binding.P_CMD:
            low, high = scene_binding.command_range(self.model, self.binding.overrides)
        long_name = LONG_NAMES.get(input_name, f"level of the step on {input_name}")
        return Target(
            name, "input", unit=var.unit, low=low, high=high, long_name=long_name, input=input_name
        )

    def base_value(self, name: str, n: int) -> float:
        """The scene's value of model parameter ``name`` (its [parameters] entry, else the
        model's default), SI."""
        var = self.model_at(n).variables[name]
        raw = self.binding.overrides.get(name)
        return var.value if raw is None else to_si(raw, var.unit, name)

    # --- samples -----------------------------------------------------------------
    def apply(self, factors, values) -> tuple[Model, dict, dict]:
        """The model, parameter overrides and inputs of one sample (values in SI, one per
        factor). Raises ParameterError for a value the model or APS refuses."""
        b = self.binding
        n = b.n
        over = dict(b.overrides)
        inputs = dict(self.inputs)
        fields: dict[str, float] = {}
        relative: dict[str, float] = {}
        loads = None
        for f, v in zip(factors, values, strict=True):
            v, t = float(v), self.target(f.name)
            if t.category == "n":
                n = int(round(v))
            elif t.category == "load":
                loads = v
            elif t.category == "input":
                inputs[t.input] = dataclasses.replace(inputs[t.input], final=v)
            elif t.category == "family":
                fields.update(family_member(v))
            elif t.category == "aps":
                (relative if f.relative else fields)[f.name[4:]] = v
            else:
                over[f.name] = self.base_value(f.name, n) * v if f.relative else v
        for name, scale in relative.items():
            fields[name] = fields.get(name, getattr(b.aps, name)) * scale
        dataclasses.replace(b.aps, **fields)  # a ParameterError for a field out of range
        structural = {}
        for name, value in fields.items():
            mapped = self.aps_parameters(name, n)
            v0 = getattr(b.aps, name)
            if mapped is None:
                structural[name] = value
            else:
                over.update({p: p0 * (value / v0) for p, p0 in mapped})
        model = self.model_at(n, dataclasses.replace(b.aps, **structural) if structural else None)
        if loads is not None:
            over["load.m"] = model.variables["load.m"].value - b.load_kg + loads
        return model, over, inputs
