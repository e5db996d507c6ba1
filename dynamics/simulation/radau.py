"""``radau``: a compiled adaptive Radau IIA method (3 stages, order 5) on the CasADi side.

The integrator is C (``c/radau.c``, the RADAU5 algorithm of Hairer & Wanner): simplified
Newton on the collocation system split into one real and one complex linear system,
Jacobian reuse across steps, the embedded error estimate, Gustafsson's step-size
predictor and outputs from the collocation polynomial. The model's right-hand side under
the input law and its sparse Jacobian (``casadi.jacobian`` of the same expression) are
generated to C by CasADi (:func:`generate_sources`, in pieces of bounded size) and
compiled with it into one shared library per model and input law, memoised on the model
(``Model.cached``) and cached on disk by content hash (:mod:`.compiled`), loaded with
ctypes. One call integrates a whole run (``c/radau_runs.c``: every piece between input
breakpoints restarted, the states checked finite and inside the physical domain in C by
the generated ``sm_dom``), so Python is paid per run, not per step or segment.

Why: the model's oscillatory modes lie 73-80 deg from the negative real axis, outside
the stability sectors of BDF4/BDF5, so CVODES needs 6-9x the steps of this A-stable
order-5 method at equal accuracy (``BENCHMARKS.md``, section 1). Explicit ODEs only
(``nz = 0``); the LU works on the nonzeros and their fill-in only (``docs/numerics.md``).
"""

from __future__ import annotations

import ctypes
import os
import time
import weakref
from pathlib import Path

import casadi as cs
import numpy as np

from ..errors import ParameterError, SolverError
from ..modeling.model import Model
from . import compiled
from .collocation import radau5_packed
from .common import law_dae, method_options, require_ode
from .settings import (
    InputLaw,
    Pieces,
    PiecesFailure,
    Segment,
    SolverSettings,
    add_stats,
    register_method,
)

SOURCE = Path(__file__).parent / "c" / "radau.c"
"""The integrator's C source (package data); it includes :data:`HEADERS`."""
HEADERS = tuple(Path(__file__).parent / "c" / h for h in ("integrator.h", "sparse_lu.h"))
"""The headers :data:`SOURCE` includes, directly or through ``integrator.h`` (what it
shares with ``rodas.c``) (package data, copied next to it into an FMU)."""
RUNS_SOURCE = Path(__file__).parent / "c" / "radau_runs.c"
"""The simulator's driver: several pieces in one call, states checked in C (package data)."""

CAUSES = {
    1: "too many steps (max_steps reached)",
    2: "step size became too small (below 10 machine epsilons of t)",
    3: "Newton iteration failed to converge repeatedly (11 step halvings)",
    4: "Jacobian evaluation failed (NaN or inf)",
    5: "out of memory",
    6: "right-hand side evaluation failed (NaN or inf)",
}
"""The C integrators' return codes (``integrator.h``; 1, 2, 4 and 5 mean the same in
``rodas.c``) and what each says in a failure."""
_NONFINITE, _DOMAIN = 7, 8  # radau_runs.c's codes beyond radau.c's
CFLAGS = ("-O3", "-fno-math-errno", "-fcx-limited-range", "-std=c11")
"""Compiler flags of the integrator: no errno from sqrt/pow and C99's NaN-recovery in
complex products left out (neither is ever relied on here): inline arithmetic, 8 %
faster at n = 3."""
MODEL_CFLAGS = ("-O1", "-fno-math-errno", "-std=c11")
"""Compiler flags of the generated right-hand side and Jacobian (``BENCHMARKS.md``,
section 2): GCC's -O2/-O3 passes grow faster than linearly in a function's size (the
n = 100 Jacobian as one function: 28 s at -O1, 420 s at -O2)."""
CHUNK = 2000
"""Most operations per generated C function: the right-hand side and the Jacobian's
nonzeros are split into functions of about this size, so the compile time is linear in n."""
ROUNDOFF_ATOL, ROUNDOFF_RTOL = 1e-14, 1e-12
"""Below these tolerances a Newton failure names the roundoff floor as a likely cause: the
muscle scenes run at rtol 1e-12 / atol 1e-14; the step scene fails at atol 1e-16 (SI units)."""
_STATS = ("n_steps", "n_rejected", "n_rhs", "n_jac", "n_lu", "n_newton", "n_newton_fail")
_DEFAULTS = {"first_step": None, "max_step": np.inf, "max_newton": 7}


def _packed() -> np.ndarray:
    return radau5_packed()


class Library:
    """A compiled integrator for one model and input law, and a pool of integrator
    memories (``sm_radau_new``: work arrays allocated once, taken by one call at a time,
    so threads never share one; freed with the library).

    Attributes
    ----------
    n : int
        Number of states.
    run : ctypes function
        ``sm_radau`` (see ``c/radau.c``): one segment.
    runs : ctypes function
        ``sm_radau_runs`` (see ``c/radau_runs.c``): several pieces, states checked.
    handle : ctypes.CDLL
        The loaded library (kept so it stays loaded).
    build_s : float
        Code generation, compile (if any) and load time [s].
    path : Path
        The library in the on-disk cache.
    compiled : bool
        Whether this process compiled it (False: found in the cache).
    low, high : numpy.ndarray
        The ranges of the bounded signals ``sm_dom`` returns (the model's order).
    """

    def __init__(self, n: int, handle: ctypes.CDLL, build_s: float, path: Path, built: bool,
                 low: np.ndarray, high: np.ndarray) -> None:  # fmt: skip
        ptr, i32, f64, i64 = ctypes.c_void_p, ctypes.c_int, ctypes.c_double, ctypes.c_long
        self.n, self.handle, self.build_s, self.path, self.compiled = (
            n,
            handle,
            build_s,
            path,
            built,
        )
        self.low, self.high = low, high
        self.run = handle.sm_radau
        self.run.restype = i32
        self.run.argtypes = [
            ptr,
            ptr,
            ptr,
            f64,
            ptr,
            i32,
            ptr,
            ptr,
            ptr,
            ptr,
            i64,
            i32,
            ptr,
            ptr,
            i32,
        ]
        self.runs = handle.sm_radau_runs
        self.runs.restype = i32
        self.runs.argtypes = [ptr, i32, i32, ptr, i32, ptr, ptr, f64, ptr, ptr, ptr, ptr, ptr,
                              i64, i32, ptr, ptr, i32, ptr, ptr, ptr, ptr]  # fmt: skip
        handle.sm_radau_new.restype = ptr
        handle.sm_radau_new.argtypes = [i32]
        handle.sm_radau_free.argtypes = [ptr]
        self._pool: list[int] = []
        weakref.finalize(self, _free_all, handle.sm_radau_free, self._pool)

    def acquire(self) -> int:
        """An integrator memory (give it back with :meth:`release`)."""
        try:
            return self._pool.pop()  # atomic: no two callers get the same memory
        except IndexError:
            mem = self.handle.sm_radau_new(self.n)
            if not mem:
                raise SolverError("radau: out of memory") from None
            return mem

    def release(self, mem: int) -> None:
        self._pool.append(mem)


def _free_all(free, pool: list) -> None:
    for mem in pool:
        free(mem)
    pool.clear()


def library(model: Model, law: InputLaw) -> Library:
    """The compiled integrator of ``model`` under ``law``: memoised on the model by the
    law, and on disk by content hash (:mod:`.compiled`), so another process with the
    same model loads it without compiling."""
    return model.cached(("radau", law.key()), lambda: _build(model, law))


def generate_sources(
    rhs: cs.Function, folder: Path, chunk: int = CHUNK, sparse: bool = True
) -> list[Path]:
    """Generate ``sm_rhs`` and ``sm_jac``, the C functions ``c/radau.c`` calls, into
    ``folder``.

    Parameters
    ----------
    rhs : casadi.Function
        An SX Function ``(t, x, w, p) -> f``, ``f`` the state derivative (same size as
        ``x``).
    folder : Path
        Where the sources go: ``sm_rhs.c`` and ``sm_jac.c``.
    chunk : int
        Most operations per generated C function.
    sparse : bool
        False: ``sm_jac`` returns the dense Jacobian (n^2 entries, column-major); the
        integrator takes either.

    Returns
    -------
    list of Path
        The two sources. Both use ``casadi_int = int``; ``sm_jac`` returns the Jacobian
        ``df/dx`` sparse: its nonzeros in the compressed-column pattern that
        ``sm_jac_sparsity_out(0)`` returns (``[nrow, ncol, colind[ncol + 1],
        row[nnz]]``).
    """
    args = rhs.sx_in()
    f = rhs.call(args)[0]
    jac = cs.jacobian(f, args[1])
    jac = jac if sparse else cs.densify(jac)
    return [
        _generate(name, args, e, folder, chunk)
        for name, e in (("sm_rhs", cs.densify(f)), ("sm_jac", jac))
    ]


def _generate(name: str, args: list, expr: cs.SX, folder: Path, chunk: int) -> Path:
    """``name(args) -> expr`` generated (chunked, ``casadi_int = int``) into ``folder``."""
    gen = cs.CodeGenerator(f"{name}.c", {"casadi_int": "int"})
    gen.add(_chunked(name, args, expr, chunk))
    gen.generate(str(folder) + os.sep)
    return Path(folder) / f"{name}.c"


def _chunked(name: str, args: list, expr: cs.SX, chunk: int) -> cs.Function:
    """``name(args) -> expr`` as an MX Function calling SX Functions of at most about
    ``chunk`` operations each (common subexpressions merged inside each)."""
    nz = expr.nonzeros()
    size = cs.Function("size", args, [cs.vertcat(*nz)]).n_instructions()
    pieces = max(1, -(-size // chunk))
    bounds = np.linspace(0, len(nz), pieces + 1).round().astype(int)
    mx = [cs.MX.sym(f"in{k}", a.sparsity()) for k, a in enumerate(args)]
    parts = []
    for k, (a, b) in enumerate(zip(bounds[:-1], bounds[1:], strict=True)):
        if b > a:
            part = cs.Function(f"{name}_{k}", args, [cs.cse(cs.vertcat(*nz[a:b]))])
            parts.append(part.call(mx)[0])
    values = cs.vertcat(*parts) if parts else cs.MX(0, 1)
    return cs.Function(name, mx, [cs.MX(expr.sparsity(), values)])


def cached(model: Model, law: InputLaw) -> Path | None:
    """The library of ``model`` under ``law`` if it is in the disk cache, else None: a
    cache lookup (the key's expressions serialised), no code generation, no compile."""
    path = compiled.library_path("radau", _generated(model, law)[-1])
    return path if path.is_file() else None


def default_method(model: Model, law: InputLaw) -> tuple[str, str]:
    """The method a run gets when it names none, and why (``docs/numerics.md``): the
    compiled ``radau`` if its library for ``model`` under ``law`` is in the disk cache
    (:func:`cached`), else ``cvodes`` (``idas`` for a model with algebraic unknowns),
    never a compile; the choice depends on the cache only, not on time or load."""
    if model.nz:
        return "idas", f"{model.nz} algebraic unknowns: radau takes explicit ODEs only"
    try:
        path = cached(model, law)
    except SolverError as e:  # no C compiler: no key
        return "cvodes", f"radau's library cannot be looked up ({e})"
    if path is None:
        where = compiled.cache_dir() / "lib"
        return "cvodes", f"radau's library for this model and input law is not in {where}"
    return "radau", f"radau's library for this model and input law is cached ({path.name})"


def _generated(model: Model, law: InputLaw) -> tuple:
    """The functions the library is generated from, the domain's bounds, the cache key's
    inputs."""
    d = law_dae(model, law)
    rhs = cs.Function("sm_rhs", [d.t, d.x, d.w, d.p], [d.ode])
    # the bounded signals (the physical domain) under the law, checked by radau_runs.c
    bounded = model.bounded_signal_names
    u = law.u_expr(d.t, d.w)
    dom = cs.densify(model.signals_function(bounded).call([d.x, d.z, u, d.p])[0])
    args = [d.t, d.x, d.w, d.p]
    low = np.array([model.variables[k].low for k in bounded], dtype=float)
    high = np.array([model.variables[k].high for k in bounded], dtype=float)
    # the key: the model's expression (serialised: deterministic) and what turns it into
    # C (CasADi's version, this module's code, the chunk size), the sources and flags
    dom_fn = cs.Function("sm_dom", args, [dom])
    inputs = [rhs.serialize(), dom_fn.serialize(), cs.__version__, Path(__file__).read_bytes()]
    inputs += [f.read_bytes() for f in (SOURCE, *HEADERS, RUNS_SOURCE)]
    inputs += [" ".join(CFLAGS), " ".join(MODEL_CFLAGS), str(CHUNK)]
    return rhs, dom, args, low, high, inputs


def _build(model: Model, law: InputLaw) -> Library:
    tic = time.perf_counter()
    rhs, dom, args, low, high, inputs = _generated(model, law)

    def units(folder: Path) -> list[compiled.Unit]:
        sources = [*generate_sources(rhs, folder), _generate("sm_dom", args, dom, folder, CHUNK)]
        own = [compiled.Unit(SOURCE, CFLAGS), compiled.Unit(RUNS_SOURCE, CFLAGS)]
        return own + [compiled.Unit(s, MODEL_CFLAGS) for s in sources]

    try:
        path, built = compiled.shared_library("radau", inputs, units)
    except SolverError as e:
        raise SolverError(f"radau: {e}") from None
    handle = ctypes.CDLL(str(path))
    return Library(model.nx, handle, time.perf_counter() - tic, path, built, low, high)


_TABLEAU = _packed()
_TABLEAU_PTR = _TABLEAU.ctypes.data


def _options(s: SolverSettings) -> tuple[np.ndarray, int]:
    """The checked options: ``[rtol, atol, first_step or 0, max_step]`` and max_newton."""
    opts = method_options(s, _DEFAULTS)
    first, hmax, newton = opts["first_step"], float(opts["max_step"]), opts["max_newton"]
    if first is not None and not (np.isfinite(first) and first > 0):
        raise ParameterError("solver.options.first_step", first, "(0, inf) s, or None")
    if not hmax > 0:
        raise ParameterError("solver.options.max_step", hmax, "(0, inf] s")
    if not (isinstance(newton, int) and 2 <= newton <= 50):
        why = "the convergence test needs the contraction rate of two increments"
        raise ParameterError("solver.options.max_newton", newton, "an integer in [2, 50]", why)
    return np.array([s.rtol, s.atol, first or 0.0, hmax]), newton


def _cause(code: int, s: SolverSettings) -> str:
    cause = CAUSES.get(code, f"error code {code}")
    if code == 3 and (s.atol < ROUNDOFF_ATOL or s.rtol < ROUNDOFF_RTOL):
        cause += (
            f" at atol = {s.atol:g}, rtol = {s.rtol:g}: below the roundoff floor of the"
            " stage equations of this model? (docs/numerics.md: raise atol)"
        )
    return cause


def _add(stats: dict, counts: np.ndarray, segments: int) -> None:
    add_stats(stats, **dict(zip(_STATS, counts.astype(int).tolist(), strict=False)),
              n_segments=segments)  # fmt: skip


def _run(seg: Segment) -> tuple[np.ndarray, np.ndarray]:
    s, m = seg.settings, seg.model
    require_ode(m, s)
    opt, newton = m.cached(("radau_options", s.key), lambda: _options(s))  # read only
    lib = library(m, seg.law)
    nx = lib.n
    times = np.ascontiguousarray(seg.times, dtype=float)
    x = np.array(seg.x0, dtype=float)
    X = np.empty((len(times), nx))
    w = np.ascontiguousarray(seg.w, dtype=float)
    p = np.ascontiguousarray(seg.p, dtype=float)
    stats = np.zeros(len(_STATS) + 1)  # + t_fail
    mem = lib.acquire()
    try:
        code = lib.run(mem, w.ctypes.data, p.ctypes.data, float(seg.t0), x.ctypes.data,
                       len(times), times.ctypes.data, X.ctypes.data, _TABLEAU_PTR,
                       opt.ctypes.data, int(s.max_steps), newton, stats.ctypes.data,
                       stats[-1:].ctypes.data, 0)  # fmt: skip
    finally:
        lib.release(mem)
    _add(seg.stats, stats[:-1], 1)
    if code:
        raise seg.fail(_cause(code, s), float(stats[-1]), x)
    return X, np.zeros((len(times), 0))


def _bound(model: Model, law: InputLaw, s: SolverSettings) -> tuple:
    """What every call with ``(model, law, s)`` passes alike: the library, the addresses
    of the options and of the domain's bounds (arrays kept alive here), max_newton."""
    opt, newton = _options(s)
    lib = library(model, law)
    return lib, opt, opt.ctypes.data, newton, lib.low.ctypes.data, lib.high.ctypes.data


def _run_pieces(run: Pieces) -> tuple[np.ndarray, PiecesFailure | None]:
    """All pieces of ``run`` in one C call (``radau_runs.c``): the states at every time,
    checked finite and inside the physical domain there."""
    s, m = run.settings, run.model
    require_ode(m, s)
    key = ("radau_bound", run.law.key(), s.key)
    lib, _, opt, newton, low, high = m.cached(key, lambda: _bound(m, run.law, s))
    nx, nb = lib.n, len(lib.low)
    times, ends = run.times, run.ends
    X = np.empty((len(times), nx))
    x = np.array(run.x0, dtype=float)
    # counters, t_fail, failure info (4), room for the bounded signals
    work = np.zeros(12 + nb)
    w0 = work.ctypes.data
    mem = lib.acquire()
    try:
        code = lib.runs(mem, nx, len(ends), ends.ctypes.data, run.W.shape[1], run.W.ctypes.data,
                        run.p.ctypes.data, run.t0, x.ctypes.data, times.ctypes.data,
                        X.ctypes.data, _TABLEAU_PTR, opt, s.max_steps, newton, w0, w0 + 56, nb,
                        low, high, w0 + 96, w0 + 64)  # fmt: skip
    finally:
        lib.release(mem)
    piece = int(work[8]) if code else len(ends)
    _add(run.stats, work[:7], min(piece + 1, len(ends)))
    if not code:
        return X, None
    if code == _NONFINITE:
        return X, PiecesFailure(piece, row=int(work[9]))
    if code == _DOMAIN:
        return X, PiecesFailure(piece, row=int(work[9]), signal=int(work[10]), value=work[11])
    return X, PiecesFailure(piece, cause=_cause(code, s), t=float(work[7]), x=x)


register_method("radau", pieces=_run_pieces)(_run)
