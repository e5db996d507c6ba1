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
from ..schema import MAX_VALUES
from .settings import METHODS, SolverSettings
from .simulator import Simulator

__all__ = ["METHODS", "MAX_VALUES", "SolverSettings", "simulate"]


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
    known = model.cached(("signal_set",), lambda: frozenset(model.signal_names))
    unknown = [n for n in wanted if n not in known]
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
    direct = model.cached(("direct_columns",), lambda: _direct_columns(model))
    rows = [direct.get(name) for name in wanted]
    if None in rows:
        S = sim._signals_at(tuple(wanted), X.T, Z.T, U.T)  # bound buffers: no conversions
    else:  # states and inputs only: the columns themselves
        S = np.concatenate([X, U], axis=1).T[rows]
    values = dict(zip(wanted, S, strict=True))
    units = model.cached(("units", tuple(wanted)), lambda: [model.unit(n) for n in wanted])
    units = dict(zip(wanted, units, strict=True))
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
    result = Result("time", "s", t_out, values, units, meta)
    return result if np.isfinite(S).all() else result.require_finite(settings.method)


def _direct_columns(model: Model) -> dict[str, int]:
    """The signals that are a state or an input, by their column of ``[X, U]``."""
    names = [*model.state_names, *model.input_names]
    return {name: i for i, name in enumerate(names)}


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
