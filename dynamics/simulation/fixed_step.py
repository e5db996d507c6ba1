"""Fixed-step methods, registered in :data:`~.settings.METHODS`.

* ``rk4``: classic explicit Runge-Kutta (4 stages, order 4); needs ``step``.
* ``euler``: explicit Euler (order 1, a stability yardstick); needs ``step``.
* ``collocation``: one element of CasADi's ``integrator("collocation")`` per step
  (Radau points, 3 by default: order 5; ODE or DAE); needs ``step``.
* ``radau_fixed``: Radau IIA with 3 points (order 5), Newton on SX residuals;
  needs ``step``.

Each method is a **core step Function** ``(x, z, w, t, h, p) -> (xf, zf)`` built once per
model, settings and input law (:class:`~.common.InputLaw`; memoised with
:meth:`Model.cached`): ``w`` is the input ``u`` itself when the input is held over the
step, or the segment bounds ``[a, b_left]`` when signals are integrated as expressions
of time. :func:`step_function` exposes the held form as ``step(x, z, u, h, p)`` for
optimal control. A segment is marched with ``mapaccum`` chunks of the core.

* **Fixed steps** land on every output time and breakpoint: each output interval is
  split into ``ceil(interval / step)`` equal steps, so no step exceeds
  ``settings.step`` (an output grid finer than the step makes the steps smaller).
* **Statistics** ``n_steps``, ``n_rhs``, ``n_jac`` (``None`` where the method does
  not expose the count), ``n_segments`` and ``max_step_s`` go to ``segment.stats``.
* **Failures** raise :class:`~.errors.SolverError` naming the time and the cause; a
  non-finite state is a failure, never a result.

The stability guard of ``rk4`` and ``euler`` (:mod:`.guard`) is run by the simulator
before the first segment after a reset.
"""

from __future__ import annotations

from dataclasses import dataclass

import casadi as cs
import numpy as np

from ..errors import ParameterError, SolverError
from ..modeling.model import Model
from . import collocation
from .common import LawDAE, law_dae, method_options, require_ode, require_step
from .guard import SCHEMES, ExplicitScheme
from .settings import HELD, InputLaw, Segment, SolverSettings, add_stats, register_method

CHUNK_STEPS = 128
"""Most fixed steps per CasADi call (``mapaccum``); a shorter run uses the next power of
two, and the last chunk is padded with h = 0."""


# --- fixed-step marching ----------------------------------------------------------------
def step_grid(
    a: float, b: float, outs: np.ndarray, h: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Steps of at most ``h`` [s] from ``a`` to ``b`` landing on every output time.

    Returns
    -------
    (numpy.ndarray, numpy.ndarray, numpy.ndarray)
        Step start times [s], step sizes [s], and for each output time in ``outs``
        the index of the step that ends on it.
    """
    edges = np.unique(np.concatenate([[a], outs, [b]]))
    lengths = np.diff(edges)
    counts = np.maximum(np.ceil(lengths / h * (1.0 - 1e-12)).astype(int), 1)
    sizes = np.repeat(lengths / counts, counts)
    first = np.repeat(edges[:-1], counts)
    within = np.arange(counts.sum()) - np.repeat(np.cumsum(counts) - counts, counts)
    starts = first + within * sizes
    ends = np.cumsum(counts) - 1
    out_idx = ends[np.searchsorted(edges[1:], outs)]
    return starts, sizes, out_idx


def max_substep(edges: np.ndarray, h: float) -> float:
    """The largest step [s] :func:`step_grid` takes between consecutive ``edges``."""
    lengths = np.diff(np.unique(edges))
    return float(np.max(lengths / np.maximum(np.ceil(lengths / h * (1.0 - 1e-12)), 1)))


def _march(
    seg: Segment, key: tuple, step: cs.Function, rhs_per_step: int | None
) -> tuple[np.ndarray, np.ndarray]:
    """Run a core step Function ``(x, z, w, t, h, p) -> (xf, zf)`` through the segment."""
    s = seg.settings
    h = require_step(s)
    starts, sizes, out_idx = step_grid(seg.t0, float(seg.times[-1]), seg.times, h)
    if len(starts) > s.max_steps:
        raise seg.fail(
            f"{len(starts)} steps of {h:.3g} s needed in [{seg.t0:.6g}, {seg.times[-1]:.6g}] s, "
            f"more than max_steps = {s.max_steps}",
            seg.t0,
            seg.x0,
        )
    n_chunk = min(CHUNK_STEPS, 1 << (len(starts) - 1).bit_length())
    chunk = seg.model.cached(
        (*key, "chunk", n_chunk), lambda: step.mapaccum("chunk", n_chunk, [0, 1], [0, 1])
    )
    xs, zs = _run_chunks(seg, step, chunk, starts, sizes)
    add_stats(
        seg.stats,
        n_steps=len(starts),
        n_rhs=None if rhs_per_step is None else rhs_per_step * len(starts),
        n_jac=None if rhs_per_step is None else 0,
        n_segments=1,
        max_step_s=float(sizes.max()),
    )
    return xs[out_idx], zs[out_idx]


def _run_chunks(
    seg: Segment, step: cs.Function, chunk: cs.Function, starts: np.ndarray, sizes: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """States and algebraic unknowns after each step; padding steps have h = 0."""
    N = chunk.size2_in(3)
    n = len(starts)
    pad = (-n) % N
    T = np.concatenate([starts, np.full(pad, starts[-1])])
    H = np.concatenate([sizes, np.zeros(pad)])
    x, z = seg.x0, seg.z0
    xs, zs = np.empty((n + pad, len(x))), np.empty((n + pad, len(z)))
    for k in range(0, n + pad, N):
        sl = slice(k, k + N)
        try:
            Xk, Zk = (np.array(v).T for v in chunk(x, z, seg.w, T[None, sl], H[None, sl], seg.p))
        except RuntimeError:
            raise _locate_failure(seg, step, (x, z), T[sl], H[sl]) from None
        bad = ~(np.all(np.isfinite(Xk), axis=1) & np.all(np.isfinite(Zk), axis=1))
        if bad.any():
            i = int(np.argmax(bad))
            before = Xk[i - 1] if i else x
            t_bad = float(T[k + i] + H[k + i])
            raise seg.fail("the state became non-finite (blew up)", t_bad, before)
        xs[sl], zs[sl] = Xk, Zk
        x, z = Xk[-1], Zk[-1]
    return xs[:n], zs[:n]


def _locate_failure(
    seg: Segment,
    step: cs.Function,
    xz: tuple[np.ndarray, np.ndarray],
    T: np.ndarray,
    H: np.ndarray,
) -> SolverError:
    """Replay a failed chunk one step at a time; the error names the failing step."""
    x, z = xz
    for t, h in zip(T, H, strict=True):
        try:
            x, z = (np.array(v).ravel() for v in step(x, z, seg.w, t, h, seg.p))
        except RuntimeError as exc:
            return seg.fail(f"{_casadi_cause(str(exc))} (step {h:.3g} s)", float(t), x)
    return seg.fail("a step failed inside a chunk but not when replayed", float(T[0]), xz[0])


def _casadi_cause(msg: str) -> str:
    if "rootfinder process failed" in msg:
        return "Newton iteration of the implicit stage equations did not converge"
    return msg.strip().splitlines()[-1][:300]


_CORE_ARGS = ["x", "z", "w", "t", "h", "p"]


def _explicit_step(dae: LawDAE, scheme: ExplicitScheme) -> cs.Function:
    """``(x, z, w, t, h, p) -> (xf, zf)`` for an explicit Runge-Kutta tableau."""
    h = cs.SX.sym("h")
    f = dae.rhs()
    k = []
    for i, ci in enumerate(scheme.c):
        xi = dae.x + h * sum((scheme.A[i][j] * k[j] for j in range(i) if scheme.A[i][j]), 0)
        k.append(f(dae.t + ci * h, xi, dae.w, dae.p))
    x_next = dae.x + h * sum(bi * ki for bi, ki in zip(scheme.b, k, strict=True))
    return cs.Function(
        scheme.name,
        [dae.x, dae.z, dae.w, dae.t, h, dae.p],
        [x_next, dae.z],
        _CORE_ARGS,
        ["xf", "zf"],
    )


# --- implicit fixed-step ----------------------------------------------------------------
NEWTON_TOL = 1e-3
"""Newton tolerance of the implicit fixed-step methods, in units of the error weight
``rtol max(|x_n|, |x_n + h f_n|) + atol`` (the unknowns are scaled by that weight)."""


@dataclass(frozen=True)
class _ScaledStep:
    """One step on ``[t_n, t_n + h]`` in normalised time ``tau`` and weighted unknowns.

    ``x = w_x xi``, ``z = w_z zeta``, ``t = t_n + h tau``: every unknown is O(1/rtol)
    whatever its unit, so one absolute Newton tolerance fits air masses (1e-6 kg)
    and pressures (1e5 Pa) alike.
    """

    xi: cs.SX
    zeta: cs.SX
    tau: cs.SX
    P: cs.SX
    ode: cs.SX
    alg: cs.SX

    @classmethod
    def of(cls, dae: LawDAE) -> _ScaledStep:
        nx, nz = dae.x.numel(), dae.z.numel()
        xi, zeta, tau = cs.SX.sym("xi", nx), cs.SX.sym("zeta", nz), cs.SX.sym("tau")
        tn, h = cs.SX.sym("t_n"), cs.SX.sym("h")
        wx, wz = cs.SX.sym("w_x", nx), cs.SX.sym("w_z", nz)
        ode, alg = cs.substitute(
            [dae.ode, dae.alg], [dae.t, dae.x, dae.z], [tn + h * tau, wx * xi, wz * zeta]
        )
        P = cs.vertcat(dae.p, dae.w, tn, h, wx, wz)
        return cls(xi, zeta, tau, P, h * ode / wx, alg)


def _implicit_step(dae: LawDAE, one_step, tol: tuple[float, float]) -> cs.Function:
    """``(x, z, w, t, h, p) -> (xf, zf)`` around a normalised scaled step.

    ``one_step(xi0, zeta0, P) -> (xi1, zeta1)`` solves the step in scaled unknowns.
    """
    rtol, atol = tol
    nx, nz, n_p = dae.x.numel(), dae.z.numel(), dae.p.numel()
    x, z, w = cs.MX.sym("x", nx), cs.MX.sym("z", nz), cs.MX.sym("w", dae.w.numel())
    t, h, p = cs.MX.sym("t"), cs.MX.sym("h"), cs.MX.sym("p", n_p)
    f = cs.Function("f", [dae.t, dae.x, dae.z, dae.w, dae.p], [dae.ode])
    wx = rtol * cs.fmax(cs.fabs(x), cs.fabs(x + h * f(t, x, z, w, p))) + atol
    wz = rtol * cs.fabs(z) + atol
    xi1, zeta1 = one_step(x / wx, z / wz, cs.vertcat(p, w, t, h, wx, wz))
    return cs.Function(
        "implicit_step", [x, z, w, t, h, p], [wx * xi1, wz * zeta1], _CORE_ARGS, ["xf", "zf"]
    )


def _newton_options() -> dict:
    return {
        "abstol": NEWTON_TOL,
        "abstolStep": NEWTON_TOL,
        "max_iter": 50,
        "line_search": False,
        "linear_solver": "qr",
    }


def _radau_one_step(dae: LawDAE, points: int):
    """Radau IIA collocation equations (:func:`.collocation.residual`: the scaled states
    at the ``points`` Radau nodes, the last one the step end) solved by
    ``casadi.rootfinder`` (Newton)."""
    sc = _ScaledStep.of(dae)
    nx = sc.xi.numel()
    f = cs.Function("f", [sc.tau, sc.xi, sc.P], [sc.ode])
    R = collocation.residual(f, nx, points)
    V, xi0 = cs.SX.sym("V", nx * points), cs.SX.sym("xi0", nx)
    resid = cs.Function("radau_residual", [V, xi0, sc.P], [R(xi0, V, sc.P)])
    rf = cs.rootfinder("radau_newton", "newton", resid, _newton_options())

    def one_step(xi0, zeta0, P):
        return rf(cs.repmat(xi0, points, 1), xi0, P)[-nx:], zeta0

    return one_step


def _collocation_one_step(dae: LawDAE, order: int, scheme: str):
    """One element of CasADi's ``collocation`` integrator (ODE or DAE)."""
    sc = _ScaledStep.of(dae)
    spec = {"x": sc.xi, "p": sc.P, "t": sc.tau, "ode": sc.ode}
    if sc.zeta.numel():
        spec.update(z=sc.zeta, alg=sc.alg)
    F = cs.integrator(
        "collocation_step",
        "collocation",
        spec,
        0.0,
        1.0,
        {
            "number_of_finite_elements": 1,
            "interpolation_order": order,
            "collocation_scheme": scheme,
            "rootfinder_options": _newton_options(),
        },
    )

    def one_step(xi0, zeta0, P):
        res = F(x0=xi0, z0=zeta0, p=P)
        return res["xf"], res["zf"]

    return one_step


# --- the methods: a core step Function per (model, settings, input law) ----------------
def _core(
    model: Model, settings: SolverSettings, law: InputLaw
) -> tuple[tuple, cs.Function, int | None]:
    """The core step Function ``(x, z, w, t, h, p) -> (xf, zf)`` of a fixed-step method,
    its cache key and the right-hand sides per step (None where not counted)."""
    method = settings.method
    require_step(settings)
    if method in ("rk4", "euler"):
        require_ode(model, settings)
        method_options(settings, {"on_unstable": "warn"})  # refuse unknown options
        scheme = SCHEMES[method]
        key = ("fixed_step", method, law.key())
        build = lambda: _explicit_step(law_dae(model, law), scheme)  # noqa: E731
        per_step = len(scheme.c)
    elif method == "radau_fixed":
        require_ode(model, settings)
        points = int(method_options(settings, {"points": 3})["points"])
        if not 1 <= points <= 9:
            raise ParameterError("solver.options.points", points, "1..9 Radau points")
        tol = (settings.rtol, settings.atol)
        key = ("fixed_step", method, points, tol, law.key())

        def build() -> cs.Function:
            d = law_dae(model, law)
            return _implicit_step(d, _radau_one_step(d, points), tol)

        per_step = None
    else:
        opts = method_options(settings, {"interpolation_order": 3, "collocation_scheme": "radau"})
        order, scheme_name = int(opts["interpolation_order"]), str(opts["collocation_scheme"])
        tol = (settings.rtol, settings.atol)
        key = ("fixed_step", method, order, scheme_name, tol, law.key())

        def build() -> cs.Function:
            d = law_dae(model, law)
            return _implicit_step(d, _collocation_one_step(d, order, scheme_name), tol)

        per_step = None
    return key, model.cached(key, build), per_step


def _run(seg: Segment) -> tuple[np.ndarray, np.ndarray]:
    key, core, per_step = _core(seg.model, seg.settings, seg.law)
    return _march(seg, key, core, per_step)


def step_function(model: Model, settings: SolverSettings) -> cs.Function:
    """``step(x, z, u, h, p) -> (xf, zf)``: one fixed step of size ``h`` [s] with ``u``
    held (the core step Function of the held law at ``t = 0``; an MX Function that an
    optimal-control problem can call and differentiate)."""
    _, core, _ = _core(model, settings, HELD)
    x, z = cs.MX.sym("x", model.nx), cs.MX.sym("z", model.nz)
    u, h, p = cs.MX.sym("u", model.u.numel()), cs.MX.sym("h"), cs.MX.sym("p", model.p.numel())
    xf, zf = core(x, z, u, 0, h, p)
    return cs.Function("step", [x, z, u, h, p], [xf, zf], ["x", "z", "u", "h", "p"], ["xf", "zf"])


for _name in ("rk4", "euler", "radau_fixed", "collocation"):
    register_method(_name, step_function)(_run)
