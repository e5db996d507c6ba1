"""Fidelity levels without a flattened model of their own, their predicted errors, and
the ``fidelity = "auto"`` policy that picks a level from those predictions.

* :mod:`.levels`: ``linear`` and ``equilibrium_path`` (the equilibria along the input's
  range, :class:`Path`);
* :mod:`.predictions`: what each level leaves out, predicted before any nonlinear
  simulation (defect estimates, static differences of reduced chains);
* :mod:`.policy`: the ladder, cheapest first, and :func:`choose`.
"""

from .levels import (
    LEVELS,
    PATH_NODES,
    Path,
    equilibrium_path,
    level_result,
    run_equilibrium_path,
    run_linear,
    trajectory,
)
from .policy import AUTO_LADDER, Choice, Scene, choose, grouped_units
from .predictions import (
    SAFETY,
    ChainResponse,
    chain_response,
    defect_error,
    level_defect,
    path_deviation_bound,
    path_jump_bound,
    predict,
    predict_linear,
    predict_path,
    predict_reduced,
    static_difference,
    static_nonlinearity,
)

__all__ = [
    "AUTO_LADDER",
    "LEVELS",
    "PATH_NODES",
    "SAFETY",
    "ChainResponse",
    "Choice",
    "Path",
    "Scene",
    "chain_response",
    "choose",
    "defect_error",
    "equilibrium_path",
    "grouped_units",
    "level_defect",
    "level_result",
    "path_deviation_bound",
    "path_jump_bound",
    "predict",
    "predict_linear",
    "predict_path",
    "predict_reduced",
    "run_equilibrium_path",
    "run_linear",
    "static_difference",
    "static_nonlinearity",
    "trajectory",
]
