"""Static equilibrium of a flattened model: ``ode(x, z, u, p) = 0``, ``alg = 0``.

The damped Newton method of :mod:`.newton` on the exact sparse CasADi Jacobian, with
continuation: the
inputs and parameters move from a solved state to their targets in steps that halve
on failure. It never returns silently wrong: a failure raises
:class:`~sarcomere.dynamics.errors.SolverError` with the residual, the iteration count
and the continuation fraction reached; a solution that leaves the physical domain (the
thread pulled straight, a negative air mass) is reported as such.

The same equations are also CasADi Functions, for generated C and for NLPs:
:func:`residual_function` (the residual and its scaled norm) and :func:`newton_function`
(a fixed-budget Newton solve without line search, ``fast_newton``). The continuation
and settling stay here in Python, around them.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import casadi as cs
import numpy as np
import scipy.sparse as sp

from .errors import ParameterError, SolverError
from .modeling.buffered import BufferedCall
from .modeling.model import Model
from .newton import (
    ContinuationFailure,
    NewtonFailure,
    NewtonResult,
    continuation,
    damped_newton,
    row_weights,
)
from .units import to_si

_ARGS = ["x", "z", "u", "p"]


@dataclass
class Equilibrium:
    """A solved operating point: vectors, named signals and solver diagnostics."""

    x: np.ndarray
    z: np.ndarray
    u: np.ndarray
    p: np.ndarray
    signals: dict[str, float]
    residual: float
    iterations: int

    def __getitem__(self, name: str) -> float:
        return self.signals[name]


def _residual(m: Model) -> tuple[cs.SX, cs.SX, cs.SX]:
    """``w = [x; z]``, ``r = [ode; alg]`` and its Jacobian in ``w`` (the model's own
    ``d ode / dx`` for an explicit ODE)."""
    if not m.nz:
        return m.x, m.ode, m._jacobian("ode", "x")
    w = cs.vertcat(m.x, m.z)
    r = cs.vertcat(m.ode, m.alg)
    return w, r, cs.jacobian(r, w)


def _row_scales(J: cs.SX, scale: cs.SX) -> cs.SX:
    """``1 / max_j |J_ij| scale_j``: each residual compared in its own units."""
    weighted = cs.mtimes(cs.fabs(J), cs.diag(scale))
    rows = [cs.mmax(weighted[i, :]) for i in range(J.size1())]
    return 1.0 / cs.fmax(cs.vertcat(*rows), 1e-300) if rows else cs.SX(0, 1)


def residual_function(model: Model) -> cs.Function:
    """The equilibrium residual as a CasADi Function ``(x, z, u, p) -> (r, norm)``.

    ``r = [ode; alg]`` [units of dx/dt; of the algebraic equations]; ``norm`` [-] its
    infinity norm with row ``i`` divided by ``max_j |dr_i/dw_j| max(|w_j|, 1e-6)``,
    ``w = [x; z]``: at a root, the number :func:`solve_equilibrium` compares with ``tol``.
    """
    w, r, J = _residual(model)
    rs = _row_scales(J, cs.fmax(cs.fabs(w), 1e-6))
    norm = cs.mmax(cs.fabs(r * rs)) if r.numel() else cs.SX(0.0)
    syms = [model.x, model.z, model.u, model.p]
    return cs.Function("residual", syms, [r, norm], _ARGS, ["r", "norm"])


def newton_function(model: Model, iterations: int = 30) -> cs.Function:
    """Newton's method on the equilibrium residual as a CasADi Function that generates C:
    ``(x0, z0, u, p) -> (x, z, residual)``.

    CasADi's ``fast_newton``: full steps, no line search, at most ``iterations`` steps
    (fewer once a step is exactly zero). It never raises: ``residual`` [-] is the
    scaled norm of :func:`residual_function` at the result, so compare it with a
    tolerance (e.g. ``1e-10``). Start it near an equilibrium; from far away use
    :func:`solve_equilibrium`, whose continuation and settling stay in Python. Build it
    once and keep it.

    Examples
    --------
    >>> from sarcomere.dynamics.assemblies import hanging_load
    >>> m = hanging_load(2, load_kg=0.05)
    >>> eq = solve_equilibrium(m, {"regulator.p_cmd": 3e4})
    >>> out = newton_function(m)(x0=1.001 * eq.x, z0=eq.z, u=eq.u, p=eq.p)
    >>> bool(out["residual"] < 1e-10)
    True
    """
    if isinstance(iterations, bool) or not isinstance(iterations, int) or iterations < 1:
        raise ParameterError("iterations", iterations, "an integer >= 1")
    m = model
    w, r, _ = _residual(m)
    up = cs.vertcat(m.u, m.p)
    g = cs.Function("g", [w, up], [r])
    opts = {"max_iter": iterations, "abstol": 0.0, "abstolStep": 0.0, "error_on_fail": False}
    solve = cs.rootfinder("equilibrium_newton", "fast_newton", g, opts)
    x0, z0 = cs.MX.sym("x0", m.nx), cs.MX.sym("z0", m.nz)
    u, p = cs.MX.sym("u", m.u.numel()), cs.MX.sym("p", m.p.numel())
    wf = solve(cs.vertcat(x0, z0), cs.vertcat(u, p))
    x, z = wf[: m.nx], wf[m.nx :]
    norm = residual_function(m)(x, z, u, p)[1]
    return cs.Function(
        "equilibrium", [x0, z0, u, p], [x, z, norm], ["x0", "z0", "u", "p"], ["x", "z", "residual"]
    )


class _Newton:
    """Cached residual and Jacobian Functions of one model."""

    def __init__(self, model: Model) -> None:
        m = model
        w, r, J = _residual(m)
        self.model = m
        self.F = BufferedCall(cs.Function("F", [w, m.u, m.p], [r]))
        self.J = BufferedCall(cs.Function("J", [w, m.u, m.p], [J]))
        pattern = J.sparsity()  # the Jacobian's nonzeros, as CasADi's own sparse() gives
        self.pattern = (np.array(pattern.row()), np.array(pattern.colind()), pattern.shape)
        self.sig = m.function("signals")

    def jacobian(self, w, u, p) -> sp.csc_matrix:
        rows, colind, shape = self.pattern
        return sp.csc_matrix((self.J(w, u, p), rows, colind), shape=shape)

    def solve(self, w0, u, p, tol, max_iter) -> np.ndarray:
        """Damped Newton from ``w0``, each residual row scaled by its largest Jacobian
        entry times ``max(|w0_j|, 1e-6)`` (raises :class:`NewtonFailure`)."""
        scale = np.maximum(np.abs(w0), 1e-6)
        return damped_newton(
            lambda w: (self.F(w, u, p), self.jacobian(w, u, p)),
            w0,
            residual=lambda w: self.F(w, u, p),
            weights=lambda J: row_weights(J, scale),
            tol=tol,
            max_iter=max_iter,
        )


def solve_equilibrium(
    model: Model,
    inputs: Mapping[str, float] | None = None,
    params: Mapping[str, object] | None = None,
    guess: Equilibrium | None = None,
    tol: float = 1e-10,
    max_iter: int = 60,
    min_fraction_step: float = 1e-4,
) -> Equilibrium:
    """Equilibrium for constant ``inputs`` (by name, SI) and parameter overrides.

    Continuation starts from ``guess`` (or from the model's start values with its
    default inputs and parameters) and moves linearly to the target inputs and
    parameters; each step that fails is halved, down to ``min_fraction_step``.

    Raises
    ------
    ParameterError
        For an input name that is not an input of the model, or a bad parameter.
    SolverError
        If no equilibrium is found (with the cause, residual and how far the
        continuation got), or if it leaves the physical domain.
    """
    m = model
    newton = m.cached("equilibrium.newton", lambda: _Newton(m))
    u_target = m.u0()
    for k, v in (inputs or {}).items():
        if k not in m.input_names:
            raise ParameterError("inputs", k, f"an input of model '{m.name}': {m.input_names}")
        u_target[m.input_names.index(k)] = _input_value(m, k, v)
    p_target = m.parameters(params)
    if guess is None:  # first the model's own operating point, then continue from it
        u_start, p_start = m.u0(), m.parameters()
        w = _start_point(newton, u_start, p_start, tol, max_iter)
    else:
        w = np.concatenate([guess.x, guess.z])
        u_start, p_start = guess.u, guess.p

    def advance(last: NewtonResult, frac: float) -> NewtonResult:
        u = u_start + frac * (u_target - u_start)
        p = p_start + frac * (p_target - p_start)
        found = newton.solve(last.x, u, p, tol, max_iter)
        _check_domain(newton, found.x, u, p)
        return found

    try:
        sol = continuation(advance, NewtonResult(w, np.inf, 0), min_fraction_step)
    except ContinuationFailure as stop:
        f = stop.failure
        raise SolverError(
            f"equilibrium of '{m.name}' not found: {f.why} (scaled residual {f.residual:.3g} "
            f"after {f.iterations} Newton iterations); continuation reached "
            f"{100 * stop.fraction:.3g} % of the way to the target inputs/parameters"
        ) from None
    w = sol.x
    x, z = w[: m.nx], w[m.nx :]
    vals = np.array(newton.sig(x, z, u_target, p_target)).ravel()
    signals = dict(zip(m.signal_names, vals.tolist(), strict=True))
    return Equilibrium(
        x,
        z,
        u_target,
        p_target,
        signals,
        sol.residual,
        sol.iterations,
    )


SETTLE_TIME_S = 10.0
"""Simulated time [s] of the fallback that lets a model settle before Newton."""


def _input_value(m: Model, name: str, raw: object) -> float:
    """An input value in SI (numbers or quantity strings), finite and inside its bounds."""
    var = m.variables[name]
    value = to_si(raw, var.unit, f"inputs.{name}")
    if not (np.isfinite(value) and var.contains(value)):
        raise var.refuse(f"inputs.{name}", raw)
    return value


def _start_point(newton: _Newton, u: np.ndarray, p: np.ndarray, tol: float, max_iter: int):
    """The equilibrium at the start values: Newton from the start values, or, where that
    fails (long chains start far from it), Newton after letting the dynamics settle."""
    m = newton.model
    w0 = np.concatenate([m.x0(p), m.z0(p)])
    try:
        w = newton.solve(w0, u, p, tol, max_iter).x
        _check_domain(newton, w, u, p)
        return w
    except NewtonFailure as first:
        if m.nz:
            raise SolverError(
                f"no equilibrium of '{m.name}' at its start values: {first.why}"
            ) from None
        why = first.why
    try:
        x = _settle(m, u, p)
        w = newton.solve(x, u, p, tol, max_iter).x
        _check_domain(newton, w, u, p)
        return w
    except (SolverError, NewtonFailure) as exc:
        raise SolverError(
            f"no equilibrium of '{m.name}' at its start values: Newton from the start values "
            f"failed ({why}), and after {SETTLE_TIME_S:g} s of settling: "
            f"{getattr(exc, 'why', exc)}"
        ) from None


def _settle(m: Model, u: np.ndarray, p: np.ndarray) -> np.ndarray:
    """The state after SETTLE_TIME_S of the model's own dynamics at constant ``u`` (a
    pseudo-transient start for Newton; CVODES on the flattened ODE, explicit models only)."""
    F = m.cached("equilibrium.settle", lambda: _settle_integrator(m))
    try:
        x = np.array(F(x0=m.x0(p), p=np.concatenate([u, p]))["xf"]).ravel()
    except RuntimeError as exc:
        raise SolverError(f"settling failed: {str(exc).strip().splitlines()[-1][:200]}") from None
    if not np.all(np.isfinite(x)):
        raise SolverError("settling gave a non-finite state")
    return x


def _settle_integrator(m: Model) -> cs.Function:
    """CVODES over SETTLE_TIME_S on the model's ODE, with ``p = [u; p]`` (built once per model)."""
    uv, pv = cs.SX.sym("u", m.u.numel()), cs.SX.sym("p", m.p.numel())
    ode = m.function("ode")(m.x, cs.SX(0, 1), uv, pv)
    dae = {"x": m.x, "p": cs.vertcat(uv, pv), "ode": ode}
    opts = {"abstol": 1e-10, "reltol": 1e-6, "max_num_steps": 100_000}
    opts["disable_internal_warnings"] = True
    return cs.integrator("settle", "cvodes", dae, 0.0, SETTLE_TIME_S, opts)


def _check_domain(newton: _Newton, w: np.ndarray, u: np.ndarray, p: np.ndarray) -> None:
    """Reject a root outside the physical domain of any bounded signal (raises
    NewtonFailure, so the continuation step shrinks)."""
    m = newton.model
    bad = out_of_domain(m, np.array(newton.sig(w[: m.nx], w[m.nx :], u, p)).ravel()[:, None])
    if bad:
        raise NewtonFailure(bad, np.inf, 0)


def out_of_domain(model: Model, values: np.ndarray, names: list[str] | None = None) -> str:
    """A message naming the first signal outside its ``[low, high]`` bounds, or "".

    ``values``: the signals ``names`` (default ``model.signal_names``), shape
    (n_signals, n_points).
    """
    names = model.signal_names if names is None else names
    low, high = model.cached(
        ("domain", *names),
        lambda: (
            np.array([model.variables[n].low for n in names])[:, None],
            np.array([model.variables[n].high for n in names])[:, None],
        ),
    )
    bad = np.flatnonzero(np.any((values < low) | (values > high), axis=1))
    if not bad.size:
        return ""
    i = int(bad[0])
    name, var, row = names[i], model.variables[names[i]], values[i]
    out = np.flatnonzero((row < var.low) | (row > var.high))
    return (
        f"{name} = {row[out[0]]:.4g} {var.unit} is outside its physical domain "
        f"{var.range_str} ({var.description})"
    )
