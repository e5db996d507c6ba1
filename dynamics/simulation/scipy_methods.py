"""scipy's solvers (the classes behind ``solve_ivp``) on the model's CasADi right-hand
side: ``scipy_rk45``, ``scipy_radau``, ``scipy_bdf``, ``scipy_lsoda``."""

from __future__ import annotations

import casadi as cs
import numpy as np
import scipy.sparse as sp

from ..errors import ParameterError
from ..modeling.buffered import BufferedCall
from .common import LawDAE, law_dae, method_options, require_ode
from .settings import Segment, add_stats, register_method


# --- scipy baselines --------------------------------------------------------------------
class _Buffered(BufferedCall):
    """``f(t, x)`` of a CasADi Function of (t, x, w, p) on bound buffers
    (:class:`~..modeling.buffered.BufferedCall`), ``p`` fixed; the input law's argument
    is set in place: ``call.w[:] = ...``. Writes ``t`` and ``x`` alone: about 1 us a call,
    a third of the general call's."""

    def __init__(self, F: cs.Function, p: np.ndarray) -> None:
        super().__init__(F)
        self.t, self.x, self.w, p_arg = self.args
        p_arg[:] = p

    def __call__(self, t: float, x: np.ndarray) -> np.ndarray:
        self.t[0] = t
        self.x[:] = x
        self.trigger()
        return self.res[0].copy()


class _Plain:
    """Calls of the same Function with CasADi's ordinary Python conversions (slow)."""

    def __init__(self, F: cs.Function, p: np.ndarray) -> None:
        self.F, self.p, self.w = F, p, np.zeros(F.size1_in(2))

    def __call__(self, t: float, x: np.ndarray) -> np.ndarray:
        return np.array(self.F(t, x, self.w, self.p).nonzeros())


_SCIPY = {  # method -> (scipy.integrate class, Jacobian kind); scipy.integrate (and with it
    # scipy.optimize, 0.3 s) is imported only when a scipy method runs
    "scipy_rk45": ("RK45", None),
    "scipy_radau": ("Radau", "sparse"),
    "scipy_bdf": ("BDF", "sparse"),
    "scipy_lsoda": ("LSODA", "dense"),
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


def _scipy(seg: Segment) -> tuple[np.ndarray, np.ndarray]:
    """Drive a scipy OdeSolver step by step (what ``solve_ivp`` does) through one segment."""
    s, m = seg.settings, seg.model
    require_ode(m, s)
    defaults = {"call": "buffer", "jacobian": "exact", "first_step": None, "max_step": np.inf}
    opts = method_options(s, {**defaults, **_SCIPY_DEFAULTS.get(s.method, {})})
    if opts["call"] not in _CALLS:
        raise ParameterError("solver.options.call", opts["call"], sorted(_CALLS))
    if opts["jacobian"] not in _JACOBIANS:
        raise ParameterError("solver.options.jacobian", opts["jacobian"], _JACOBIANS)
    import scipy.integrate as si

    name, jac_kind = _SCIPY[s.method]
    cls = getattr(si, name)
    if opts["jacobian"] == "finite_differences":
        jac_kind = None  # scipy estimates it by finite differences of the right-hand side
    lk = seg.law.key()
    fun = _CALLS[opts["call"]](m.cached(("rhs", lk), lambda: law_dae(m, seg.law).rhs()), seg.p)
    fun.w[:] = seg.w
    kwargs = {"rtol": s.rtol, "atol": s.atol, "max_step": opts["max_step"]}
    if opts["first_step"] is not None:
        kwargs["first_step"] = opts["first_step"]
    if jac_kind:
        Jf = m.cached(("jac", lk), lambda: LawDAE.jac(law_dae(m, seg.law)))
        jcall = _CALLS[opts["call"]](Jf, seg.p)
        jcall.w[:] = seg.w
        kwargs["jac"] = _jacobian_callable(Jf, jcall, jac_kind)
    solver = cls(fun, seg.t0, seg.x0, float(seg.times[-1]), **kwargs)
    X = _scipy_segment(seg, solver)
    add_stats(
        seg.stats,
        n_rhs=solver.nfev,
        n_jac=int(getattr(solver, "njev", 0)),
        n_lu=int(getattr(solver, "nlu", 0)),
        n_segments=1,
    )
    return X, np.zeros((len(seg.times), 0))


def _scipy_segment(seg: Segment, solver) -> np.ndarray:
    """Step the solver to the segment's end; the states at ``seg.times``."""
    grid = seg.times
    X = np.empty((len(grid), len(seg.x0)))
    k = 0
    n = 0
    while solver.status == "running":
        t_old = solver.t
        message = solver.step()
        n += 1
        if solver.status == "failed":
            raise seg.fail(f"scipy: {message}", t_old, solver.y)
        if not np.all(np.isfinite(solver.y)):
            raise seg.fail("the state became non-finite", solver.t, solver.y)
        if n > seg.settings.max_steps:
            raise seg.fail(
                f"too many steps (max_steps = {seg.settings.max_steps})", solver.t, solver.y
            )
        j = k + int(np.searchsorted(grid[k:], solver.t, side="right"))
        if j > k:
            dense = solver.dense_output()
            ts = grid[k:j]
            X[k:j] = np.where((ts == solver.t)[:, None], solver.y[None, :], dense(ts).T)
            k = j
    add_stats(seg.stats, n_steps=n)
    return X


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
