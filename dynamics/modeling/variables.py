"""Variable records of the modelling language: what a flattened variable is.

``Kind`` names the role of a variable, ``Var`` is the metadata of one variable (kind,
unit, start, nominal, bounds, source); ``Collected`` gathers every declaration of one
system before flattening.

FMI mapping (applied by ``fmu/description.py``):

========== =========== ============ ==========================================
kind       causality   variability  note
========== =========== ============ ==========================================
state      local       continuous   has a derivative (``Model.ode``, same order)
algebraic  local       continuous   solved or left as ``0 = g(x, z, u, p)``
derivative local       continuous   a rate asked for with ``Builder.der_of``
input      input       continuous
output     output      continuous
parameter  parameter   fixed        a change needs a new initialisation
========== =========== ============ ==========================================
"""

from __future__ import annotations

import math
from dataclasses import KW_ONLY, dataclass, field
from enum import StrEnum

import casadi as cs

from ..errors import ModelError
from ..params.core import Quantity
from .ports import Port


class Kind(StrEnum):
    """The role of a variable (a ``str``: ``Kind.STATE == "state"``)."""

    STATE = "state"
    ALGEBRAIC = "algebraic"
    INPUT = "input"
    PARAMETER = "parameter"
    OUTPUT = "output"
    DERIVATIVE = "derivative"


@dataclass(frozen=True)
class Var(Quantity):
    """Metadata of one flattened variable: a :class:`~..params.core.Quantity` (unit and
    range, keywords) with its kind, start and scaling.

    ``kind`` is a :class:`Kind` (or its string). ``value`` is the default of a
    parameter, refused outside its range; ``start`` the start value of the rest [unit]:
    a float, or a CasADi expression of parameter symbols (evaluated by :meth:`Model.x0`
    and friends at the parameter vector in use). ``nominal`` [unit] is the magnitude for
    solver scaling, > 0; by default ``|value|`` (parameters) or ``|start|`` (the rest)
    when that is a nonzero float, else 1. The range is held closed: an open bound is
    stored as the float next to it inside, so that the solvers' and the FMU's closed
    comparisons (``low <= v <= high``) hold as they are.
    """

    name: str
    kind: Kind
    _: KW_ONLY
    description: str = ""
    start: float | cs.SX = 0.0
    value: float = math.nan
    source: str = ""
    nominal: float | None = None

    def __post_init__(self) -> None:
        try:
            object.__setattr__(self, "kind", Kind(self.kind))
        except ValueError:
            raise ModelError(
                f"variable '{self.name}' has kind {self.kind!r}; one of {[k.value for k in Kind]}"
            ) from None
        for bound, inward in (("low", math.inf), ("high", -math.inf)):
            value, flag = getattr(self, bound), f"{bound}_open"
            if getattr(self, flag) and math.isfinite(value):
                object.__setattr__(self, bound, math.nextafter(value, inward))
            object.__setattr__(self, flag, False)
        if self.kind is Kind.PARAMETER and not self.contains(self.value):
            raise self.refuse(self.name, self.value)
        if self.nominal is None:
            base = self.value if self.kind is Kind.PARAMETER else self.start
            ok = isinstance(base, float | int) and math.isfinite(base) and base != 0.0
            object.__setattr__(self, "nominal", abs(float(base)) if ok else 1.0)
        elif not (0.0 < self.nominal < math.inf):
            raise Quantity(unit=self.unit, low=0.0, low_open=True).refuse(
                f"{self.name}.nominal", self.nominal
            )


@dataclass
class Collected:
    """Everything the builders of one system have declared (filled, then flattened)."""

    variables: dict[str, Var] = field(default_factory=dict)
    symbols: dict[str, cs.SX] = field(default_factory=dict)
    ders: dict[str, cs.SX] = field(default_factory=dict)
    equations: list[tuple[cs.SX, str, tuple[cs.SX, cs.SX] | None]] = field(default_factory=list)
    """Residual, origin, and ``(lhs, rhs)`` of a residual ``lhs - rhs`` of two expressions."""
    outputs: dict[str, cs.SX] = field(default_factory=dict)
    ports: list[Port] = field(default_factory=list)
    connections: list[tuple[Port, Port]] = field(default_factory=list)
    energies: dict[str, cs.SX] = field(default_factory=dict)
    time_derivatives: dict[str, cs.SX] = field(default_factory=dict)
    dissipations: dict[str, cs.SX] = field(default_factory=dict)
    start_nominals: dict[str, cs.SX] = field(default_factory=dict)
    """Variables whose nominal is ``|start|`` at the parameter defaults, set at flattening."""
    children: dict[str, dict[str, str]] = field(default_factory=dict)
    """Instance path -> {local name: full name} of the variables declared there."""
