"""Time-domain simulation of a flattened :class:`~sarcomere.dynamics.modeling.model.Model`.

One entry point, :func:`simulate`, whatever the method; every method returns a
:class:`~sarcomere.dynamics.results.Result` of the same form (time plus every named
signal) with solver statistics in ``result.meta``. Inputs are signals (anything with
``__call__(t)``, and optionally ``casadi(t)`` and ``breakpoints(t0, tf)``) or constants.
The integrator restarts at every breakpoint of an input (a regulator command step is a
discontinuity: stepping across it wastes steps and accuracy).

Methods are registered in :data:`METHODS`; the CasADi SUNDIALS methods are defined
in :mod:`.sundials`, the others in :mod:`.fixed_step` and :mod:`.scipy_methods`.
"""

from __future__ import annotations

import time as _time
from collections.abc import Mapping, Sequence

import casadi as cs
import numpy as np

from ..equilibrium import out_of_domain
from ..errors import ParameterError
from ..modeling.model import Model
from ..results import Result
from . import fixed_step, scipy_methods, sundials  # noqa: F401  (register the methods)
from .settings import METHODS, Problem, SolverSettings


class _Const:
    """A constant input signal."""

    def __init__(self, value: float) -> None:
        self.value = float(value)

    def __call__(self, t):
        return np.full(np.shape(t), self.value) if np.ndim(t) else self.value

    def casadi(self, t: cs.SX) -> cs.SX:
        return cs.SX(self.value)


def _input_signals(model: Model, inputs: Mapping[str, object] | None) -> list:
    inputs = dict(inputs or {})
    unknown = set(inputs) - set(model.input_names)
    if unknown:
        raise ParameterError(
            "inputs", sorted(unknown), f"inputs of model '{model.name}': {model.input_names}"
        )
    out = []
    for name in model.input_names:
        sig = inputs.get(name, model.variables[name].start)
        if callable(sig) and not hasattr(sig, "casadi"):
            raise ParameterError(
                f"inputs.{name}",
                sig,
                "a constant or a signal with casadi(t) (see sarcomere.dynamics.signals): "
                "the integrators need the input as an expression of time",
            )
        out.append(sig if callable(sig) else _Const(float(sig)))
    return out


def _check_input_range(model: Model, signals: list, t_out: np.ndarray) -> None:
    """Refuse an input signal that leaves its variable's range on the output grid."""
    for name, sig in zip(model.input_names, signals, strict=True):
        var = model.variables[name]
        values = np.asarray(sig(t_out), dtype=float) * np.ones_like(t_out)
        bad = np.flatnonzero(~((values >= var.low) & (values <= var.high)))
        if bad.size:
            raise ParameterError(
                name,
                f"{values[bad[0]]:g} {var.unit} at t = {t_out[bad[0]]:g} s",
                f"[{var.low:g}, {var.high:g}] {var.unit}",
                var.description,
            )


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
) -> Result:
    """Simulate ``model`` from t = 0 to ``t_final`` [s].

    Parameters
    ----------
    model : Model
        A flattened model.
    t_final : float
        Stop time [s], > 0.
    inputs : mapping, optional
        Input name to a signal or a constant (SI); unspecified inputs keep their start.
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

    Returns
    -------
    Result
        Time [s] and every named signal, with ``meta`` holding solver statistics.

    Raises
    ------
    SolverError
        When the method fails (names the time, the state and the cause).
    """
    settings = settings or SolverSettings()
    if not (np.isfinite(t_final) and t_final > 0):
        raise ParameterError("t_final", t_final, "(0, inf) s")
    if t_out is None:
        dt = output_interval or t_final / 500
        if not dt > 0:
            raise ParameterError("output_interval", dt, "(0, t_final] s")
        t_out = np.unique(np.append(np.arange(0.0, t_final, dt), t_final))
    t_out = np.asarray(t_out, dtype=float)
    p = model.parameters(params)
    x_init = model.x0()
    if isinstance(x0, Mapping):
        for k, v in x0.items():
            kind, i = model.index(k)
            if kind != "x":
                raise ParameterError("x0", k, f"a state of model '{model.name}'")
            x_init[i] = float(v)
    elif x0 is not None:
        x_init = np.asarray(x0, dtype=float).reshape(-1)
    model.check_finite(x_init, "x")
    wanted = list(model.signal_names if signals is None else signals)
    unknown = [n for n in wanted if n not in model.signal_names]
    if unknown:
        raise ParameterError("signals", unknown[:5], f"signals of model '{model.name}'")
    signals = _input_signals(model, inputs)
    _check_input_range(model, signals, t_out)
    bps = []
    for sig in signals:
        if hasattr(sig, "breakpoints"):
            bps.extend(float(b) for b in sig.breakpoints(t_out[0], t_out[-1]))
    bps = [b for b in bps if t_out[0] < b < t_out[-1]]
    z_init = model.z0() if z0 is None else np.asarray(z0, dtype=float).reshape(-1)
    prob = Problem(model, p, x_init, z_init, signals, t_out, bps, settings)
    tic = _time.perf_counter()
    X, Z = METHODS[settings.method](prob)
    wall = _time.perf_counter() - tic
    return _result(prob, X, Z, wall, wanted)


def _result(prob: Problem, X: np.ndarray, Z: np.ndarray, wall: float, wanted: list[str]) -> Result:
    m = prob.model
    U = (
        np.column_stack([sig(prob.t_out) * np.ones_like(prob.t_out) for sig in prob.inputs])
        if prob.inputs
        else np.zeros((len(prob.t_out), 0))
    )
    if not np.all(np.isfinite(X)):
        bad = np.argwhere(~np.isfinite(X))[0]
        raise prob.fail(
            f"state '{m.state_names[bad[1]]}' became non-finite", prob.t_out[bad[0]], X[bad[0] - 1]
        )
    names = list(dict.fromkeys(wanted + m.bounded_signal_names))
    f = m.signals_function(names, len(prob.t_out))
    P = np.repeat(prob.p[:, None], len(prob.t_out), axis=1)
    S = np.array(f(X.T, Z.T, U.T, P)).reshape(len(names), len(prob.t_out))
    bad = out_of_domain(m, S, names)
    if bad:
        raise prob.fail(f"left the physical domain: {bad}", float(prob.t_out[-1]), X[-1])
    signals = {n: S[i] for i, n in enumerate(names[: len(wanted)])}
    units = {n: m.unit(n) for n in signals}
    meta = {
        "model": m.name,
        "method": prob.settings.method,
        "rtol": prob.settings.rtol,
        "atol": prob.settings.atol,
        "step": prob.settings.step,
        "wall_time_s": wall,
        "x_final": X[-1].tolist(),
        **prob.stats,
    }
    return Result("time", "s", prob.t_out, signals, units, meta)
