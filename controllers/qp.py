"""The QP pieces both MPCs use: the exact zero-order-hold discretisation and the QP solvers
through ``casadi.conic`` (the rest they share is in :mod:`.receding`).
"""

from __future__ import annotations

import casadi as cs
import numpy as np
import scipy.linalg

from sarcomere.dynamics.errors import ParameterError

QP_SOLVERS = {
    # CasADi's own QPs: qrqp's generated C is self-contained (daqp, osqp and hpipm generate
    # calls into their libraries; qpOASES and ipqp cannot be generated)
    "ipqp": {
        "print_iter": False,
        "print_header": False,
        "print_info": False,
        "error_on_fail": False,
    },
    "qrqp": {
        "print_iter": False,
        "print_header": False,
        "print_info": False,
        "error_on_fail": False,
    },  # fmt: skip
    "qpoases": {"printLevel": "none", "error_on_fail": False},
    "daqp": {"error_on_fail": False},
    # HPIPM's default inf (1e8) is inside the range of our scaled bounds: it then treats
    # them as finite and stops at max_iter (issue 9); 1e6 is far outside every bound here.
    "hpipm": {"error_on_fail": False, "hpipm": {"iter_max": 100, "warm_start": 1}, "inf": 1e6},
}
"""``casadi.conic`` plugins the MPCs accept, with the options they are built with."""


def zoh(A: np.ndarray, B: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """Exact zero-order-hold discretisation: ``expm([[A, B], [0, 0]] dt)``."""
    nx, nu = B.shape
    M = np.zeros((nx + nu, nx + nu))
    M[:nx, :nx], M[:nx, nx:] = A, B
    E = scipy.linalg.expm(M * dt)
    return E[:nx, :nx], E[:nx, nx:]


def qp_solver(name: str, H: cs.Sparsity, A: cs.Sparsity) -> cs.Function:
    """A ``casadi.conic`` QP solver built once for the sparsities ``H`` and ``A``."""
    if name not in QP_SOLVERS:
        raise ParameterError("qp_solver", name, f"one of {sorted(QP_SOLVERS)}")
    return cs.conic("qp", name, {"h": H, "a": A}, dict(QP_SOLVERS[name]))
