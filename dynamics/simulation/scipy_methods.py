"""scipy's solvers (the classes behind ``solve_ivp``) on the model's CasADi right-hand
side: ``scipy_rk45``, ``scipy_radau``, ``scipy_bdf``, ``scipy_lsoda``."""

from __future__ import annotations

import casadi as cs
import numpy as np
import scipy.integrate as si
import scipy.sparse as sp

from ..errors import ParameterError
from .common import SegmentDAE, cached_step, method_options, require_ode, seg_bounds
from .settings import Problem, register_method


# --- scipy baselines --------------------------------------------------------------------
class _Buffered:
    """Fast repeated calls of a CasADi Function of (t, x, p, seg) through its buffer.

    ``Function.buffer`` binds numpy arrays once, so a call costs about 0.1 us of
    overhead instead of about 30 us for ``F(t, x, p, seg)`` with conversions.
    """

    def __init__(self, F: cs.Function, p: np.ndarray) -> None:
        self.F = F
        self.t = np.zeros(1)
        self.x = np.zeros(F.size1_in(1))
        self.p = np.ascontiguousarray(p, dtype=float)
        self.seg = np.zeros(2)
        self.out = np.zeros(F.nnz_out(0))
        self.buf, self.trigger = F.buffer()
        for i, arr in enumerate((self.t, self.x, self.p, self.seg)):
            self.buf.set_arg(i, memoryview(arr))
        self.buf.set_res(0, memoryview(self.out))

    def __call__(self, t: float, x: np.ndarray) -> np.ndarray:
        self.t[0] = t
        self.x[:] = x
        self.trigger()
        return self.out.copy()


class _Plain:
    """Calls of the same Function with CasADi's ordinary Python conversions (slow)."""

    def __init__(self, F: cs.Function, p: np.ndarray) -> None:
        self.F, self.p, self.seg = F, p, np.zeros(2)

    def __call__(self, t: float, x: np.ndarray) -> np.ndarray:
        return np.array(self.F(t, x, self.p, self.seg).nonzeros())


_SCIPY = {
    "scipy_rk45": (si.RK45, None),
    "scipy_radau": (si.Radau, "sparse"),
    "scipy_bdf": (si.BDF, "sparse"),
    "scipy_lsoda": (si.LSODA, "dense"),
}


_CALLS: dict[str, type] = {"buffer": _Buffered, "plain": _Plain}
_SCIPY_DEFAULTS: dict[str, dict] = {}
_JACOBIANS = ("exact", "finite_differences")


def _jacobian_callable(F: cs.Function, call, kind: str):
    """``jac(t, x)`` as a scipy sparse CSC (Radau, BDF) or dense array (LSODA)."""
    spy = F.sparsity_out(0)
    indptr, indices = np.array(spy.colind()), np.array(spy.row())
    shape = (spy.size1(), spy.size2())

    def jac(t: float, x: np.ndarray):
        J = sp.csc_matrix((call(t, x), indices, indptr), shape=shape)
        return J if kind == "sparse" else J.toarray()

    return jac


def _scipy(prob: Problem) -> tuple[np.ndarray, np.ndarray]:
    """Drive a scipy OdeSolver step by step (what ``solve_ivp`` does), segment by segment."""
    require_ode(prob)
    s, m = prob.settings, prob.model
    defaults = {"call": "buffer", "jacobian": "exact", "first_step": None, "max_step": np.inf}
    opts = method_options(prob, {**defaults, **_SCIPY_DEFAULTS.get(s.method, {})})
    if opts["call"] not in _CALLS:
        raise ParameterError("solver.options.call", opts["call"], sorted(_CALLS))
    if opts["jacobian"] not in _JACOBIANS:
        raise ParameterError("solver.options.jacobian", opts["jacobian"], _JACOBIANS)
    cls, jac_kind = _SCIPY[s.method]
    if opts["jacobian"] == "finite_differences":
        jac_kind = None  # scipy estimates it by finite differences of the right-hand side
    fun = _CALLS[opts["call"]](cached_step(prob, "rhs", SegmentDAE.rhs), prob.p)
    jcall = None
    if jac_kind:
        Jf = cached_step(prob, "jac", SegmentDAE.jac)
        jcall = _CALLS[opts["call"]](Jf, prob.p)
    X = np.empty((len(prob.t_out), m.nx))
    X[0] = prob.x0
    x = prob.x0
    stats = {"n_steps": 0, "n_rhs": 0, "n_jac": 0, "n_lu": 0, "n_segments": 0}
    kwargs = {"rtol": s.rtol, "atol": s.atol, "max_step": opts["max_step"]}
    if opts["first_step"] is not None:
        kwargs["first_step"] = opts["first_step"]
    for a, b, grid in prob.segments():
        fun.seg[:] = seg_bounds(a, b)
        if jcall is not None:
            jcall.seg[:] = fun.seg
            kwargs["jac"] = _jacobian_callable(Jf, jcall, jac_kind)
        solver = cls(fun, a, x, b, **kwargs)
        x = _scipy_segment(prob, solver, grid, X, stats)
        stats["n_rhs"] += solver.nfev
        stats["n_jac"] += int(getattr(solver, "njev", 0))
        stats["n_lu"] += int(getattr(solver, "nlu", 0))
        stats["n_segments"] += 1
    prob.stats.update(stats)
    return X, np.zeros((len(prob.t_out), 0))


def _scipy_segment(
    prob: Problem, solver, grid: np.ndarray, X: np.ndarray, stats: dict
) -> np.ndarray:
    """Step one segment to its end, filling the output rows of ``grid``; returns x(b)."""
    pos = np.searchsorted(prob.t_out, grid)
    k = 0
    n = 0
    while solver.status == "running":
        t_old = solver.t
        message = solver.step()
        n += 1
        if solver.status == "failed":
            raise prob.fail(f"scipy: {message}", t_old, solver.y)
        if not np.all(np.isfinite(solver.y)):
            raise prob.fail("the state became non-finite", solver.t, solver.y)
        if n > prob.settings.max_steps:
            raise prob.fail(
                f"too many steps (max_steps = {prob.settings.max_steps})", solver.t, solver.y
            )
        j = k + int(np.searchsorted(grid[k:], solver.t, side="right"))
        if j > k:
            dense = solver.dense_output()
            ts = grid[k:j]
            X[pos[k:j]] = np.where((ts == solver.t)[:, None], solver.y[None, :], dense(ts).T)
            k = j
    stats["n_steps"] += n
    return solver.y.copy()


def register_scipy_variant(
    name: str, solver: str, call: str, call_class: type, defaults: dict
) -> None:
    """Register ``name`` as the scipy method ``solver`` (a key of the scipy methods) with its
    own right-hand-side call mode ``call`` (a class built as ``call_class(F, p)`` and called
    as ``f(t, x)``) and option ``defaults``: how a study adds a baseline without the
    library importing it."""
    _CALLS[call] = call_class
    _SCIPY[name] = _SCIPY[solver]
    _SCIPY_DEFAULTS[name] = {"call": call, **defaults}
    register_method(name)(_scipy)


for _name in list(_SCIPY):
    register_method(_name)(_scipy)
