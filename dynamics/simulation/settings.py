"""Solver settings, the method registry and the segment every method integrates (with
its input law).

A leaf of the simulation package: method modules register themselves here, and the
:class:`~.simulator.Simulator` looks them up by name.
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING

import casadi as cs
import numpy as np

from ..errors import ParameterError, SolverError

if TYPE_CHECKING:
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

    @functools.cached_property
    def key(self) -> tuple:
        """The settings as a hashable value (option dicts and lists frozen), for caches."""
        return (self.method, self.rtol, self.atol, self.step, self.max_steps, freeze(self.options))


def freeze(value: object) -> object:
    """``value`` with dicts, lists and tuples turned into (sorted) tuples, recursively."""
    if isinstance(value, dict):
        return tuple(sorted((k, freeze(v)) for k, v in value.items()))
    if isinstance(value, list | tuple):
        return tuple(freeze(v) for v in value)
    return value


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


@dataclass
class Segment:
    """One call of a method: integrate from ``(t0, x0, z0)`` through ``times``.

    ``times`` is increasing, ``times[0] > t0``, and its last entry is the end of the
    segment; no input breakpoint lies inside, so the input ``law`` with argument ``w``
    is smooth over the whole segment. Methods add their counters to ``stats``.
    """

    model: Model
    settings: SolverSettings
    p: np.ndarray
    law: InputLaw
    w: np.ndarray
    t0: float
    x0: np.ndarray
    z0: np.ndarray
    times: np.ndarray
    stats: dict

    def fail(self, why: str, t: float, x: np.ndarray) -> SolverError:
        """A SolverError naming the method, time and state."""
        state = dict(zip(self.model.state_names, np.ravel(x).tolist(), strict=False))
        return SolverError(f"{self.settings.method}: {why}", time=t, state=state)


@dataclass
class Pieces:
    """Several segments under one input law, for a method that integrates them in one call
    (:attr:`Method.pieces`). Piece ``k`` runs from the end of piece ``k - 1`` (``t0``,
    ``x0`` for the first) through ``times[ends[k - 1]:ends[k]]`` (``ends[-1]`` = 0) with
    the law's argument ``W[k]``, restarted there as at a :class:`Segment`'s start; the
    states at every time are checked as the simulator checks a segment's: finite, and
    every bounded signal (``model.bounded_signal_names``) inside its range, its inputs
    from the law. ``times``, ``ends`` (int32) and ``W`` are C-contiguous."""

    model: Model
    settings: SolverSettings
    p: np.ndarray
    law: InputLaw
    W: np.ndarray
    t0: float
    x0: np.ndarray
    times: np.ndarray
    ends: np.ndarray
    stats: dict


@dataclass(frozen=True)
class PiecesFailure:
    """Where a :class:`Pieces` run stopped: the ``piece``, and either the method's
    ``cause`` (at time ``t``, state ``x``) or a check that failed at ``row`` of the times:
    a state not finite (``signal`` -1) or bounded signal number ``signal`` at ``value``."""

    piece: int
    cause: str | None = None
    t: float = float("nan")
    x: np.ndarray | None = None
    row: int = -1
    signal: int = -1
    value: float = float("nan")


RunFn = Callable[[Segment], tuple[np.ndarray, np.ndarray]]
StepFn = Callable[["Model", SolverSettings], cs.Function]
PiecesFn = Callable[[Pieces], tuple[np.ndarray, PiecesFailure | None]]


@dataclass(frozen=True)
class Method:
    """A registered method.

    Attributes
    ----------
    run : callable
        ``run(segment) -> (X, Z)``: states and algebraic unknowns at ``segment.times``
        (one row per time).
    step_function : callable or None
        ``step_function(model, settings)`` -> the CasADi Function
        ``step(x, z, u, h, p) -> (xf, zf)`` of one step with the input held; None for
        methods that are not CasADi graphs (scipy's).
    pieces : callable or None
        ``pieces(run) -> (X, failure)``: every piece of a :class:`Pieces` in one call, the
        states at ``run.times`` (rows after a failure undefined) and None or the
        :class:`PiecesFailure`; the same numbers as :attr:`run` piece by piece.
    """

    run: RunFn
    step_function: StepFn | None = None
    pieces: PiecesFn | None = None


METHODS: dict[str, Method] = {}


def register_method(
    name: str, step_function: StepFn | None = None, pieces: PiecesFn | None = None
) -> Callable[[RunFn], RunFn]:
    """Decorator: make ``run(segment) -> (X, Z)`` available as method ``name``."""

    def deco(fn: RunFn) -> RunFn:
        METHODS[name] = Method(fn, step_function, pieces)
        return fn

    return deco


def add_stats(stats: dict, **counts: float | None) -> None:
    """Accumulate counters into ``stats``: sums, except ``max_step_s`` (a maximum) and
    ``None`` (a count the method does not expose)."""
    for key, value in counts.items():
        old = stats.get(key, 0)
        if value is None or old is None:
            stats[key] = None
        elif key == "max_step_s":
            stats[key] = max(old, value)
        else:
            stats[key] = old + value
