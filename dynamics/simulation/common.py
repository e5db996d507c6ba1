"""What the method families share: the model's equations with a segment's input law
substituted, and the checks of a method's settings."""

from __future__ import annotations

from dataclasses import dataclass

import casadi as cs

from ..errors import ParameterError, SolverError
from ..modeling.model import Model
from .settings import InputLaw, SolverSettings


@dataclass(frozen=True)
class LawDAE:
    """The model's equations with the inputs given by an :class:`InputLaw`.

    Attributes
    ----------
    t : casadi.SX
        Time [s].
    w : casadi.SX
        The law's argument (``u`` when held, ``[a, b_left]`` for signals).
    x, z, p : casadi.SX
        States, algebraic unknowns, parameters (the model's symbols).
    ode, alg : casadi.SX
        Right-hand side and algebraic residuals with the inputs substituted.
    """

    t: cs.SX
    w: cs.SX
    x: cs.SX
    z: cs.SX
    p: cs.SX
    ode: cs.SX
    alg: cs.SX

    def rhs(self) -> cs.Function:
        """``rhs(t, x, w, p) -> ode`` (explicit ODE only)."""
        ode = cs.densify(self.ode)
        return cs.Function(
            "rhs", [self.t, self.x, self.w, self.p], [ode], ["t", "x", "w", "p"], ["ode"]
        )

    def jac(self) -> cs.Function:
        """``jac(t, x, w, p) -> d ode / dx``, sparse."""
        J = cs.jacobian(self.ode, self.x)
        return cs.Function(
            "ode_jac", [self.t, self.x, self.w, self.p], [J], ["t", "x", "w", "p"], ["J"]
        )


def law_dae(model: Model, law: InputLaw) -> LawDAE:
    """The :class:`LawDAE` of ``model`` under ``law`` (memoised on the model)."""

    def build() -> LawDAE:
        m = model
        t = cs.SX.sym("t")
        w = cs.SX.sym("w", law.size_w(m.u.numel()))
        u = law.u_expr(t, w)
        ode, alg = (cs.substitute(e, m.u, u) if m.u.numel() else e for e in (m.ode, m.alg))
        return LawDAE(t, w, m.x, m.z, m.p, ode, alg)

    return model.cached(("law_dae", law.key()), build)


def require_ode(model: Model, settings: SolverSettings) -> None:
    if model.nz:
        raise SolverError(
            f"{settings.method} needs an explicit ODE but model '{model.name}' keeps "
            f"{model.nz} algebraic unknowns: use 'idas' or 'collocation'"
        )


def method_options(settings: SolverSettings, defaults: dict) -> dict:
    """Method options: ``defaults`` updated by ``settings.options`` (unknown keys raise)."""
    opts = dict(defaults)
    for key, value in settings.options:
        if key not in defaults:
            raise ParameterError(
                "solver.options", key, f"options of '{settings.method}': {sorted(defaults)}"
            )
        opts[key] = value
    return opts


def require_step(settings: SolverSettings) -> float:
    h = settings.step
    if h is None:
        raise ParameterError(
            "solver.step",
            None,
            f"a step size (0, inf) s: method '{settings.method}' is fixed-step",
        )
    return float(h)
