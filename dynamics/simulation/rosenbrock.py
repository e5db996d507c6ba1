"""``rodas``: a compiled adaptive Rosenbrock method (Rodas5P, order 5(4), stiffly accurate).

The integrator is C (``c/rodas.c``: Steinebach's Rodas5P, BIT Numer. Math. 63, 27
(2023), in Hairer & Wanner's transformed form): eight linear stages per step on one LU
of ``I / (h gamma) - J`` (no Newton iteration), the embedded order-4 solution as the
error estimate, the step-size controller of Hairer's rodas.f and the method's order-4
dense output for the outputs. It integrates the same generated right-hand side and
sparse Jacobian as ``radau`` (:func:`.radau.generate_sources`, compiled with the same
flags and the model calls and sparse LU it shares with ``radau.c``: ``c/integrator.h``)
into its own shared library per model and input law, memoised on the model and cached on
disk (:mod:`.compiled`).
``df/dt`` (an input signal's time dependence) is a one-sided difference per step, as in
rodas.f; a held input needs none.

Why Rodas5P and not Rodas4: both are stiffly accurate and L-stable, but Rodas4 falls to
order 2 on a stiff state that follows a moving input (the Prothero-Robinson problem: the
ramp scene's regulator and chambers) and its dense output does not converge there
(measured on a sine-driven lag with tau = 0.1 ms: 3e-4 between the steps at every step
size; on the ramp scene at rtol 1e-8 it took 4.1x radau's steps, 1506 against 364, on
the held step scene 1.25x). Rodas5P keeps order 4 at the step ends and in between
(``tests/dynamics/simulation/test_rodas.py``), and its order 5 matches radau's at the
tight end, for two more stages per step. Explicit ODEs only (``nz = 0``,
as ``radau``): a model with algebraic unknowns is refused (``docs/numerics.md``).
"""

from __future__ import annotations

import ctypes
import time
from dataclasses import dataclass
from pathlib import Path

import casadi as cs
import numpy as np

from ..errors import ParameterError, SolverError
from ..modeling.model import Model
from . import compiled, radau
from .common import law_dae, method_options, require_ode
from .settings import InputLaw, Segment, SolverSettings, add_stats, register_method

SOURCE = Path(__file__).parent / "c" / "rodas.c"
"""The integrator's C source (package data)."""

_CAUSES = {
    **{code: radau.CAUSES[code] for code in (1, 2, 4, 5)},  # integrator.h's codes
    6: "right-hand side evaluation failed (NaN or inf) at 11 step sizes in a row",
    7: "iteration matrix I/(h gamma) - J singular at 11 step sizes in a row",
}
_STATS = ("n_steps", "n_rejected", "n_rhs", "n_jac", "n_lu")
_N_STATS = 7  # the C side's ST_N
_DEFAULTS = {"first_step": None, "max_step": np.inf}


@dataclass(frozen=True)
class Library:
    """A compiled Rodas5P for one model and input law.

    Attributes
    ----------
    n : int
        Number of states.
    run : ctypes function
        ``sm_rodas`` (see ``c/rodas.c``).
    handle : ctypes.CDLL
        The loaded library (kept so it stays loaded).
    autonomous : bool
        Whether the right-hand side is free of ``t`` (then no ``df/dt``).
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
    autonomous: bool
    build_s: float
    path: Path
    compiled: bool


def library(model: Model, law: InputLaw) -> Library:
    """The compiled Rodas5P of ``model`` under ``law``: memoised on the model by the law,
    and on disk by content hash."""
    return model.cached(("rodas", law.key()), lambda: _build(model, law))


def _build(model: Model, law: InputLaw) -> Library:
    tic = time.perf_counter()
    d = law_dae(model, law)
    rhs = cs.Function("sm_rhs", [d.t, d.x, d.w, d.p], [d.ode])

    def units(folder: Path) -> list[compiled.Unit]:
        sources = radau.generate_sources(rhs, folder)
        return [compiled.Unit(SOURCE, radau.CFLAGS)] + [
            compiled.Unit(s, radau.MODEL_CFLAGS) for s in sources
        ]

    # the key: as radau's (the generator lives in radau.py), with this integrator's source
    inputs = [rhs.serialize(), cs.__version__, Path(radau.__file__).read_bytes()]
    inputs += [Path(__file__).read_bytes(), SOURCE.read_bytes()]
    inputs += [h.read_bytes() for h in radau.HEADERS]
    inputs += [" ".join(radau.CFLAGS), " ".join(radau.MODEL_CFLAGS), str(radau.CHUNK)]
    try:
        path, built = compiled.shared_library("rodas", inputs, units)
    except SolverError as e:
        raise SolverError(f"rodas: {e}") from None
    handle = ctypes.CDLL(str(path))
    fn = handle.sm_rodas
    fn.restype = ctypes.c_int
    ptr, i32, f64 = ctypes.c_void_p, ctypes.c_int, ctypes.c_double
    fn.argtypes = [i32, ptr, ptr, f64, ptr, i32, ptr, ptr, ptr, ctypes.c_long, i32, ptr, ptr]
    autonomous = not cs.depends_on(d.ode, d.t)
    return Library(model.nx, fn, handle, autonomous, time.perf_counter() - tic, path, built)


def _options(s: SolverSettings) -> np.ndarray:
    """The checked options: ``[rtol, atol, first_step or 0, max_step]``."""
    opts = method_options(s, _DEFAULTS)
    first, hmax = opts["first_step"], float(opts["max_step"])
    if first is not None and not (np.isfinite(first) and first > 0):
        raise ParameterError("solver.options.first_step", first, "(0, inf) s, or None")
    if not hmax > 0:
        raise ParameterError("solver.options.max_step", hmax, "(0, inf] s")
    return np.array([s.rtol, s.atol, first or 0.0, hmax])


def _run(seg: Segment) -> tuple[np.ndarray, np.ndarray]:
    s, m = seg.settings, seg.model
    require_ode(m, s)
    opt = m.cached(("rodas_options", s.key), lambda: _options(s))  # read only
    lib = library(m, seg.law)
    times = np.ascontiguousarray(seg.times, dtype=float)
    x = np.array(seg.x0, dtype=float)
    X = np.empty((len(times), lib.n))
    w = np.ascontiguousarray(seg.w, dtype=float)
    p = np.ascontiguousarray(seg.p, dtype=float)
    stats = np.zeros(_N_STATS)
    t_fail = np.zeros(1)
    code = lib.run(
        lib.n,
        w.ctypes.data,
        p.ctypes.data,
        float(seg.t0),
        x.ctypes.data,
        len(times),
        times.ctypes.data,
        X.ctypes.data,
        opt.ctypes.data,
        int(s.max_steps),
        int(lib.autonomous),
        stats.ctypes.data,
        t_fail.ctypes.data,
    )
    counts = {k: int(v) for k, v in zip(_STATS, stats, strict=False)}
    add_stats(seg.stats, **counts, n_segments=1)
    if code:
        raise seg.fail(_CAUSES.get(code, f"error code {code}"), float(t_fail[0]), x)
    return X, np.zeros((len(times), 0))


register_method("rodas")(_run)
