"""Integration methods beyond SUNDIALS, registered in :data:`~.settings.METHODS`.

* ``rk4``: classic explicit Runge-Kutta (4 stages, order 4); needs ``step``.
* ``euler``: explicit Euler (order 1, a stability yardstick); needs ``step``.
* ``collocation``: one element of CasADi's ``integrator("collocation")`` per step
  (Radau points, 3 by default: order 5; ODE or DAE); needs ``step``.
* ``radau_fixed``: Radau IIA with 3 points (order 5), Newton on SX residuals;
  needs ``step``.
* ``scipy_rk45``, ``scipy_radau``, ``scipy_bdf``, ``scipy_lsoda``: scipy's solvers
  (the classes behind ``solve_ivp``) on the model's CasADi right-hand side; the
  implicit ones get the exact Jacobian (sparse for Radau and BDF, dense for LSODA);
  ``rtol``, ``atol``.

Conventions shared by every method here:

* **Inputs** are evaluated at each stage time from the signal's CasADi expression,
  with the time clamped into the current segment ``[a, b)`` between input
  breakpoints (at ``b`` the left limit is used), so a step command never leaks into
  the step that ends on it. Every method restarts at every breakpoint.
* **Fixed steps** land on every output time and breakpoint: each output interval is
  split into ``ceil(interval / step)`` equal steps, so no step exceeds
  ``settings.step`` (an output grid finer than the step makes the steps smaller).
* **Statistics** ``n_steps``, ``n_rhs``, ``n_jac`` (``None`` where the method does
  not expose the count), ``n_segments`` and ``max_step_s`` go to ``problem.stats``.
* **Failures** raise :class:`~.errors.SolverError` naming the time and the cause; a
  non-finite state is a failure, never a result.

Before an explicit fixed-step method runs, :func:`stability_limit` estimates the
largest stable step from the eigenvalues of the Jacobian at the initial state and at
the equilibrium after the first input step (see :func:`stability_radius`); a larger
step warns with :class:`StepStabilityWarning`, or raises with
``options=(("on_unstable", "raise"),)`` (``"ignore"`` skips the check).
"""

from __future__ import annotations

from dataclasses import dataclass

import casadi as cs
import numpy as np

from ..errors import ParameterError, SolverError
from .common import (
    SegmentDAE,
    cached_step,
    method_options,
    require_ode,
    require_step,
    seg_bounds,
)
from .guard import EULER, RK4, ExplicitScheme, check_step
from .settings import Problem, register_method

CHUNK_STEPS = 128
"""Fixed steps per CasADi call (``mapaccum``); the last chunk is padded with h = 0."""


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


def _march(
    prob: Problem, step: cs.Function, rhs_per_step: int | None
) -> tuple[np.ndarray, np.ndarray]:
    """Run a one-step Function ``(x, z, t, h, p, seg) -> (x_next, z_next)`` everywhere."""
    m, s = prob.model, prob.settings
    h = require_step(prob)
    X = np.empty((len(prob.t_out), m.nx))
    Z = np.empty((len(prob.t_out), m.nz))
    X[0], Z[0] = prob.x0, prob.z0
    x, z = prob.x0.copy(), prob.z0.copy()
    n_steps, h_max, n_seg = 0, 0.0, 0
    for a, b, grid in prob.segments():
        starts, sizes, out_idx = step_grid(a, b, grid, h)
        if len(starts) > s.max_steps:
            raise prob.fail(
                f"{len(starts)} steps of {h:.3g} s needed in [{a:.6g}, {b:.6g}] s, more than "
                f"max_steps = {s.max_steps}",
                a,
                x,
            )
        xs, zs = _run_chunks(prob, step, (x, z), starts, sizes, seg_bounds(a, b))
        idx = np.searchsorted(prob.t_out, grid)
        X[idx], Z[idx] = xs[out_idx], zs[out_idx]
        x, z = xs[-1], zs[-1]
        n_steps += len(starts)
        h_max = max(h_max, float(sizes.max()))
        n_seg += 1
    prob.stats.update(
        n_steps=n_steps,
        n_rhs=None if rhs_per_step is None else rhs_per_step * n_steps,
        n_jac=None if rhs_per_step is None else 0,
        n_segments=n_seg,
        max_step_s=h_max,
    )
    return X, Z


def _run_chunks(
    prob: Problem,
    step: cs.Function,
    xz: tuple[np.ndarray, np.ndarray],
    starts: np.ndarray,
    sizes: np.ndarray,
    seg: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """States and algebraic unknowns after each step; padding steps have h = 0."""
    chunk = step.mapaccum("chunk", CHUNK_STEPS, [0, 1], [0, 1])
    n = len(starts)
    pad = (-n) % CHUNK_STEPS
    T = np.concatenate([starts, np.full(pad, starts[-1])])
    H = np.concatenate([sizes, np.zeros(pad)])
    x, z = xz
    xs, zs = np.empty((n + pad, len(x))), np.empty((n + pad, len(z)))
    for k in range(0, n + pad, CHUNK_STEPS):
        sl = slice(k, k + CHUNK_STEPS)
        try:
            Xk, Zk = (np.array(v).T for v in chunk(x, z, T[None, sl], H[None, sl], prob.p, seg))
        except RuntimeError:
            raise _locate_failure(prob, step, (x, z), T[sl], H[sl], seg) from None
        bad = ~(np.all(np.isfinite(Xk), axis=1) & np.all(np.isfinite(Zk), axis=1))
        if bad.any():
            i = int(np.argmax(bad))
            before = Xk[i - 1] if i else x
            t_bad = float(T[k + i] + H[k + i])
            raise prob.fail("the state became non-finite (blew up)", t_bad, before)
        xs[sl], zs[sl] = Xk, Zk
        x, z = Xk[-1], Zk[-1]
    return xs[:n], zs[:n]


def _locate_failure(
    prob: Problem,
    step: cs.Function,
    xz: tuple[np.ndarray, np.ndarray],
    T: np.ndarray,
    H: np.ndarray,
    seg: np.ndarray,
) -> SolverError:
    """Replay a failed chunk one step at a time; the error names the failing step."""
    x, z = xz
    for t, h in zip(T, H, strict=True):
        try:
            x, z = (np.array(v).ravel() for v in step(x, z, t, h, prob.p, seg))
        except RuntimeError as exc:
            return prob.fail(f"{_casadi_cause(str(exc))} (step {h:.3g} s)", float(t), x)
    return prob.fail("a step failed inside a chunk but not when replayed", float(T[0]), xz[0])


def _casadi_cause(msg: str) -> str:
    if "rootfinder process failed" in msg:
        return "Newton iteration of the implicit stage equations did not converge"
    return msg.strip().splitlines()[-1][:300]


_STEP_ARGS = ["x", "z", "t", "h", "p", "seg"]


def _explicit_step(dae: SegmentDAE, scheme: ExplicitScheme) -> cs.Function:
    """``(x, z, t, h, p, seg) -> (x_next, z)`` for an explicit Runge-Kutta tableau."""
    h = cs.SX.sym("h")
    f = dae.rhs()
    k = []
    for i, ci in enumerate(scheme.c):
        xi = dae.x + h * sum((scheme.A[i][j] * k[j] for j in range(i) if scheme.A[i][j]), 0)
        k.append(f(dae.t + ci * h, xi, dae.p, dae.seg))
    x_next = dae.x + h * sum(bi * ki for bi, ki in zip(scheme.b, k, strict=True))
    return cs.Function(
        scheme.name,
        [dae.x, dae.z, dae.t, h, dae.p, dae.seg],
        [x_next, dae.z],
        _STEP_ARGS,
        ["xf", "zf"],
    )


def _explicit(prob: Problem, scheme: ExplicitScheme) -> tuple[np.ndarray, np.ndarray]:
    require_ode(prob)
    h = require_step(prob)
    opts = method_options(prob, {"on_unstable": "warn"})
    h_used = max(float(step_grid(a, b, grid, h)[1].max()) for a, b, grid in prob.segments())
    check_step(prob, scheme, h_used, opts["on_unstable"])
    step = cached_step(prob, scheme.name, lambda d: _explicit_step(d, scheme))
    return _march(prob, step, len(scheme.c))


@register_method("rk4")
def _rk4(prob: Problem) -> tuple[np.ndarray, np.ndarray]:
    """Classic fixed-step RK4 (4 right-hand sides per step)."""
    return _explicit(prob, RK4)


@register_method("euler")
def _euler(prob: Problem) -> tuple[np.ndarray, np.ndarray]:
    """Fixed-step explicit Euler (1 right-hand side per step)."""
    return _explicit(prob, EULER)


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
    def of(cls, dae: SegmentDAE) -> _ScaledStep:
        nx, nz = dae.x.numel(), dae.z.numel()
        xi, zeta, tau = cs.SX.sym("xi", nx), cs.SX.sym("zeta", nz), cs.SX.sym("tau")
        tn, h = cs.SX.sym("t_n"), cs.SX.sym("h")
        wx, wz = cs.SX.sym("w_x", nx), cs.SX.sym("w_z", nz)
        ode, alg = cs.substitute(
            [dae.ode, dae.alg], [dae.t, dae.x, dae.z], [tn + h * tau, wx * xi, wz * zeta]
        )
        P = cs.vertcat(dae.p, dae.seg, tn, h, wx, wz)
        return cls(xi, zeta, tau, P, h * ode / wx, alg)


def _implicit_step(dae: SegmentDAE, one_step, tol: tuple[float, float]) -> cs.Function:
    """``(x, z, t, h, p, seg) -> (x_next, z_next)`` around a normalised scaled step.

    ``one_step(xi0, zeta0, P) -> (xi1, zeta1)`` solves the step in scaled unknowns.
    """
    rtol, atol = tol
    nx, nz, n_p = dae.x.numel(), dae.z.numel(), dae.p.numel()
    x, z = cs.MX.sym("x", nx), cs.MX.sym("z", nz)
    t, h, p, seg = cs.MX.sym("t"), cs.MX.sym("h"), cs.MX.sym("p", n_p), cs.MX.sym("seg", 2)
    f = cs.Function("f", [dae.t, dae.x, dae.z, dae.p, dae.seg], [dae.ode])
    wx = rtol * cs.fmax(cs.fabs(x), cs.fabs(x + h * f(t, x, z, p, seg))) + atol
    wz = rtol * cs.fabs(z) + atol
    xi1, zeta1 = one_step(x / wx, z / wz, cs.vertcat(p, seg, t, h, wx, wz))
    return cs.Function(
        "implicit_step", [x, z, t, h, p, seg], [wx * xi1, wz * zeta1], _STEP_ARGS, ["xf", "zf"]
    )


def _newton_options() -> dict:
    return {
        "abstol": NEWTON_TOL,
        "abstolStep": NEWTON_TOL,
        "max_iter": 50,
        "line_search": False,
        "linear_solver": "qr",
    }


def _radau_one_step(dae: SegmentDAE, points: int):
    """Radau IIA collocation equations in SX, solved by ``casadi.rootfinder`` (Newton).

    Unknowns: the scaled states at the ``points`` Radau points (``casadi.collocation_points``);
    residuals ``ode(x_j, tau_j) - sum_r C[r, j] x_r`` with ``C`` from
    ``casadi.collocation_coeff``. The last Radau point is the step end.
    """
    sc = _ScaledStep.of(dae)
    nx = sc.xi.numel()
    tau = cs.collocation_points(points, "radau")
    C = cs.collocation_coeff(tau)[0]
    V = cs.SX.sym("V", nx, points)
    xi0 = cs.SX.sym("xi0", nx)
    Xall = cs.horzcat(xi0, V)
    f = cs.Function("f", [sc.xi, sc.tau, sc.P], [sc.ode])
    res = [f(V[:, j], tau[j], sc.P) - cs.mtimes(Xall, C[:, j]) for j in range(points)]
    resid = cs.Function("radau_residual", [cs.vec(V), xi0, sc.P], [cs.vertcat(*res)])
    rf = cs.rootfinder("radau_newton", "newton", resid, _newton_options())

    def one_step(xi0, zeta0, P):
        return rf(cs.repmat(xi0, points, 1), xi0, P)[-nx:], zeta0

    return one_step


def _collocation_one_step(dae: SegmentDAE, order: int, scheme: str):
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


def _tol(prob: Problem) -> tuple[float, float]:
    return prob.settings.rtol, prob.settings.atol


@register_method("radau_fixed")
def _radau_fixed(prob: Problem) -> tuple[np.ndarray, np.ndarray]:
    """Fixed-step Radau IIA; option ``points`` (default 3: order 5).

    ``rtol`` and ``atol`` set the Newton tolerance (:data:`NEWTON_TOL`), not the step.
    """
    require_ode(prob)
    require_step(prob)
    points = int(method_options(prob, {"points": 3})["points"])
    if not 1 <= points <= 9:
        raise ParameterError("solver.options.points", points, "1..9 Radau points")
    tol = _tol(prob)
    step = cached_step(
        prob, ("radau", points, tol), lambda d: _implicit_step(d, _radau_one_step(d, points), tol)
    )
    return _march(prob, step, None)


@register_method("collocation")
def _collocation(prob: Problem) -> tuple[np.ndarray, np.ndarray]:
    """CasADi's ``collocation`` integrator, one element per fixed step (ODE or DAE).

    Options ``interpolation_order`` (default 3) and ``collocation_scheme`` (default
    "radau": Radau IIA, order 5 with 3 points). ``rtol`` and ``atol`` set the Newton
    tolerance (:data:`NEWTON_TOL`), not the step.
    """
    require_step(prob)
    opts = method_options(prob, {"interpolation_order": 3, "collocation_scheme": "radau"})
    order, scheme = int(opts["interpolation_order"]), str(opts["collocation_scheme"])
    tol = _tol(prob)
    step = cached_step(
        prob,
        ("collocation", order, scheme, tol),
        lambda d: _implicit_step(d, _collocation_one_step(d, order, scheme), tol),
    )
    return _march(prob, step, None)
