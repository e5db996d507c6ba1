"""The shared environment: one ambient state for every component (Modelica ``inner``).

A model adds one :class:`Environment` named ``"ambient"`` at the top of its System, before
the components that use it; those read its parameters through ``Builder.outer("ambient")``.
So the whole model has one ambient pressure, temperature, gas constant, ratio of specific
heats and gravity: overriding ``ambient.p`` moves the regulator's and every chamber's
reference together.
"""

from __future__ import annotations

import dataclasses

from ..modeling.component import Builder, Component
from ..params.ambient import Ambient

ENVIRONMENT = "ambient"
"""Name of the environment component every user looks up."""

POSITIVE = 1e-12
"""Lower bound of the ambient pressure [Pa], temperature [K] and gas constant
[J/(kg K)]: each physically > 0 (``ambient.T = 0 K`` is refused)."""

# parameter name -> Ambient field (the one source of the defaults, units and sources)
_FIELDS = {"p": "p_amb", "T": "T_amb", "R": "R_air", "gamma": "kappa", "g": "g"}


class Environment(Component):
    """Ambient pressure ``p`` [Pa], temperature ``T`` [K], gas constant ``R`` [J/(kg K)],
    ratio of specific heats ``gamma`` [1] and gravity ``g`` [m/s^2] along +s.

    Defaults, units and sources come from :class:`~sarcomere.dynamics.params.ambient.Ambient`;
    keyword arguments (by parameter name) change the defaults of this instance.
    """

    def __init__(self, name: str = ENVIRONMENT, **defaults: float) -> None:
        super().__init__(name)
        unknown = set(defaults) - set(_FIELDS)
        if unknown:
            raise TypeError(f"Environment() got unknown parameters {sorted(unknown)}")
        self.ambient = Ambient(**{_FIELDS[k]: v for k, v in defaults.items()})

    def build(self, b: Builder) -> None:
        meta = {f.name: f.metadata for f in dataclasses.fields(Ambient)}
        for local, field_name in _FIELDS.items():
            m = meta[field_name]
            # gamma = 1 has no internal energy; no absolute pressure, temperature or gas
            # constant is 0 (g may be: a set-up across gravity)
            low = {"gamma": 1.001, "g": 0.0}.get(local, POSITIVE)
            b.parameter(
                local,
                getattr(self.ambient, field_name),
                m["unit"],
                m["description"],
                low=low,
                source=m["source"],
            )


__all__ = ["ENVIRONMENT", "POSITIVE", "Environment"]
