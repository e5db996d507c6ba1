"""What a study factor changes in its base scene, and the models a worker reuses.

:class:`SceneContext` binds a transient scene once (``[model]``, ``[parameters]``, inputs,
solver, output grid) and turns one sample's factor values into the model to simulate
(built once per process and structure: :func:`model_for`), its parameter overrides and
its inputs. Everything that a sample changes is a run-time input of the model:
``load``, model parameters and the APS fields (mapped onto the per-unit parameters they
set, see :func:`aps_map`) become parameter overrides, ``pressure`` replaces the level
of the scene's step or ramp; only ``n`` (and an APS field whose parameters are not
proportional to it) selects another model.
"""

from __future__ import annotations

import dataclasses
import difflib
import math
from dataclasses import KW_ONLY, dataclass

import numpy as np

from sarcomere.dynamics.assemblies import GROUPS, N_LIMITS
from sarcomere.dynamics.components.aps import APSParams
from sarcomere.dynamics.errors import ParameterError
from sarcomere.dynamics.modeling.model import Model
from sarcomere.dynamics.params.core import Quantity
from sarcomere.dynamics.signals import Ramp, Step
from sarcomere.dynamics.units import to_si

from .. import dynamic
from .designs import FAMILY, family_member

#: Parameters a factor may not set: structural (built into the model's bounds).
STRUCTURAL = {"regulator.p_max": "the regulator's range is built into the model"}

#: Relative perturbation of an APS field when probing its parameters (:func:`aps_map`).
PROBE_RATIOS = (1.25, 0.8)


@dataclass(frozen=True)
class Target(Quantity):
    """What a factor name sets: its SI unit and allowed range (a :class:`Quantity`,
    keywords), and how it is applied."""

    name: str
    category: str  # "n", "load", "pressure", "family", "aps", "parameter"
    _: KW_ONLY
    long_name: str = ""
    integer: bool = False
    levels: tuple[float, ...] = ()

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

_MODELS: dict[tuple, Model] = {}
_PROBES: dict[tuple, tuple[tuple[str, float], ...] | None] = {}
BUILDS = {"models": 0, "probes": 0}
"""Models flattened in this process: study models and APS probes (tests count them)."""


def model_for(binding: dynamic.Binding, key: tuple, fidelity: str, n: int, aps: APSParams):
    """The model of ``binding`` at ``n`` with ``aps``, flattened once per process and
    ``key`` (the scene's structure) and reused."""
    full_key = (key, fidelity, n, aps)
    if full_key not in _MODELS:
        if len(_MODELS) >= MAX_MODELS:
            del _MODELS[next(iter(_MODELS))]  # the oldest
        _MODELS[full_key] = dataclasses.replace(binding, aps=aps).build(fidelity, n)
        BUILDS["models"] += 1
    return _MODELS[full_key]


def aps_map(binding, key: tuple, fidelity: str, n: int, field: str):
    """The model parameters ``field`` of APSParams sets, each as ``(name, value at the
    base field value)``: they are proportional to the field (checked by flattening once
    with the field scaled, and comparing every parameter and start value). None if they
    are not (or the base value is 0): the field is then structural (one model per value).
    """
    probe_key = (key, fidelity, n, field)
    if probe_key in _PROBES:
        return _PROBES[probe_key]
    base = model_for(binding, key, fidelity, n, binding.aps)
    v0 = getattr(binding.aps, field)
    found = None
    if v0 != 0 and math.isfinite(v0):
        for ratio in PROBE_RATIOS:
            try:
                aps = dataclasses.replace(binding.aps, **{field: v0 * ratio})
            except ParameterError:
                continue
            probe = dataclasses.replace(binding, aps=aps).build(fidelity, n)
            BUILDS["probes"] += 1
            found = _proportional(base, probe, ratio)
            break
    _PROBES[probe_key] = found
    return found


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


class SceneContext:
    """A transient scene bound for a study: targets of factor names, and samples applied.

    Raises ScenarioError (via the scene) for a scene a study cannot use.
    """

    def __init__(self, sc) -> None:
        if sc.kind != "transient":
            raise sc.error(("scenario", "kind"), f"'{sc.kind}': a study runs kind 'transient'")
        sc.refuse_unused("sweep", "control", "cosim", "outputs.tolerance")
        self.scene = sc
        self.binding = dynamic.bind(sc)
        fid = dynamic.fidelity_level(sc, allow_auto=True)
        if fid == "auto":
            raise sc.error(
                ("model", "fidelity"), "'auto' picks a level per run; a study needs one level"
            )
        dynamic.check_n(sc, ("model", "n"), self.binding.n, fid)
        self.fidelity = fid
        self.key = (sc.name, repr(sc.model), repr(sorted(sc.parameters.items())))
        self.model = self.model_at(self.binding.n)
        self.inputs, self.signals, self.grid = dynamic._prepare(sc, self.binding, self.model)
        self.settings = dynamic._settings(sc, self.model)

    def model_at(self, n: int, aps: APSParams | None = None) -> Model:
        return model_for(self.binding, self.key, self.fidelity, n, aps or self.binding.aps)

    # --- names -------------------------------------------------------------------
    def target(self, name: str) -> Target:
        """The target of factor ``name``; ParameterError (with the nearest names) if none."""
        b = self.binding
        if name == "n":
            low = 2 * GROUPS + 1 if self.fidelity == "grouped" else 1
            return Target(
                name,
                "n",
                low=low,
                high=N_LIMITS[self.fidelity],
                long_name="APS in the chain",
                integer=True,
            )
        if name == "load":
            if b.setup != "hanging":
                raise ParameterError(
                    name, name, "a factor of this scene", "set-up 'isometric' holds no load"
                )
            if "load.m" in b.overrides:
                raise ParameterError(
                    name, name, "a factor of this scene", "the scene sets load.m in [parameters]"
                )
            return Target(name, "load", unit="kg", low=0.0, long_name="hanging load (payload)")
        if name == "pressure":
            self.pressure_signal()
            low, high = dynamic.command_range(self.model, b.overrides)
            return Target(
                name,
                "pressure",
                unit="Pa",
                low=low,
                high=high,
                long_name="regulator command level (gauge)",
            )
        if name == "family":
            levels = tuple(m.L_r for m in FAMILY)
            return Target(
                name,
                "family",
                unit="m",
                low=min(levels),
                high=max(levels),
                long_name="calibration family member (its L_r)",
                levels=levels,
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
            *("n", "load", "pressure", "family"),
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

    def pressure_signal(self):
        """The scene's step or ramp on the regulator command (the ``pressure`` factor
        replaces its final level)."""
        sig = self.inputs.get(dynamic.P_CMD)
        if not isinstance(sig, Step | Ramp):
            what = "no input" if sig is None else f"a {type(sig).__name__.lower()}"
            raise ParameterError(
                "pressure",
                "pressure",
                "a scene with a step or ramp on regulator.p_cmd",
                f"the scene has {what} there",
            )
        return sig

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
            v = float(v)
            if f.name == "n":
                n = int(round(v))
            elif f.name == "load":
                loads = v
            elif f.name == "pressure":
                inputs[dynamic.P_CMD] = dataclasses.replace(self.pressure_signal(), final=v)
            elif f.name == "family":
                fields.update(family_member(v))
            elif f.name.startswith("aps."):
                (relative if f.relative else fields)[f.name[4:]] = v
            elif f.relative:
                over[f.name] = self.base_value(f.name, n) * v
            else:
                over[f.name] = v
        for name, scale in relative.items():
            fields[name] = fields.get(name, getattr(b.aps, name)) * scale
        dataclasses.replace(b.aps, **fields)  # a ParameterError for a field out of range
        structural = {}
        for name, value in fields.items():
            mapped = aps_map(b, self.key, self.fidelity, n, name)
            v0 = getattr(b.aps, name)
            if mapped is None:
                structural[name] = value
            else:
                over.update({p: p0 * (value / v0) for p, p0 in mapped})
        model = self.model_at(n, dataclasses.replace(b.aps, **structural) if structural else None)
        if loads is not None:
            over["load.m"] = model.variables["load.m"].value - b.load_kg + loads
        return model, over, inputs
