"""``radau``: a compiled adaptive Radau IIA method (3 stages, order 5) on the CasADi side.

The integrator is C (``c/radau.c``, the RADAU5 algorithm of Hairer & Wanner): simplified
Newton on the collocation system split into one real and one complex linear system,
Jacobian reuse across steps, the embedded error estimate, Gustafsson's step-size
predictor and outputs from the collocation polynomial. The model's right-hand side under
the input law and its sparse Jacobian (``casadi.jacobian`` of the same expression) are
generated to C by CasADi (:func:`generate_sources`, in pieces of bounded size) and
compiled with it into one shared library per model and input law, memoised on the model
(``Model.cached``) and cached on disk by content hash (:mod:`.compiled`), loaded with
ctypes. One call integrates a whole segment, so Python is paid per segment, not per step.

Why: the model's oscillatory modes lie 73-80 deg from the negative real axis, outside
the stability sectors of BDF4/BDF5, so CVODES needs 6-9x the steps of this A-stable
order-5 method at equal accuracy (``BENCHMARKS.md``, section 1). Explicit ODEs only
(``nz = 0``); the LU works on the nonzeros and their fill-in only (``docs/numerics.md``).
"""

from __future__ import annotations

import ctypes
import os
import time
from dataclasses import dataclass
from pathlib import Path

import casadi as cs
import numpy as np

from ..errors import ParameterError, SolverError
from ..modeling.model import Model
from . import compiled
from .collocation import radau5_packed
from .common import law_dae, method_options, require_ode
from .settings import InputLaw, Segment, SolverSettings, add_stats, register_method

SOURCE = Path(__file__).parent / "c" / "radau.c"
"""The integrator's C source (package data)."""
HEADER = Path(__file__).parent / "c" / "integrator.h"
"""What ``radau.c`` shares with ``rodas.c`` (model calls, sparse LU): included by both."""

_CAUSES = {
    1: "too many steps (max_steps reached)",
    2: "step size became too small (below 10 machine epsilons of t)",
    3: "Newton iteration failed to converge repeatedly (11 step halvings)",
    4: "Jacobian evaluation failed (NaN or inf)",
    5: "out of memory",
    6: "right-hand side evaluation failed (NaN or inf)",
}
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
muscle scenes run at rtol 1e-12 / atol 1e-14 and fail at atol 1e-15 (SI units)."""
_STATS = ("n_steps", "n_rejected", "n_rhs", "n_jac", "n_lu", "n_newton", "n_newton_fail")
_DEFAULTS = {"first_step": None, "max_step": np.inf, "max_newton": 7}


def _packed() -> np.ndarray:
    return radau5_packed()


@dataclass(frozen=True)
class Library:
    """A compiled integrator for one model and input law.

    Attributes
    ----------
    n : int
        Number of states.
    run : ctypes function
        ``sm_radau`` (see ``c/radau.c``).
    handle : ctypes.CDLL
        The loaded library (kept so it stays loaded).
    build_s : float
        Code generation, compile (if any) and load time [s].
    path : Path
        The library in the on-disk cache.
    compiled : bool
        Whether this process compiled it (False: found in the cache).
    """

    n: int
    run: ctypes._CFuncPtr
    handle: ctypes.CDLL
    build_s: float
    path: Path
    compiled: bool


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
    paths = []
    for name, expr in (("sm_rhs", cs.densify(f)), ("sm_jac", jac)):
        gen = cs.CodeGenerator(f"{name}.c", {"casadi_int": "int"})
        gen.add(_chunked(name, args, expr, chunk))
        gen.generate(str(folder) + os.sep)
        paths.append(Path(folder) / f"{name}.c")
    return paths


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


def _build(model: Model, law: InputLaw) -> Library:
    tic = time.perf_counter()
    d = law_dae(model, law)
    rhs = cs.Function("sm_rhs", [d.t, d.x, d.w, d.p], [d.ode])

    def units(folder: Path) -> list[compiled.Unit]:
        sources = generate_sources(rhs, folder)
        return [compiled.Unit(SOURCE, CFLAGS)] + [compiled.Unit(s, MODEL_CFLAGS) for s in sources]

    # the key: the model's expression (serialised: deterministic) and what turns it into
    # C (CasADi's version, this module's code, the chunk size), the sources and flags
    inputs = [rhs.serialize(), cs.__version__, Path(__file__).read_bytes(), SOURCE.read_bytes()]
    inputs += [HEADER.read_bytes()]
    inputs += [" ".join(CFLAGS), " ".join(MODEL_CFLAGS), str(CHUNK)]
    try:
        path, built = compiled.shared_library("radau", inputs, units)
    except SolverError as e:
        raise SolverError(f"radau: {e}") from None
    handle = ctypes.CDLL(str(path))
    fn = handle.sm_radau
    fn.restype = ctypes.c_int
    ptr, i32, f64 = ctypes.c_void_p, ctypes.c_int, ctypes.c_double
    fn.argtypes = [i32, ptr, ptr, f64, ptr, i32, ptr, ptr, ptr, ptr, ctypes.c_long, i32, ptr, ptr]
    return Library(model.nx, fn, handle, time.perf_counter() - tic, path, built)


_TABLEAU = _packed()


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
    stats = np.zeros(len(_STATS))
    t_fail = np.zeros(1)
    code = lib.run(
        nx,
        w.ctypes.data,
        p.ctypes.data,
        float(seg.t0),
        x.ctypes.data,
        len(times),
        times.ctypes.data,
        X.ctypes.data,
        _TABLEAU.ctypes.data,
        opt.ctypes.data,
        int(s.max_steps),
        newton,
        stats.ctypes.data,
        t_fail.ctypes.data,
    )
    add_stats(seg.stats, **{k: int(v) for k, v in zip(_STATS, stats, strict=True)}, n_segments=1)
    if code:
        cause = _CAUSES.get(code, f"error code {code}")
        if code == 3 and (s.atol < ROUNDOFF_ATOL or s.rtol < ROUNDOFF_RTOL):
            cause += (
                f" at atol = {s.atol:g}, rtol = {s.rtol:g}: below the roundoff floor of the"
                " stage equations of this model? (docs/numerics.md: raise atol)"
            )
        raise seg.fail(cause, float(t_fail[0]), x)
    return X, np.zeros((len(times), 0))


register_method("radau")(_run)
