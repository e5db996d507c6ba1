"""Solver settings, the method registry and the problem every method solves.

A leaf of the simulation package: method modules register themselves here, and
:func:`~.simulate.simulate` looks them up by name.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import casadi as cs
import numpy as np

from ..errors import ParameterError, SolverError
from ..modeling.model import Model


@dataclass(frozen=True)
class SolverSettings:
    """How to integrate.

    Attributes
    ----------
    method : str
        A key of :data:`METHODS` ("cvodes", "idas", "scipy_radau", ...).
    rtol, atol : float
        Relative and absolute tolerances (variable-step methods).
    step : float or None
        Step size [s] for fixed-step methods.
    max_steps : int
        Step limit per integration segment before the solver gives up.
    options : tuple of (str, object)
        Extra method options, passed through.
    """

    method: str = "cvodes"
    rtol: float = 1e-6
    atol: float = 1e-9
    step: float | None = None
    max_steps: int = 100_000
    options: tuple = ()

    def __post_init__(self) -> None:
        if self.method not in METHODS:
            raise ParameterError("solver.method", self.method, f"one of {sorted(METHODS)}")
        for name in ("rtol", "atol"):
            v = getattr(self, name)
            if not (0 < v < 1):
                raise ParameterError(f"solver.{name}", v, "(0, 1)")
        if self.step is not None and not self.step > 0:
            raise ParameterError("solver.step", self.step, "(0, inf) s")


@dataclass
class Problem:
    """Everything a method needs: model, numeric vectors, input signals, output grid."""

    model: Model
    p: np.ndarray
    x0: np.ndarray
    z0: np.ndarray
    inputs: list  # one signal per model input, in model.input_names order
    t_out: np.ndarray
    breakpoints: list[float]
    settings: SolverSettings
    stats: dict = field(default_factory=dict)

    def u_at(self, t: float) -> np.ndarray:
        """Input vector at time t [s]."""
        return np.array([float(sig(t)) for sig in self.inputs], dtype=float)

    def u_expr(self, t: cs.SX) -> cs.SX:
        """Input vector as a CasADi expression of symbolic time."""
        parts = [sig.casadi(t) for sig in self.inputs]
        return cs.vertcat(*parts) if parts else cs.SX(0, 1)

    def segments(self) -> list[tuple[float, float, np.ndarray]]:
        """(t_start, t_end, output times in (t_start, t_end]) between breakpoints."""
        edges = sorted({float(self.t_out[0]), float(self.t_out[-1]), *self.breakpoints})
        out = []
        for a, b in zip(edges[:-1], edges[1:], strict=True):
            mask = (self.t_out > a) & (self.t_out <= b)
            out.append((a, b, self.t_out[mask]))
        return out

    def fail(self, why: str, t: float, x: np.ndarray) -> SolverError:
        """A SolverError naming the method, time and state."""
        state = dict(zip(self.model.state_names, np.ravel(x).tolist(), strict=False))
        return SolverError(f"{self.settings.method}: {why}", time=t, state=state)


MethodFn = Callable[[Problem], tuple[np.ndarray, np.ndarray]]
METHODS: dict[str, MethodFn] = {}


def register_method(name: str) -> Callable[[MethodFn], MethodFn]:
    """Decorator: make ``fn(problem) -> (X, Z)`` at ``problem.t_out`` available by name."""

    def deco(fn: MethodFn) -> MethodFn:
        METHODS[name] = fn
        return fn

    return deco
