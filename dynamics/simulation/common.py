"""What the method families share: the input law over a segment, the model's equations
with that law substituted, and the checks of a method's settings."""

from __future__ import annotations

from dataclasses import dataclass

import casadi as cs
import numpy as np

from ..errors import ParameterError, SolverError
from ..modeling.model import Model
from .settings import SolverSettings


class _Identity:
    """A cache-key element for an unhashable signal: equal only to the same object (the
    key holds a reference, so the object's id cannot be reused while the entry lives)."""

    def __init__(self, obj: object) -> None:
        self.obj = obj

    def __eq__(self, other: object) -> bool:
        return isinstance(other, _Identity) and other.obj is self.obj

    def __hash__(self) -> int:
        return id(self.obj)


def _by_value(sig: object) -> object:
    try:
        hash(sig)
    except TypeError:
        return _Identity(sig)
    return sig


@dataclass(frozen=True)
class InputLaw:
    """How the inputs move over one segment, and what the method's input argument ``w`` is.

    * ``signals is None`` (**held**): every input is constant over the segment and
      ``w = u`` (one value per input). This is the law of :meth:`Simulator.step` with a
      constant ``u`` and of piecewise-constant signals (steps, staircases) between their
      breakpoints: the integrators and step Functions then take ``u`` as an argument.
    * otherwise (**signals**): one signal per input, evaluated as its CasADi expression
      of time clamped into ``[a, b_left]`` with ``w = [a, b_left]`` (the segment start
      and the float just below its end), so a ramp, a sine or a chirp is integrated
      exactly and a jump at ``b`` never leaks into the segment that ends there.
    """

    signals: tuple | None = None

    def key(self) -> object:
        """Value key for caches: None (held) or the signals (by value where hashable)."""
        return None if self.signals is None else tuple(_by_value(s) for s in self.signals)

    def u_expr(self, t: cs.SX, w: cs.SX) -> cs.SX:
        if self.signals is None:
            return w
        tc = cs.fmin(cs.fmax(t, w[0]), w[1])
        parts = [cs.SX(sig.casadi(tc)) for sig in self.signals]
        return cs.vertcat(*parts) if parts else cs.SX(0, 1)

    def size_w(self, nu: int) -> int:
        return nu if self.signals is None else 2


HELD = InputLaw()


def segment_w(a: float, b: float) -> np.ndarray:
    """``w`` of a signals law on ``[a, b)``: ``[a, b_left]``."""
    return np.array([a, np.nextafter(b, -np.inf)])


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
