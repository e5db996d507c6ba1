"""Time-domain simulation of a flattened :class:`~sarcomere.dynamics.modeling.model.Model`.

One entry point, :func:`simulate`, whatever the method; every method returns a
:class:`~sarcomere.dynamics.results.Result` of the same form (time plus every named
signal) with solver statistics in ``result.meta``. Inputs are signals (anything with
``__call__(t)`` and ``casadi(t)``, and optionally ``breakpoints(t0, tf)``), constants
or strings with units. ``simulate`` is a :class:`~.simulator.Simulator` reset at the start state and
advanced once through the output grid: the same path as a closed loop. The integrator
restarts at every breakpoint of an input (a regulator command step is a discontinuity:
stepping across it wastes steps and accuracy).

Methods are registered in :data:`METHODS`; the CasADi SUNDIALS methods are defined
in :mod:`.sundials`, the others in :mod:`.fixed_step` and :mod:`.scipy_methods`.
"""

from __future__ import annotations

import time as _time
from collections.abc import Callable, Mapping, Sequence

import numpy as np

from ..errors import ParameterError, SolverError
from ..modeling.model import Model
from ..results import Result
from .settings import METHODS, SolverSettings
from .simulator import CHUNK_POINTS, Simulator

__all__ = ["METHODS", "MAX_VALUES", "PausableRun", "SolverSettings", "simulate"]

MAX_VALUES = 2e7
"""Default limit on output points x signals of one :func:`simulate` call (160 MB of
float64); ``simulate(..., max_values=...)`` raises it."""


def simulate(
    model: Model,
    t_final: float,
    inputs: Mapping[str, object] | None = None,
    params: Mapping[str, object] | None = None,
    x0: np.ndarray | Mapping[str, float] | None = None,
    z0: np.ndarray | None = None,
    settings: SolverSettings | None = None,
    output_interval: float | None = None,
    t_out: np.ndarray | None = None,
    signals: Sequence[str] | None = None,
    *,
    max_values: float = MAX_VALUES,
    progress: Callable[[float], None] | None = None,
) -> Result:
    """Simulate ``model`` from t = 0 to ``t_final`` [s].

    Parameters
    ----------
    model : Model
        A flattened model.
    t_final : float
        Stop time [s], > 0.
    inputs : mapping, optional
        Input name to a signal, a constant (SI) or a string with a unit ("0.1 MPa");
        unspecified inputs keep their start. A signal's ``unit`` must be its input's
        (the default ``"1"`` is taken as unstated).
    params : mapping, optional
        Parameter overrides by name (SI floats or strings with units).
    x0 : array or mapping, optional
        Initial state (full vector, or a mapping of state names to values).
    z0 : array, optional
        Initial guess of the algebraic unknowns (e.g. ``Equilibrium.z``).
    settings : SolverSettings, optional
        Method and tolerances; default CVODES at rtol 1e-6.
    output_interval, t_out : optional
        Output grid: a spacing [s] (default t_final/500) or explicit times.
    signals : sequence of str, optional
        The signals to return (default: every named signal). Evaluating all of them
        costs about as much as the integration itself on small models.
    max_values : float, keyword
        Refuse a run whose output (points x signals) would exceed this many values.
    progress : callable, keyword, optional
        ``progress(fraction)`` after every integrated piece (a breakpoint or
        :data:`~.simulator.CHUNK_POINTS` output points), fraction in (0, 1].

    Returns
    -------
    Result
        Time [s] and every named signal, with ``meta`` holding solver statistics.

    Raises
    ------
    ParameterError
        For a bad argument or an output larger than ``max_values``.
    SolverError
        When the method fails, the trajectory leaves the physical domain (names the
        time, the state and the cause) or a returned signal is not finite (names it and
        the time). Its ``partial`` is the :class:`Result` of the output points before the
        failure (meta ``status = "incomplete"`` and ``reason``), or None if there are none.
    """
    settings = settings or SolverSettings()
    if not (np.isfinite(t_final) and t_final > 0):
        raise ParameterError("t_final", t_final, "(0, inf) s")
    if t_out is None:
        dt = t_final / 500 if output_interval is None else output_interval
        if not (np.isfinite(dt) and dt > 0):
            raise ParameterError("output_interval", dt, "(0, t_final] s")
        n_points = int(np.ceil(t_final / dt)) + 1
        _check_size(n_points, model, signals, max_values)
        t_out = np.unique(np.append(np.arange(0.0, t_final, dt), t_final))
    t_out = np.asarray(t_out, dtype=float).reshape(-1)
    if len(t_out) < 2:
        raise ParameterError("t_out", t_out.tolist(), "at least two increasing times [s]")
    wanted = list(model.signal_names if signals is None else signals)
    unknown = [n for n in wanted if n not in model.signal_names]
    if unknown:
        raise ParameterError("signals", unknown[:5], f"signals of model '{model.name}'")
    _check_size(len(t_out), model, wanted, max_values)
    sim = Simulator(model, settings, x0=x0, z0=z0, params=params, t0=float(t_out[0]))
    tic = _time.perf_counter()
    try:
        X, Z, U = sim.advance(inputs, t_out, progress)
    except SolverError as exc:  # keep what was computed, marked incomplete
        if isinstance(exc.partial, tuple) and len(exc.partial[0]):
            exc.partial = _result(sim, wanted, *exc.partial, _time.perf_counter() - tic)
            exc.partial.meta.update(status="incomplete", reason=str(exc))
        raise
    return _result(sim, wanted, t_out, X, Z, U, _time.perf_counter() - tic)


def _result(
    sim: Simulator,
    wanted: list[str],
    t_out: np.ndarray,
    X: np.ndarray,
    Z: np.ndarray,
    U: np.ndarray,
    wall: float,
) -> Result:
    """The :class:`Result` of a run of ``sim`` through ``t_out`` (states ``X``, algebraic
    unknowns ``Z``, inputs ``U``, one row per time; ``wall`` its integration time [s])."""
    model, settings = sim.model, sim.settings
    S = sim._signals_at(tuple(wanted), X.T, Z.T, U.T)  # bound buffers: no conversions
    values = {name: S[i] for i, name in enumerate(wanted)}
    units = {name: model.unit(name) for name in values}
    meta = {
        "model": model.name,
        "method": settings.method,
        "rtol": settings.rtol,
        "atol": settings.atol,
        "step": settings.step,
        "wall_time_s": wall,
        "x_final": X[-1].tolist(),
        **sim.stats,
    }
    return Result("time", "s", t_out, values, units, meta).require_finite(settings.method)


def _check_size(
    n_points: int, model: Model, signals: Sequence[str] | None, max_values: float
) -> None:
    n_signals = len(model.signal_names if signals is None else signals)
    total = n_points * n_signals
    if total > max_values:
        raise ParameterError(
            "max_values",
            max_values,
            f">= {total:.3g} for this run, or fewer points or signals",
            f"{n_points} output points x {n_signals} signals = {total:.3g} values "
            f"({total * 8 / 1e6:.0f} MB)",
        )


class PausableRun:
    """A :func:`simulate` run through ``t_out`` that can pause when a wall-time budget is
    spent and go on later where it stopped (the auto policy's "full first",
    docs/numerics.md). It may pause where :func:`simulate` restarts the integrator anyway:
    after every ``points`` output points from the start or from an input's breakpoint
    (:data:`~.simulator.CHUNK_POINTS`). With the default, its integrator restarts where
    :func:`simulate`'s does: the same result for held inputs (steps, staircases; measured
    identical on the packaged step, sweep and vent), within the solver's tolerance for
    smooth ones (a piece's time origin differs: 2e-5 of the length's span on the 30 s
    dither, rtol 1e-6). Arguments as in :func:`simulate` (``t_out`` and ``signals`` required,
    checked by the caller)."""

    def __init__(
        self,
        model: Model,
        inputs: Mapping[str, object] | None,
        params: Mapping[str, object] | None,
        x0: np.ndarray,
        z0: np.ndarray | None,
        settings: SolverSettings,
        t_out: np.ndarray,
        signals: Sequence[str],
        points: int = CHUNK_POINTS,
    ) -> None:
        if not (isinstance(points, int) and points >= 1):
            raise ParameterError("points", points, "an integer >= 1")
        self.t_out = np.asarray(t_out, dtype=float).reshape(-1)
        self.inputs, self.wanted = inputs, list(signals)
        self.sim = Simulator(model, settings, x0=x0, z0=z0, params=params, t0=self.t_out[0])
        self._cuts = _cuts(self.t_out, inputs or {}, points)
        self._done = 0  # pieces integrated
        self._rows: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []
        self.wall_s = 0.0  # integration time so far [s]

    @property
    def finished(self) -> bool:
        return self._done == len(self._cuts) - 1

    @property
    def fraction(self) -> float:
        """Share of the time span integrated, 0..1."""
        t = self.t_out
        return float((t[self._cuts[self._done]] - t[0]) / (t[-1] - t[0]))

    def run(self, budget_s: float = float("inf")) -> bool:
        """Integrate piece after piece until the run is finished (True) or, after a
        piece, ``budget_s`` [s] of wall time since this call is spent (False)."""
        tic = _time.perf_counter()
        while not self.finished:
            lo, hi = self._cuts[self._done], self._cuts[self._done + 1]
            X, Z, U = self.sim.advance(self.inputs, self.t_out[lo : hi + 1])
            first = 0 if self._done == 0 else 1  # a piece's first row ends the one before
            self._rows.append((X[first:], Z[first:], U[first:]))
            self._done += 1
            elapsed = _time.perf_counter() - tic
            if elapsed >= budget_s and not self.finished:
                self.wall_s += elapsed
                return False
        self.wall_s += _time.perf_counter() - tic
        return True

    def result(self) -> Result:
        """The finished run's :class:`Result` (runs what is left first)."""
        self.run()
        X, Z, U = (np.concatenate(parts) for parts in zip(*self._rows, strict=True))
        return _result(self.sim, self.wanted, self.t_out, X, Z, U, self.wall_s)


def _cuts(t_out: np.ndarray, inputs: Mapping[str, object], points: int) -> list[int]:
    """Indices into ``t_out`` of the pieces' ends (and 0): where
    :meth:`~.simulator.Simulator.advance` ends a chunk of ``points`` output points counted
    from the start or from an input's breakpoint."""
    t0, tf = float(t_out[0]), float(t_out[-1])
    bps = {
        float(b)
        for sig in inputs.values()
        if hasattr(sig, "breakpoints")
        for b in sig.breakpoints(t0, tf)
    } - {t0, tf}
    cuts = [0]
    for a, b in zip([t0, *sorted(bps)], [*sorted(bps), tf], strict=True):
        lo = 1 + int(np.searchsorted(t_out[1:], a, side="right"))  # the segment's first
        hi = 1 + int(np.searchsorted(t_out[1:], b, side="right"))  # past its last
        cuts += [i for i in range(lo + points - 1, hi - 1, points)]
    return [*cuts, len(t_out) - 1]
