"""Integration methods beyond SUNDIALS, registered in :data:`~.simulate.METHODS`.

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

import math
import warnings
from dataclasses import dataclass

import casadi as cs
import numpy as np
import scipy.integrate as si
import scipy.optimize as so
import scipy.sparse as sp

from .equilibrium import solve_equilibrium
from .errors import ParameterError, SarcomereError, SolverError
from .model import Model
from .pysource import python_function
from .simulate import Problem, register_method

CHUNK_STEPS = 128
"""Fixed steps per CasADi call (``mapaccum``); the last chunk is padded with h = 0."""


class StepStabilityWarning(UserWarning):
    """A fixed explicit step exceeds the estimated linear stability limit."""


# --- the ODE with the inputs substituted ------------------------------------------------
@dataclass(frozen=True)
class SegmentDAE:
    """The model's equations with the inputs as functions of clamped time.

    Attributes
    ----------
    t : casadi.SX
        Time [s].
    seg : casadi.SX
        ``[a, b_left]``: the segment start and the float just below its end [s];
        inputs are evaluated at ``min(max(t, a), b_left)``.
    x, z, p : casadi.SX
        States, algebraic unknowns, parameters (the model's symbols).
    ode, alg : casadi.SX
        Right-hand side and algebraic residuals with the inputs substituted.
    """

    t: cs.SX
    seg: cs.SX
    x: cs.SX
    z: cs.SX
    p: cs.SX
    ode: cs.SX
    alg: cs.SX

    def rhs(self) -> cs.Function:
        """``rhs(t, x, p, seg) -> ode`` (explicit ODE only)."""
        ode = cs.densify(self.ode)
        return cs.Function(
            "rhs", [self.t, self.x, self.p, self.seg], [ode], ["t", "x", "p", "seg"], ["ode"]
        )

    def jac(self) -> cs.Function:
        """``jac(t, x, p, seg) -> d ode / dx``, sparse."""
        J = cs.jacobian(self.ode, self.x)
        return cs.Function(
            "ode_jac", [self.t, self.x, self.p, self.seg], [J], ["t", "x", "p", "seg"], ["J"]
        )


_T = cs.SX.sym("t")
_DAE_CACHE: dict = {}


def segment_dae(prob: Problem) -> SegmentDAE:
    """The :class:`SegmentDAE` of a problem (cached per model and input expression)."""
    m = prob.model
    key = (m, str(prob.u_expr(_T)))
    hit = _DAE_CACHE.get(key)
    if hit is not None:
        return hit
    seg = cs.SX.sym("seg", 2)
    u = prob.u_expr(cs.fmin(cs.fmax(_T, seg[0]), seg[1]))
    ode = cs.substitute(m.ode, m.u, u) if m.u.numel() else m.ode
    alg = cs.substitute(m.alg, m.u, u) if m.u.numel() else m.alg
    dae = SegmentDAE(_T, seg, m.x, m.z, m.p, ode, alg)
    if len(_DAE_CACHE) > 64:
        _DAE_CACHE.clear()
    _DAE_CACHE[key] = dae
    return dae


def _seg(a: float, b: float) -> np.ndarray:
    return np.array([a, np.nextafter(b, -np.inf)])


def _require_ode(prob: Problem) -> None:
    m = prob.model
    if m.nz:
        raise SolverError(
            f"{prob.settings.method} needs an explicit ODE but model '{m.name}' keeps "
            f"{m.nz} algebraic unknowns: use 'idas' or 'collocation'"
        )


def _options(prob: Problem, defaults: dict) -> dict:
    """Method options: ``defaults`` updated by ``settings.options`` (unknown keys raise)."""
    opts = dict(defaults)
    for key, value in prob.settings.options:
        if key not in defaults:
            raise ParameterError(
                "solver.options", key, f"options of '{prob.settings.method}': {sorted(defaults)}"
            )
        opts[key] = value
    return opts


def _require_step(prob: Problem) -> float:
    h = prob.settings.step
    if h is None:
        raise ParameterError(
            "solver.step",
            None,
            f"a step size (0, inf) s: method '{prob.settings.method}' is fixed-step",
        )
    return float(h)


# --- stability of explicit schemes ------------------------------------------------------
@dataclass(frozen=True)
class ExplicitScheme:
    """An explicit Runge-Kutta tableau and its stability polynomial.

    Attributes
    ----------
    name : str
        Method name.
    A : tuple of tuple of float
        Strictly lower triangular stage matrix.
    b, c : tuple of float
        Weights and stage times (fractions of the step).
    poly : tuple of float
        Coefficients of ``R(z) = sum_k poly[k] z^k`` (``y_{n+1} = R(h lambda) y_n``).
    """

    name: str
    A: tuple
    b: tuple
    c: tuple
    poly: tuple


RK4 = ExplicitScheme(
    "rk4",
    ((0, 0, 0, 0), (0.5, 0, 0, 0), (0, 0.5, 0, 0), (0, 0, 1, 0)),
    (1 / 6, 1 / 3, 1 / 3, 1 / 6),
    (0, 0.5, 0.5, 1),
    (1, 1, 1 / 2, 1 / 6, 1 / 24),
)
EULER = ExplicitScheme("euler", ((0,),), (1,), (0,), (1, 1))
SCHEMES = {"rk4": RK4, "euler": EULER}


def stability_radius(poly: tuple, theta: np.ndarray) -> np.ndarray:
    """Distance from 0 to the boundary of the stability region along rays.

    The region is ``|R(z)| <= 1`` with ``R(z) = sum_k poly[k] z^k``. Along the ray
    ``z = r exp(i theta)`` the radius is the first ``r > 0`` where ``|R| = 1``
    (grid scan, then Brent's method to 1e-12). For RK4 on the negative real axis it
    is 2.7853; on the imaginary axis 2 sqrt(2); for explicit Euler ``-2 cos(theta)``.

    Parameters
    ----------
    poly : tuple of float
        Stability polynomial coefficients, lowest order first.
    theta : array_like
        Ray angles [rad], ``pi/2 <= |theta| <= pi`` (the left half-plane).

    Returns
    -------
    numpy.ndarray
        Radii [1] (0 where the ray leaves the region at once).
    """
    theta = np.atleast_1d(np.asarray(theta, dtype=float))
    coeffs = np.asarray(poly, dtype=float)[::-1]
    r_max = 2.0 * len(poly) + 2.0
    r = np.linspace(0.0, r_max, 4001)[1:]

    def excess(rr: float | np.ndarray, th: float) -> float | np.ndarray:
        return np.abs(np.polyval(coeffs, rr * np.exp(1j * th))) ** 2 - 1.0

    out = np.empty_like(theta)
    for i, th in enumerate(theta):
        g = excess(r, th)
        outside = np.flatnonzero(g > 0)
        if len(outside) == 0:
            out[i] = r_max
        elif outside[0] == 0:
            out[i] = 0.0
        else:
            k = outside[0]
            out[i] = so.brentq(excess, r[k - 1], r[k], args=(th,), xtol=1e-12)
    return out


def max_stable_step(eigenvalues: np.ndarray, scheme: ExplicitScheme) -> tuple[float, complex]:
    """Largest step [s] with every ``h lambda`` in the scheme's stability region.

    ``h_max = min over lambda of r(arg lambda) / |lambda|`` (:func:`stability_radius`).
    Eigenvalues with a positive real part (a physical instability) or zero are left
    out: no step size makes those decay.

    Returns
    -------
    (float, complex)
        The limit [s] (``inf`` if no eigenvalue limits it) and the eigenvalue
        [1/s] that sets it.
    """
    lam = np.asarray(eigenvalues, dtype=complex)
    mag = np.abs(lam)
    keep = (lam.real <= 0) & (mag > 1e-9 * max(float(mag.max(initial=0.0)), 1.0))
    if not keep.any():
        return math.inf, complex(0.0)
    lam = lam[keep]
    h = stability_radius(scheme.poly, np.angle(lam)) / np.abs(lam)
    k = int(np.argmin(h))
    return float(h[k]), complex(lam[k])


def jacobian_eigenvalues(model: Model, x: np.ndarray, u: np.ndarray, p: np.ndarray) -> np.ndarray:
    """Eigenvalues [1/s] of ``A = d ode / dx`` at one point (explicit ODE)."""
    A = np.array(model.function("jac")(x, model.z0(), u, p)[0])
    return np.linalg.eigvals(A)


def stability_limit(prob: Problem, scheme: ExplicitScheme) -> tuple[float, complex, str]:
    """Stability limit of ``scheme`` estimated before a run.

    Two points are checked: the initial state (with the input at the start), and the
    equilibrium that the input just after the first breakpoint leads to (the input at
    the end if there is no breakpoint; skipped when no equilibrium is found). The
    second catches models that are stiffest at the new operating point (e.g. a wider
    laminar region, ``r_lam = 0.995``); points in between are not checked
    (:mod:`sarcomere.dynamics.stability` scans a whole trajectory).

    Returns
    -------
    (float, complex, str)
        Limit [s], the eigenvalue [1/s] that sets it, and where it was found.
    """
    m = prob.model
    t_after = min(prob.breakpoints, default=float(prob.t_out[-1]))
    u_after = prob.u_at(t_after)
    points = [("the initial state", prob.x0, prob.u_at(float(prob.t_out[0])))]
    try:
        eq = solve_equilibrium(
            m,
            dict(zip(m.input_names, u_after.tolist(), strict=True)),
            params=dict(zip(m.param_names, prob.p.tolist(), strict=True)),
        )
        points.append((f"the equilibrium for the input at t = {t_after:.4g} s", eq.x, u_after))
    except SarcomereError:
        pass
    best = (math.inf, complex(0.0), points[0][0])
    for where, x, u in points:
        h, crit = max_stable_step(jacobian_eigenvalues(m, x, u, prob.p), scheme)
        if h < best[0]:
            best = (h, crit, where)
    return best


def _guard(prob: Problem, scheme: ExplicitScheme, h_used: float, action: str) -> None:
    if action not in ("warn", "raise", "ignore"):
        raise ParameterError("solver.options.on_unstable", action, "'warn', 'raise' or 'ignore'")
    if action == "ignore":
        return
    h_max, lam, where = stability_limit(prob, scheme)
    prob.stats["stability_limit_s"] = h_max
    if h_used <= h_max:
        return
    theta = float(np.degrees(np.angle(lam)))
    why = (
        f"{scheme.name} step {h_used:.4g} s exceeds the linear stability limit "
        f"{h_max:.4g} s = r(theta)/|lambda| set by the Jacobian eigenvalue "
        f"{lam.real:.4g}{lam.imag:+.4g}j 1/s (theta = {theta:.1f} deg) at {where}; "
        "the answer may blow up or settle into a false oscillation"
    )
    if action == "raise":
        raise ParameterError("solver.step", h_used, f"(0, {h_max:.4g}] s", why)
    warnings.warn(why + " (options=(('on_unstable', 'raise'),) refuses)", StepStabilityWarning, 3)


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
    h = _require_step(prob)
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
        xs, zs = _run_chunks(prob, step, (x, z), starts, sizes, _seg(a, b))
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
    _require_ode(prob)
    h = _require_step(prob)
    opts = _options(prob, {"on_unstable": "warn"})
    h_used = max(float(step_grid(a, b, grid, h)[1].max()) for a, b, grid in prob.segments())
    _guard(prob, scheme, h_used, opts["on_unstable"])
    step = _cached(prob, scheme.name, lambda d: _explicit_step(d, scheme))
    return _march(prob, step, len(scheme.c))


_STEP_CACHE: dict = {}


def _cached(prob: Problem, kind: object, build) -> cs.Function:
    """``build(segment_dae(prob))``, cached per DAE and ``kind``."""
    dae = segment_dae(prob)
    key = (id(dae), kind)
    hit = _STEP_CACHE.get(key)
    if hit is None or hit[0] is not dae:
        if len(_STEP_CACHE) > 64:
            _STEP_CACHE.clear()
        hit = _STEP_CACHE[key] = (dae, build(dae))
    return hit[1]


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
    _require_ode(prob)
    _require_step(prob)
    points = int(_options(prob, {"points": 3})["points"])
    if not 1 <= points <= 9:
        raise ParameterError("solver.options.points", points, "1..9 Radau points")
    tol = _tol(prob)
    step = _cached(
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
    _require_step(prob)
    opts = _options(prob, {"interpolation_order": 3, "collocation_scheme": "radau"})
    order, scheme = int(opts["interpolation_order"]), str(opts["collocation_scheme"])
    tol = _tol(prob)
    step = _cached(
        prob,
        ("collocation", order, scheme, tol),
        lambda d: _implicit_step(d, _collocation_one_step(d, order, scheme), tol),
    )
    return _march(prob, step, None)


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
    "scipy_radau_numpy": (si.Radau, "sparse"),
    "scipy_bdf": (si.BDF, "sparse"),
    "scipy_lsoda": (si.LSODA, "dense"),
}


class _Python:
    """The same Function as generated straight-line Python (a numpy/math right-hand side
    as a user would write it, from the one copy of the physics: :mod:`.pysource`)."""

    def __init__(self, F: cs.Function, p: np.ndarray) -> None:
        self.f, self.p, self.seg = python_function(F), np.asarray(p, float), np.zeros(2)

    def __call__(self, t: float, x: np.ndarray) -> np.ndarray:
        return self.f((t,), x, self.p, self.seg)[0]


_CALLS = {"buffer": _Buffered, "plain": _Plain, "python": _Python}
_SCIPY_DEFAULTS = {  # the baseline a user writes: a Python/numpy RHS, scipy's FD Jacobian
    "scipy_radau_numpy": {"call": "python", "jacobian": "finite_differences"},
}
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
    _require_ode(prob)
    s, m = prob.settings, prob.model
    defaults = {"call": "buffer", "jacobian": "exact", "first_step": None, "max_step": math.inf}
    opts = _options(prob, {**defaults, **_SCIPY_DEFAULTS.get(s.method, {})})
    if opts["call"] not in _CALLS:
        raise ParameterError("solver.options.call", opts["call"], sorted(_CALLS))
    if opts["jacobian"] not in _JACOBIANS:
        raise ParameterError("solver.options.jacobian", opts["jacobian"], _JACOBIANS)
    cls, jac_kind = _SCIPY[s.method]
    if opts["jacobian"] == "finite_differences":
        jac_kind = None  # scipy estimates it by finite differences of the right-hand side
    fun = _CALLS[opts["call"]](_cached(prob, "rhs", SegmentDAE.rhs), prob.p)
    jcall = None
    if jac_kind:
        Jf = _cached(prob, "jac", SegmentDAE.jac)
        jcall = _CALLS[opts["call"]](Jf, prob.p)
    X = np.empty((len(prob.t_out), m.nx))
    X[0] = prob.x0
    x = prob.x0
    stats = {"n_steps": 0, "n_rhs": 0, "n_jac": 0, "n_lu": 0, "n_segments": 0}
    kwargs = {"rtol": s.rtol, "atol": s.atol, "max_step": opts["max_step"]}
    if opts["first_step"] is not None:
        kwargs["first_step"] = opts["first_step"]
    for a, b, grid in prob.segments():
        fun.seg[:] = _seg(a, b)
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


for _name in _SCIPY:
    register_method(_name)(_scipy)
