"""Variable records of the modelling language: what a flattened variable is.

``Var`` is the metadata of one variable (kind, unit, start, bounds, source);
``Collected`` gathers every declaration of one system before flattening.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import casadi as cs

from .ports import Port


@dataclass(frozen=True)
class Var:
    """Metadata of one flattened variable.

    ``kind`` is one of "state", "algebraic", "input", "parameter", "output".
    ``value`` is the default of a parameter; ``start`` the start value of the rest
    [unit]: a float, or a CasADi expression of parameter symbols (evaluated by
    :meth:`Model.x0` and friends at the parameter vector in use).
    """

    name: str
    kind: str
    unit: str
    description: str = ""
    start: float | cs.SX = 0.0
    low: float = -math.inf
    high: float = math.inf
    value: float = math.nan
    source: str = ""


@dataclass
class Collected:
    """Everything the builders of one system have declared (filled, then flattened)."""

    variables: dict[str, Var] = field(default_factory=dict)
    symbols: dict[str, cs.SX] = field(default_factory=dict)
    ders: dict[str, cs.SX] = field(default_factory=dict)
    equations: list[tuple[cs.SX, str]] = field(default_factory=list)
    outputs: dict[str, cs.SX] = field(default_factory=dict)
    ports: list[Port] = field(default_factory=list)
    connections: list[tuple[Port, Port]] = field(default_factory=list)
    energies: dict[str, cs.SX] = field(default_factory=dict)
    time_derivatives: dict[str, cs.SX] = field(default_factory=dict)
    dissipations: dict[str, cs.SX] = field(default_factory=dict)
