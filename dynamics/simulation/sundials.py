"""CasADi's SUNDIALS integrators: ``cvodes`` (explicit ODE) and ``idas`` (index-1 DAE)."""

from __future__ import annotations

import casadi as cs
import numpy as np

from ..errors import SolverError
from .settings import Problem, register_method

# --- CasADi SUNDIALS methods ------------------------------------------------------------
_CACHE: dict = {}


def _dae(prob: Problem) -> dict:
    """The integrator's DAE dict: the model with the inputs as expressions of time."""
    m = prob.model
    t = cs.SX.sym("t")
    u = prob.u_expr(t)
    ode = cs.substitute(m.ode, m.u, u) if m.u.numel() else m.ode
    dae = {"x": m.x, "p": m.p, "t": t, "ode": ode}
    if m.nz:
        dae.update(z=m.z, alg=cs.substitute(m.alg, m.u, u) if m.u.numel() else m.alg)
    return dae


def _sundials(prob: Problem, plugin: str) -> tuple[np.ndarray, np.ndarray]:
    m, s = prob.model, prob.settings
    if plugin == "cvodes" and m.nz:
        raise SolverError(
            f"cvodes needs an explicit ODE but model '{m.name}' keeps {m.nz} algebraic "
            "unknowns: use method 'idas'"
        )
    opts = {
        "abstol": s.atol,
        "reltol": s.rtol,
        "max_num_steps": s.max_steps,
        "print_stats": False,
        "disable_internal_warnings": True,  # failures raise SolverError; t + h = t notes are noise
        **dict(s.options),
    }
    X = np.empty((len(prob.t_out), m.nx))
    Z = np.empty((len(prob.t_out), m.nz))
    X[0], Z[0] = prob.x0, prob.z0
    x, z = prob.x0, prob.z0
    stats = {"n_steps": 0, "n_rhs": 0, "n_jac": 0, "n_segments": 0}
    for a, b, grid in prob.segments():
        times = list(grid) if len(grid) and grid[-1] == b else [*grid, b]
        key = (m, plugin, repr(s), tuple(map(repr, prob.inputs)), a, tuple(times))
        F = _CACHE.get(key)
        if F is None:
            F = cs.integrator("F", plugin, _dae(prob), a, times, opts)
            if len(_CACHE) > 256:
                _CACHE.clear()
            _CACHE[key] = F
        try:
            res = F(x0=x, z0=z, p=prob.p)
        except RuntimeError as exc:
            raise prob.fail(_cause(str(exc)), a, x) from None
        xf = np.array(res["xf"])
        zf = np.array(res["zf"]) if m.nz else np.zeros((0, len(times)))
        st = F.stats()
        stats["n_steps"] += int(st.get("nsteps", 0))
        stats["n_rhs"] += int(st.get("nfevals", 0))
        stats["n_jac"] += int(st.get("njevals", 0) or st.get("nlinsetups", 0))
        stats["n_segments"] += 1
        idx = np.searchsorted(prob.t_out, grid)
        X[idx] = xf[:, : len(grid)].T
        Z[idx] = zf[:, : len(grid)].T
        x, z = xf[:, -1], zf[:, -1]
    prob.stats.update(stats)
    return X, Z


def _cause(msg: str) -> str:
    for flag, why in (
        ("CV_TOO_MUCH_WORK", "too many steps (max_steps reached): stiff or a step is too small"),
        ("IDA_TOO_MUCH_WORK", "too many steps (max_steps reached)"),
        ("CV_CONV_FAILURE", "Newton iteration failed to converge repeatedly"),
        ("IDA_CONV_FAIL", "Newton iteration failed to converge repeatedly"),
        ("CV_ERR_FAILURE", "error test failed repeatedly (step size became too small)"),
        ("CV_RHSFUNC_FAIL", "right-hand side evaluation failed (NaN or inf)"),
        ("IDA_RES_FAIL", "residual evaluation failed (NaN or inf)"),
        ("IDA_INIT", "initial algebraic state inconsistent (calc_ic failed)"),
    ):
        if flag in msg:
            return f"{why} [{flag}]"
    return msg.strip().splitlines()[-1][:300]


@register_method("cvodes")
def _cvodes(prob: Problem):
    return _sundials(prob, "cvodes")


@register_method("idas")
def _idas(prob: Problem):
    return _sundials(prob, "idas")
