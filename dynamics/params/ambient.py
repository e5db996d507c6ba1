"""Shared environment defaults: ambient air, gravity, ISO 6358 reference conditions.

One :class:`Ambient` object holds what every component may need (as the environment
object of a Modelica model does). Fields are SI; units and sources are in the field
metadata and in :meth:`Ambient.params`.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

from .core import Param, ParameterSet

__all__ = ["Ambient"]


def _f(default: float, unit: str, source: str, description: str):
    return field(
        default=default,
        metadata={"unit": unit, "source": source, "description": description},
    )


@dataclass(frozen=True)
class Ambient:
    """Ambient conditions and constants (all SI, all > 0).

    Attributes
    ----------
    p_amb : float, default 101325.0
        Ambient (absolute) pressure, Pa. Source: ISO 2533 standard atmosphere, sea level.
    T_amb : float, default 293.15
        Ambient temperature, K (20 degC). Source: estimate (laboratory room temperature).
    g : float, default 9.80665
        Standard acceleration of gravity, m/s^2. Source: CGPM 1901 (standard gravity).
    R_air : float, default 287.05
        Specific gas constant of dry air, J/(kg K). Source: ISO 2533.
    rho0 : float, default 1.185
        Air density at the ISO 6358 reference conditions, kg/m^3. Source: ISO 6358-1:2013.
    T0 : float, default 293.15
        ISO 6358 reference temperature, K (20 degC). Source: ISO 6358-1:2013.
    p0 : float, default 100000.0
        ISO 6358 reference pressure, Pa (100 kPa). Source: ISO 6358-1:2013.
    kappa : float, default 1.4
        Ratio of specific heats of air, dimensionless. Source: ideal diatomic gas.

    Raises
    ------
    ParameterError
        A field that is not a finite positive number.
    """

    p_amb: float = _f(101325.0, "Pa", "ISO 2533 standard atmosphere", "ambient pressure")
    T_amb: float = _f(293.15, "K", "estimate (room temperature, 20 degC)", "ambient temp.")
    g: float = _f(9.80665, "m/s^2", "standard gravity (CGPM 1901)", "gravity")
    R_air: float = _f(287.05, "J/(kg*K)", "ISO 2533", "specific gas constant of dry air")
    rho0: float = _f(1.185, "kg/m^3", "ISO 6358-1:2013", "reference air density")
    T0: float = _f(293.15, "K", "ISO 6358-1:2013", "reference temperature")
    p0: float = _f(100000.0, "Pa", "ISO 6358-1:2013", "reference pressure")
    kappa: float = _f(1.4, "1", "ideal diatomic gas", "ratio of specific heats")

    def __post_init__(self) -> None:
        for p in self.params().params:  # each field checked as a Param: finite, > 0
            object.__setattr__(self, p.name, p.value)

    def params(self) -> ParameterSet:
        """The fields as a :class:`ParameterSet` (with units, ranges and sources)."""
        return ParameterSet(
            [
                Param(
                    f.name,
                    getattr(self, f.name),
                    unit=f.metadata["unit"],
                    low=0.0,
                    low_open=True,
                    source=f.metadata["source"],
                    description=f.metadata["description"],
                )
                for f in dataclasses.fields(self)
            ],
            name="ambient",
        )
