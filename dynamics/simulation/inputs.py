"""The input signals a :class:`~.simulator.Simulator` takes: a constant, a unit string
or a signal per input, checked against the input's unit; their values at times; start
vectors by name."""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass

import casadi as cs
import numpy as np

from ..errors import ParameterError
from ..modeling.model import Model
from ..signals import Staircase, Step
from ..units import to_si


@dataclass(frozen=True)
class Const:
    """A constant input value [SI]."""

    value: float
    unit = None

    def __call__(self, t):
        return np.full(np.shape(t), self.value) if np.ndim(t) else self.value

    def casadi(self, t: cs.SX) -> cs.SX:
        return cs.SX(self.value)

    def breakpoints(self, t0: float, tf: float) -> list[float]:
        return []


HELD_TYPES = (Const, Step, Staircase)
"""Signals constant between their breakpoints (right-continuous): integrated as held."""


def input_ranges(model: Model) -> tuple[np.ndarray, np.ndarray]:
    """The inputs' ``low`` and ``high`` (one entry each)."""
    low = np.array([model.variables[k].low for k in model.input_names], dtype=float)
    high = np.array([model.variables[k].high for k in model.input_names], dtype=float)
    return low, high


def signal_of(model: Model, name: str, spec: object):
    """An input's signal from a constant, a unit string or a signal (unit checked)."""
    var = model.variables[name]
    if hasattr(spec, "casadi"):
        unit = getattr(spec, "unit", None)
        if unit not in (None, "1", var.unit):
            raise ParameterError(
                name,
                f"a signal in {unit}",
                f"a signal in {var.unit} (signals hold SI values of the input they drive)",
            )
        return spec
    if callable(spec):
        raise ParameterError(
            name,
            spec,
            "a constant or a signal with casadi(t) (see sarcomere.dynamics.signals): "
            "the integrators need the input as an expression of time",
        )
    value = number(spec, var.unit, name)
    if not math.isfinite(value):
        raise ParameterError(name, value, "a finite number")
    return Const(value)


def number(value: object, unit: str, name: str) -> float:
    """An SI float from a number (fast path) or a string with a unit."""
    if isinstance(value, int | float) and not isinstance(value, bool):
        return float(value)
    return to_si(value, unit, name)


def values_at(signals: list, t: float | np.ndarray) -> np.ndarray:
    """Input values at a time (vector) or at times (one row per time)."""
    if np.ndim(t) == 0:
        return np.array([float(sig(t)) for sig in signals], dtype=float)
    t = np.asarray(t, dtype=float)
    cols = [np.asarray(sig(t), dtype=float) * np.ones_like(t) for sig in signals]
    return np.column_stack(cols) if cols else np.zeros((len(t), 0))


def start_vector(
    model: Model, what: str, given: object, default: np.ndarray, names: list[str]
) -> np.ndarray:
    """A start vector from a full vector or a mapping by name (others keep ``default``)."""
    out = default.astype(float).copy()
    if given is None:
        return out
    if isinstance(given, Mapping):
        for key, value in given.items():
            if key not in names:
                raise ParameterError(what, key, f"names of model '{model.name}': {names}")
            out[names.index(key)] = float(value)
        return out
    vec = np.asarray(given, dtype=float).reshape(-1)
    if len(vec) != len(names):
        raise ParameterError(what, f"{len(vec)} values", f"{len(names)} values for {names}")
    return vec.copy()
