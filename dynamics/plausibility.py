"""Values that run but are probably not what was meant: one rule for the Python API, the
scenes and the studies.

A load or an APS parameter far from what the model was made for (the paper's experiment)
gets a :class:`PlausibilityWarning` from the set-ups (:mod:`.assemblies`), a
``ScenarioWarning`` at its key from a scene file; physically impossible values (a
temperature of 0 K, a mass or a stiffness <= 0) are refused by the parameters' ranges.
"""

from __future__ import annotations

import dataclasses
import math

from .components.aps import APSParams

PLAUSIBLE_LOAD_KG = (0.0, 1.0)
"""Plausible hanging loads [kg]: the paper's are 0 to 100 g and one APS pulls about 0.3 N
(31 g) at 0.1 MPa."""

PLAUSIBLE_GEOMETRY_FACTOR = 10.0
"""An APS length [m] more than this factor from the paper's experimental APS (squared for
an area [m^2]) is implausible."""

PLAUSIBLE_FACTOR = 1e3
"""Any other APS parameter with a positive default (stiffnesses, dampings, masses,
volumes, conductance, material constants; not the numerical settings) more than this
factor from the paper's APS is implausible (``k_s = 2e-12 N/m`` hangs a chain 9e11 m
long)."""


class PlausibilityWarning(UserWarning):
    """A value that runs but is probably not what was meant (a 50 kg load on an APS)."""


def implausible_load(kg: float) -> str | None:
    """Why a hanging load of ``kg`` [kg] is implausible, or None."""
    low, high = PLAUSIBLE_LOAD_KG
    if low <= kg <= high:
        return None
    why = "the paper's loads are 0 to 100 g; one APS pulls about 0.3 N (31 g) at 0.1 MPa"
    return f"{kg:.6g} kg is outside the plausible {low:g} to {high:g} kg ({why})"


def implausible_aps(aps: APSParams) -> dict[str, str]:
    """APSParams field -> why its value is implausible, against the paper's APS of the
    same material (:data:`PLAUSIBLE_GEOMETRY_FACTOR`, :data:`PLAUSIBLE_FACTOR`)."""
    paper = APSParams.from_paper(aps.material)
    out = {}
    for f in dataclasses.fields(APSParams):
        if "quantity" not in f.metadata:  # text choices (material, thermal)
            continue
        name, unit = f.name, f.metadata["quantity"].unit
        if unit == "1" or f.metadata["source"].startswith("numerical"):
            continue  # dimensionless ratios have ranges; numerical settings are free
        ref, value = getattr(paper, name), getattr(aps, name)
        if not (0 < ref < math.inf) or value == ref:
            continue
        k = {"m": PLAUSIBLE_GEOMETRY_FACTOR, "m^2": PLAUSIBLE_GEOMETRY_FACTOR**2}.get(
            unit, PLAUSIBLE_FACTOR
        )
        if not ref / k <= value <= ref * k:
            out[name] = (
                f"{value:.6g} {unit} is more than {k:g} times from the paper's APS "
                f"({ref:.6g} {unit}); plausible {ref / k:.3g} to {ref * k:.3g} {unit}"
            )
    return out


__all__ = [
    "PLAUSIBLE_FACTOR",
    "PLAUSIBLE_GEOMETRY_FACTOR",
    "PLAUSIBLE_LOAD_KG",
    "PlausibilityWarning",
    "implausible_aps",
    "implausible_load",
]
