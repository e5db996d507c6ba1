"""Parameters with units, ranges and sources: geometry, materials, ambient.

>>> from sarcomere.dynamics.params import experimental_geometry, get_material
>>> g = experimental_geometry()
>>> g["t_w"], g.param("t_w").unit
(0.0015, 'm')
>>> get_material("dragonskin_30").C1
96000.0
"""

from .ambient import Ambient
from .core import Check, Derived, Param, ParameterSet, Quantity
from .geometry import (
    FEM_H_CH_ESTIMATE_M,
    FEM_T_W_OVER_H_CH,
    anchor_spacing,
    check_anchors_fit_thread,
    experimental_geometry,
    fem_geometry,
    myosin_height,
)
from .materials import (
    MATERIALS,
    YeohMaterial,
    cauchy_stress,
    cauchy_stress_inverse,
    get_material,
    monotone_branch,
    strain_energy,
    stress_slope,
    true_cauchy_stress,
    yeoh_energy,
)

__all__ = [
    "FEM_H_CH_ESTIMATE_M",
    "FEM_T_W_OVER_H_CH",
    "MATERIALS",
    "Ambient",
    "Check",
    "Derived",
    "Param",
    "ParameterSet",
    "Quantity",
    "YeohMaterial",
    "anchor_spacing",
    "cauchy_stress",
    "cauchy_stress_inverse",
    "check_anchors_fit_thread",
    "experimental_geometry",
    "fem_geometry",
    "get_material",
    "monotone_branch",
    "myosin_height",
    "strain_energy",
    "stress_slope",
    "true_cauchy_stress",
    "yeoh_energy",
]
