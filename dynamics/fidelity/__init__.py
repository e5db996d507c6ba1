"""Fidelity levels without a flattened model of their own, their predicted errors, and
the ``fidelity = "auto"`` rule that picks a level (on n, the scene and the predictions).

* :mod:`.levels`: ``linear`` and ``equilibrium_path`` (the equilibria along the input's
  range, :class:`Path`);
* :mod:`.predictions`: what each level leaves out, predicted before any nonlinear
  simulation (defect estimates, static differences of reduced chains);
* :mod:`.policy`: the rule, the ladder of reduced chains, and :func:`choose`.
"""

from .levels import (
    LEVELS,
    LINEAR_PATH_NODES,
    PATH_NODES,
    Path,
    equilibrium_path,
    level_result,
    trajectory,
)
from .policy import AUTO_LADDER, REDUCED_FROM_N, Choice, Scene, choose, grouped_units, predicts
from .predictions import (
    SAFETY,
    ChainResponse,
    chain_response,
    defect_error,
    predict_reduced,
    run_level,
    static_difference,
    static_nonlinearity,
)

__all__ = [
    "AUTO_LADDER",
    "REDUCED_FROM_N",
    "LEVELS",
    "LINEAR_PATH_NODES",
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
    "level_result",
    "predict_reduced",
    "predicts",
    "run_level",
    "static_difference",
    "static_nonlinearity",
    "trajectory",
]
