"""What the method families share: the model with its inputs as functions of clamped
time, and the checks of a problem's settings."""

from __future__ import annotations

from dataclasses import dataclass

import casadi as cs
import numpy as np

from ..errors import ParameterError, SolverError
from .settings import Problem


# --- the ODE with the inputs substituted ------------------------------------------------
@dataclass(frozen=True)
class SegmentDAE:
    """The model's equations with the inputs as functions of clamped time.

    Attributes
    ----------
    t : casadi.SX
        Time [s].
    seg : casadi.SX
        ``[a, b_left]``: the segment start and the float just below its end [s];
        inputs are evaluated at ``min(max(t, a), b_left)``.
    x, z, p : casadi.SX
        States, algebraic unknowns, parameters (the model's symbols).
    ode, alg : casadi.SX
        Right-hand side and algebraic residuals with the inputs substituted.
    """

    t: cs.SX
    seg: cs.SX
    x: cs.SX
    z: cs.SX
    p: cs.SX
    ode: cs.SX
    alg: cs.SX

    def rhs(self) -> cs.Function:
        """``rhs(t, x, p, seg) -> ode`` (explicit ODE only)."""
        ode = cs.densify(self.ode)
        return cs.Function(
            "rhs", [self.t, self.x, self.p, self.seg], [ode], ["t", "x", "p", "seg"], ["ode"]
        )

    def jac(self) -> cs.Function:
        """``jac(t, x, p, seg) -> d ode / dx``, sparse."""
        J = cs.jacobian(self.ode, self.x)
        return cs.Function(
            "ode_jac", [self.t, self.x, self.p, self.seg], [J], ["t", "x", "p", "seg"], ["J"]
        )


_T = cs.SX.sym("t")
_DAE_CACHE: dict = {}


def segment_dae(prob: Problem) -> SegmentDAE:
    """The :class:`SegmentDAE` of a problem (cached per model and input expression)."""
    m = prob.model
    key = (m, str(prob.u_expr(_T)))
    hit = _DAE_CACHE.get(key)
    if hit is not None:
        return hit
    seg = cs.SX.sym("seg", 2)
    u = prob.u_expr(cs.fmin(cs.fmax(_T, seg[0]), seg[1]))
    ode = cs.substitute(m.ode, m.u, u) if m.u.numel() else m.ode
    alg = cs.substitute(m.alg, m.u, u) if m.u.numel() else m.alg
    dae = SegmentDAE(_T, seg, m.x, m.z, m.p, ode, alg)
    if len(_DAE_CACHE) > 64:
        _DAE_CACHE.clear()
    _DAE_CACHE[key] = dae
    return dae


def seg_bounds(a: float, b: float) -> np.ndarray:
    return np.array([a, np.nextafter(b, -np.inf)])


def require_ode(prob: Problem) -> None:
    m = prob.model
    if m.nz:
        raise SolverError(
            f"{prob.settings.method} needs an explicit ODE but model '{m.name}' keeps "
            f"{m.nz} algebraic unknowns: use 'idas' or 'collocation'"
        )


def method_options(prob: Problem, defaults: dict) -> dict:
    """Method options: ``defaults`` updated by ``settings.options`` (unknown keys raise)."""
    opts = dict(defaults)
    for key, value in prob.settings.options:
        if key not in defaults:
            raise ParameterError(
                "solver.options", key, f"options of '{prob.settings.method}': {sorted(defaults)}"
            )
        opts[key] = value
    return opts


def require_step(prob: Problem) -> float:
    h = prob.settings.step
    if h is None:
        raise ParameterError(
            "solver.step",
            None,
            f"a step size (0, inf) s: method '{prob.settings.method}' is fixed-step",
        )
    return float(h)


_STEP_CACHE: dict = {}


def cached_step(prob: Problem, kind: object, build) -> cs.Function:
    """``build(segment_dae(prob))``, cached per DAE and ``kind``."""
    dae = segment_dae(prob)
    key = (id(dae), kind)
    hit = _STEP_CACHE.get(key)
    if hit is None or hit[0] is not dae:
        if len(_STEP_CACHE) > 64:
            _STEP_CACHE.clear()
        hit = _STEP_CACHE[key] = (dae, build(dae))
    return hit[1]
