"""Time-domain simulation of a flattened :class:`~sarcomere.dynamics.model.Model`.

One entry point, :func:`simulate`, whatever the method; every method returns a
:class:`~sarcomere.dynamics.results.Result` of the same form (time plus every named
signal) with solver statistics in ``result.meta``. Inputs are signals (anything with
``__call__(t)``, and optionally ``casadi(t)`` and ``breakpoints(t0, tf)``) or constants.
The integrator restarts at every breakpoint of an input (a regulator command step is a
discontinuity: stepping across it wastes steps and accuracy).

Methods are registered in :data:`METHODS`; the CasADi SUNDIALS methods are defined
here, others (fixed-step, collocation, scipy) in :mod:`sarcomere.dynamics.methods`.
"""

from __future__ import annotations

import time as _time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field

import casadi as cs
import numpy as np

from .equilibrium import out_of_domain
from .errors import ParameterError, SolverError
from .model import Model
from .results import Result


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


from . import methods as _methods  # noqa: E402, F401  (registers rk4, euler, collocation, radau_fixed, scipy_*)
