"""Multiple shooting of a time series: Radau IIA collocation steps that may span several
samples, with forward sensitivities, generated to C.

The record is cut into shooting intervals of ``interval`` samples (or a few more: each
ends at a step's end). The scaled state
``xi = x / x_nominal`` at each interval's start is an unknown of the fit (a node). Inside
an interval the states follow from it by Radau IIA steps (3 nodes, order 5: the equations
of :func:`..simulation.collocation.residual`) on a grid of samples: a step spans at most
``step`` samples and ends at every kink of the inputs (a sample where their slope
changes; after a kink the steps grow from one sample, doubling, as the response to a
kink is least smooth there), so the inputs, linear between samples (the
:class:`~sarcomere.dynamics.signals.Table` convention), are linear inside each step and
the step integrates them exactly. The states at the samples a step spans come from its
collocation polynomial (through the step's start and its three stage values; exact at
its end). :func:`auto_step` picks ``step`` so that this costs less than
:data:`STEP_TOLERANCE` of the data's noise.

Each step's collocation equations ``R(V, xi_k, q_k, p) = 0`` are solved for the stage
values ``V`` by Newton with the sparse LU of their Jacobian written out in the generated
C (:mod:`..simulation.sparse_lu`; CasADi's ``fast_newton`` with its pivoting sparse QR
where that does not converge). The stage sensitivities follow at the converged stages by
the implicit function theorem (exact, no finite differences), with the same sparse LU:
``S_V = -R_V^-1 (R_xi S_k + [0, R_p D])`` with ``S = d xi / d(node, theta_e)``
(``theta_e``: the estimated values the experiment uses, entering ``p`` as
``p_sel = D theta_e``), and ``S_{k+1}`` is its last block. A step and its
sensitivities are each one compiled call on numpy arrays (the sensitivities at the stages
just solved: no second Newton); the C is generated once per (model, estimated entries,
outputs) and kept in the disk cache of
:mod:`..simulation.compiled`. A step whose Newton does not bring the scaled residual
below :data:`RESIDUAL_TOL` is a SolverError naming its time.
"""

from __future__ import annotations

import functools
import itertools
from collections.abc import Callable
from dataclasses import dataclass

import casadi as cs
import numpy as np

from ..errors import SolverError
from ..modeling.model import Model
from ..simulation import collocation, compiled, sparse_lu

POINTS = 3
"""Radau IIA nodes per step (order 5)."""

NEWTON = {"abstol": 1e-10, "abstolStep": 1e-10, "max_iter": 30, "error_on_fail": False}
"""The step's Newton (scaled unknowns: states divided by their nominal values); a failure
is detected from the residual it leaves (:data:`RESIDUAL_TOL`), not by CasADi."""

RESIDUAL_TOL = 1e-8
"""Largest scaled collocation residual of an accepted step."""

STEPS = (32, 16, 8, 4, 2)
"""The samples per step :func:`auto_step` tries, largest first (1 if none passes)."""

STEP_TOLERANCE = 0.01
"""Largest difference :func:`auto_step` allows between a coarse grid's outputs and one
step per sample, as a fraction of each signal's noise level [-]: a bias of 1 % of the
noise moves chi-squared by about 1e-4 per sample."""

LU_ITERATIONS = 3
"""Newton iterations of one ``lu_step`` call: from the previous step's polynomial a step
converges in 2-3 (measured on fit-synthetic: 52 of 69 steps in 3, the last confirming)."""

LU_CALLS = 3
"""``lu_step`` calls (each :data:`LU_ITERATIONS` iterations) before a step falls back to
CasADi's ``fast_newton``."""

RESCUE = (2, 4, 8, 16)
"""Substeps per step tried, in turn, to guess the stages of a step whose Newton failed
from the previous step's polynomial and from its start."""

OUTPUT_CHUNK = 256
"""Samples per call of the compiled outputs Function."""


def scales(model: Model, states=()) -> np.ndarray:
    """State scales ``x = scales * xi``: the larger of the model's nominal values and the
    magnitudes in ``states`` (e.g. equilibria of the record: a set pressure whose nominal
    is 1 Pa reaches 1e5 Pa), rounded up to a power of two (exact scaling)."""
    mag = np.max(np.abs(np.vstack([model.nominal("x"), *states])), axis=0)
    return 2.0 ** np.ceil(np.log2(np.maximum(mag, 1e-12)))


def noise_level(data: np.ndarray) -> np.ndarray:
    """Each column's noise standard deviation estimated from its second differences
    (robust: 1.4826 times their median absolute value, over sqrt(6), the factor of white
    noise), NaN rows left out; 0 for a column with fewer than 3 values."""
    data = np.asarray(data, dtype=float).reshape(len(data), -1)
    out = np.zeros(data.shape[1])
    for j in range(data.shape[1]):
        col = data[np.isfinite(data[:, j]), j]
        if len(col) >= 3:
            out[j] = 1.4826 * np.median(np.abs(np.diff(col, 2))) / np.sqrt(6.0)
    return out


@dataclass(frozen=True)
class Engine:
    """The compiled Functions of one (model, estimated entries, ``ne`` estimated values,
    outputs), called on numpy arrays (:class:`~..simulation.compiled.NumpyFunction`):

    * ``lu_step(xi, guess, q, p, scale) -> (V, res, last)``: :data:`LU_ITERATIONS`
      Newton iterations on one step's scaled stage values (nx x 3, the last is the
      step's end) from ``guess``, each with the sparse LU of the collocation Jacobian
      (:mod:`..simulation.sparse_lu`: no pivoting), the scaled collocation residual at
      the result and the last Newton step's size; ``q = (u0, u1, h)``.
    * ``step(xi, guess, q, p, scale) -> (V, res)``: the same step by CasADi's
      ``fast_newton`` (pivoting sparse QR; about 3x slower per iteration, measured): the
      fallback where ``lu_step`` does not converge, compiled on its first call.
    * ``sens(V, xi, S, q, p, D, scale) -> S_V``: the sensitivities of the converged
      stages ``V`` (3 nx x (nx + ne)) from the start's ``S`` (nx x (nx + ne)), every
      column solved with one sparse LU of the collocation Jacobian.
    * ``outputs(X, U, p) -> (y, Y_x, Y_p)``: the measured signals at
      :data:`OUTPUT_CHUNK` samples and their Jacobians to ``x`` (unscaled) and to
      ``p_sel``, side by side.
    * ``equilibrium(xi, u, p, scale) -> (f, F_xi, F_p)``: the scaled ODE at the first
      sample and its Jacobians to ``xi`` and ``p_sel``.
    """

    step: Callable[..., tuple]
    lu_step: compiled.NumpyFunction
    sens: compiled.NumpyFunction
    outputs: compiled.NumpyFunction
    equilibrium: compiled.NumpyFunction


def engine(model: Model, idx: tuple[int, ...], ne: int, outputs: tuple) -> Engine:
    """The :class:`Engine` (generated, compiled and loaded once; memoised on the model)."""
    key = ("identification.engine", idx, ne, outputs)
    return model.cached(key, lambda: _build(model, idx, ne, outputs))


def _build(model: Model, idx: tuple[int, ...], ne: int, outputs: tuple) -> Engine:
    nx, nu, n_p, k = model.nx, model.u.numel(), model.p.numel(), len(idx)
    scale = cs.SX.sym("scale", nx)
    ode = cs.Function("ode", [model.x, model.u, model.p], [model.ode])
    tau, xi, q = cs.SX.sym("tau"), cs.SX.sym("xi", nx), cs.SX.sym("q", 2 * nu + 1)
    p = cs.SX.sym("p", n_p)
    u0, u1, h = q[:nu], q[nu : 2 * nu], q[2 * nu]
    f = cs.Function(
        "f",
        [tau, xi, cs.vertcat(q, p, scale)],
        [h * ode(scale * xi, u0 + tau * (u1 - u0), p) / scale],
    )
    V = cs.SX.sym("V", nx * POINTS)
    r = collocation.residual(f, nx, POINTS)(xi, V, cs.vertcat(q, p, scale))
    psel = cs.vertcat(*[p[i] for i in idx]) if idx else cs.SX(0, 1)
    R = cs.Function("R", [V, xi, q, p, scale], [r])
    RV = cs.jacobian(r, V)
    lu = sparse_lu.collocation_factors(RV, nx, POINTS)
    lu_solve = lu.solve_function("fit_lu_solve")
    factor = cs.Function("fit_lu_factor", [V, xi, q, p, scale], [lu.values])
    RJ = cs.Function("RJ", [V, xi, q, p, scale], [cs.jacobian(r, xi), cs.jacobian(r, psel)])
    newton = cs.rootfinder("radau_step", "fast_newton", R, NEWTON)

    xm, qm, pm = cs.MX.sym("xi", nx), cs.MX.sym("q", q.numel()), cs.MX.sym("p", n_p)
    Sm, Dm, cm = cs.MX.sym("S", nx, nx + ne), cs.MX.sym("D", k, ne), cs.MX.sym("scale", nx)
    Gm = cs.MX.sym("guess", nx, POINTS)
    Vs = newton(cs.vec(Gm), xm, qm, pm, cm)
    res = cs.norm_inf(R(Vs, xm, qm, pm, cm))
    Vm = cs.reshape(Vs, nx, POINTS)
    names = ["xi", "guess", "q", "p", "scale"]
    step = cs.Function("fit_step", [xm, Gm, qm, pm, cm], [Vm, res], names, ["V", "res"])
    Vl, last = cs.vec(Gm), None
    for _ in range(LU_ITERATIONS):  # the factorisation and the solve generated once each
        dv = lu_solve(factor(Vl, xm, qm, pm, cm), R(Vl, xm, qm, pm, cm))
        Vl, last = Vl - dv, cs.norm_inf(dv)
    lu_step = cs.Function(
        "fit_lu_step",
        [xm, Gm, qm, pm, cm],
        [cs.reshape(Vl, nx, POINTS), cs.norm_inf(R(Vl, xm, qm, pm, cm)), last],
        names,
        ["V", "res", "last"],
    )
    Vk = cs.MX.sym("V", nx, POINTS)
    Rx, Rp = RJ(cs.vec(Vk), xm, qm, pm, cm)
    rhs = Rx @ Sm + cs.horzcat(cs.MX(nx * POINTS, nx), Rp @ Dm)
    shared = lu_solve.map(nx + ne, [True, False], [False])  # one factorisation, every column
    sens = cs.Function(
        "fit_sens",
        [Vk, xm, Sm, qm, pm, Dm, cm],
        [-shared(factor(cs.vec(Vk), xm, qm, pm, cm), rhs)],
        ["V", "xi", "S", "q", "p", "D", "scale"],
        ["S_V"],
    )

    index = {n: i for i, n in enumerate(model.signal_names)}
    sig = model.function("signals")(model.x, cs.SX(0, 1), model.u, model.p)
    y = cs.vertcat(*[sig[index[o]] for o in outputs]) if outputs else cs.SX(0, 1)
    psel_m = cs.vertcat(*[model.p[i] for i in idx]) if idx else cs.SX(0, 1)
    out = cs.Function(
        "fit_outputs",
        [model.x, model.u, model.p],
        [y, cs.jacobian(y, model.x), cs.jacobian(y, psel_m)],
        ["x", "u", "p"],
        ["y", "Y_x", "Y_p"],
    )
    fe = ode(scale * xi, model.u, p) / scale
    eq = cs.Function(
        "fit_equilibrium",
        [xi, model.u, p, scale],
        [fe, cs.jacobian(fe, xi), cs.jacobian(fe, psel)],
        ["xi", "u", "p", "scale"],
        ["f", "F_xi", "F_p"],
    )
    stem = f"fit_{model.name}".replace(".", "_")
    L = OUTPUT_CHUNK
    Xo, Uo = cs.MX.sym("X", nx, L), cs.MX.sym("U", nu, L)
    outs = cs.Function("fit_outputs_map", [Xo, Uo, pm], out.map(L)(Xo, Uo, cs.repmat(pm, 1, L)))
    lib = compiled.numpy_library([lu_step, sens, outs, eq], stem)
    fallback = _Compiled(lambda: compiled.numpy_library([step], f"{stem}_qr")["fit_step"])
    return Engine(
        fallback,
        lib["fit_lu_step"],
        lib["fit_sens"],
        lib["fit_outputs_map"],
        lib["fit_equilibrium"],
    )


class _Compiled:
    """A Function compiled (or loaded from the disk cache) on its first call: the fallback
    step, which most fits never call, costs no compile time until one does."""

    def __init__(self, build) -> None:
        self._build, self._function = build, None

    def __call__(self, *args):
        if self._function is None:
            self._function = self._build()
        return self._function(*args)


def kinks(t: np.ndarray, u: np.ndarray) -> np.ndarray:
    """The samples (indices, first and last excluded) where an input's slope changes by
    more than 1e-9 of its range over the record's duration per second."""
    u = np.asarray(u, dtype=float).reshape(len(t), -1)
    if len(t) < 3:
        return np.zeros(0, int)
    slope = np.diff(u, axis=0) / np.diff(t)[:, None]
    span = np.ptp(u, axis=0) / (t[-1] - t[0])
    bent = np.abs(np.diff(slope, axis=0)) > 1e-9 * np.maximum(span, 1e-300)
    return np.flatnonzero(np.any(bent, axis=1)) + 1


@dataclass(frozen=True)
class Grid:
    """The Radau IIA steps of a record: step ``s`` goes from sample ``k0[s]`` to ``k1[s]``;
    shooting interval ``j``'s steps are ``first[j]:first[j + 1]``; sample ``k >= 1`` lies in step
    ``of[k]`` with polynomial weights ``w[k]`` (exactly ``(0, 0, 0, 1)`` at a step's end);
    ``ahead[s]`` (3 x 4): step ``s - 1``'s polynomial at step ``s``'s Radau nodes;
    ``q[s] = (u0, u1, h)``: its inputs at both ends and its length [s]."""

    k0: np.ndarray
    k1: np.ndarray
    first: np.ndarray
    of: np.ndarray
    w: np.ndarray
    ahead: np.ndarray
    q: np.ndarray

    @classmethod
    def of_record(cls, t: np.ndarray, u: np.ndarray, step: int, interval: int | None) -> Grid:
        """The grid of samples ``t`` and inputs ``u``: steps of at most ``step`` samples
        (none across a kink; after one, no longer than the time since it), and an
        interval ending at the first step end ``interval`` or more samples after the
        last (``None``: one interval). The steps do not depend on ``interval``: single
        and multiple shooting integrate alike."""
        u = np.asarray(u, dtype=float).reshape(len(t), -1)
        bent = kinks(t, u)
        k0, k1 = [], []
        k, n = 0, len(t)
        while k < n - 1:
            i = np.searchsorted(bent, k, "right")  # the first kink after k
            since = k - bent[i - 1] if i else step  # samples since the last kink
            end = min(k + min(step, max(since, 1)), n - 1)
            if i < len(bent):
                end = min(end, int(bent[i]))
            k0.append(k)
            k1.append(end)
            k = end
        first, cut = [0], 0
        for s, end in enumerate(k1[:-1]):
            if interval is not None and end - cut >= interval:
                first.append(s + 1)
                cut = end
        first.append(len(k0))
        k0a, k1a = np.array(k0), np.array(k1)
        of = np.zeros(n, int)
        for s, (a, b) in enumerate(zip(k0a, k1a, strict=True)):
            of[a + 1 : b + 1] = s
        frac = (t[1:] - t[k0a[of[1:]]]) / (t[k1a[of[1:]]] - t[k0a[of[1:]]])
        w = np.zeros((n, POINTS + 1))
        w[1:] = collocation.interpolation(frac)
        ends = np.flatnonzero(np.arange(1, n) == k1a[of[1:]]) + 1
        w[ends] = 0.0
        w[ends, -1] = 1.0
        h = t[k1a] - t[k0a]
        ratio = h / np.concatenate([h[:1], h[:-1]])  # to the previous step (the first: 1)
        tau = collocation.nodes(POINTS)
        ahead = collocation.interpolation((1.0 + np.outer(ratio, tau)).ravel()).reshape(
            len(h), POINTS, -1
        )
        q = np.hstack([u[k0a], u[k1a], h[:, None]])
        return cls(k0a, k1a, np.array(first), of, w, ahead, q)


@dataclass
class Shooting:
    """The shooting of one record: its model, samples ``t`` (n,) [s], inputs ``u`` (n, nu),
    the :class:`Engine`, the state scales, the step :class:`Grid` and the samples a step
    spans at most."""

    model: Model
    t: np.ndarray
    u: np.ndarray
    engine: Engine
    scale: np.ndarray
    grid: Grid
    step: int

    @classmethod
    def of(
        cls, model: Model, t, u, interval: int | None, idx, ne: int, outputs, scale, step: int = 1
    ) -> Shooting:
        t = np.asarray(t, float)
        u = np.asarray(u, float).reshape(len(t), -1)
        grid = Grid.of_record(t, u, step, interval)
        eng = engine(model, tuple(idx), ne, tuple(outputs))
        return cls(model, t, u, eng, scale, grid, step)

    @property
    def bounds(self) -> list[tuple[int, int]]:
        """The shooting intervals (first and last sample index): every ``interval``
        samples or more, each at a step's end."""
        g = self.grid
        return [(int(g.k0[a]), int(g.k1[b - 1])) for a, b in itertools.pairwise(g.first)]

    @property
    def nodes(self) -> int:
        return len(self.grid.first) - 1

    def _fail(self, s: int, r: float, finite: bool) -> SolverError:
        why = (
            "a non-finite state"
            if not finite
            else f"Newton left a scaled residual of {r:.3g} (above {RESIDUAL_TOL:g})"
        )
        a, b = self.grid.k0[s], self.grid.k1[s]
        return SolverError(
            f"the Radau IIA step from t = {self.t[a]:g} s to {self.t[b]:g} s failed: {why}"
        )

    def _run(self, p, S=None, xi0=None, D=None):
        """The steps of every interval, from the nodes ``S`` (nx x nodes) or, with ``xi0``,
        each interval from the last one's end. Returns the node values (steps, 4, nx): the
        step's start and its stages, and with ``D`` their sensitivities (steps, 4, nx,
        nx + ne). Each step's Newton starts from the previous step's polynomial
        extrapolated, across interval ends too, so that single and multiple shooting
        compute alike (:meth:`_step`)."""
        g, nx, eng = self.grid, self.model.nx, self.engine
        m = len(g.k0)
        vals = np.empty((m, POINTS + 1, nx))
        sens = None if D is None else np.empty((m, POINTS + 1, nx, nx + D.shape[1]))
        x = None if xi0 is None else np.asarray(xi0, float)
        for j in range(self.nodes):
            if S is not None:
                x = S[:, j]
            if sens is not None:
                Sx = np.hstack([np.eye(nx), np.zeros((nx, D.shape[1]))])
            for s in range(g.first[j], g.first[j + 1]):
                ahead = (g.ahead[s] @ vals[s - 1]).T if s else None
                V = self._step(s, x, ahead, g.q[s], p)
                if sens is not None:
                    (SV,) = eng.sens(V, x, Sx, g.q[s], p, D, self.scale)
                    sens[s, 0] = Sx
                    sens[s, 1:] = SV.reshape(POINTS, nx, -1)
                    Sx = sens[s, -1]
                vals[s, 0] = x
                vals[s, 1:] = V.T
                x = vals[s, -1]
        return vals, sens

    def _step(self, s: int, x: np.ndarray, ahead, q: np.ndarray, p) -> np.ndarray:
        """Step ``s``'s converged stages (nx x 3) from ``x``: Newton with the sparse LU
        (``lu_step``) from ``ahead`` (the previous step's polynomial) when given, else from
        ``x`` repeated; where that does not converge, CasADi's ``fast_newton`` from
        ``ahead``, then from ``x`` repeated, then from the step taken as 2, 4, ...
        :data:`RESCUE` equal substeps (their polynomials at the step's nodes: the same
        step's solution, found from closer). Raises SolverError naming the step's time
        where none converges."""
        flat = np.repeat(x[:, None], POINTS, axis=1)
        V = ahead if ahead is not None else flat
        for _ in range(LU_CALLS):
            V, res, last = self.engine.lu_step(x, V, q, p, self.scale)
            r, dv = float(res.ravel()[0]), float(last.ravel()[0])
            if not (np.isfinite(r) and np.isfinite(dv)):
                break
            if r <= NEWTON["abstol"] or dv <= NEWTON["abstolStep"]:  # fast_newton's stop
                if r <= RESIDUAL_TOL and np.all(np.isfinite(V)):
                    return V
                break
        starts = [ahead] if ahead is not None else []
        starts.append(flat)
        starts += [functools.partial(self._substepped, x, q, p, m) for m in RESCUE]
        r, finite = np.inf, True
        for guess in starts:
            guess = guess() if callable(guess) else guess
            if guess is None:  # a substep failed
                continue
            V, res = self.engine.step(x, guess, q, p, self.scale)
            r, finite = float(res.ravel()[0]), bool(np.all(np.isfinite(V)))
            if r <= RESIDUAL_TOL and finite:
                return V
        raise self._fail(s, r, finite)

    def _substepped(self, x: np.ndarray, q: np.ndarray, p, m: int) -> np.ndarray | None:
        """The stages of the step ``q`` from ``x`` guessed by ``m`` equal substeps (inputs
        interpolated), each from its start repeated; None where a substep fails."""
        nu = (len(q) - 1) // 2
        u0, u1, h = q[:nu], q[nu : 2 * nu], q[-1]
        tau = collocation.nodes(POINTS)
        holder = np.minimum((tau * m).astype(int), m - 1)  # the substep of each node
        guess = np.empty((len(x), POINTS))
        for j in range(m):
            qj = np.concatenate([u0 + j / m * (u1 - u0), u0 + (j + 1) / m * (u1 - u0), [h / m]])
            V, res = self.engine.step(x, np.repeat(x[:, None], POINTS, axis=1), qj, p, self.scale)
            if not (float(res.ravel()[0]) <= RESIDUAL_TOL and np.all(np.isfinite(V))):
                return None
            mine = holder == j
            if mine.any():
                w = collocation.interpolation(tau[mine] * m - j)  # (k, 4) on (x, V1, V2, V3)
                guess[:, mine] = np.column_stack([x, V]) @ w.T
            x = V[:, -1]
        return guess

    def _at_samples(self, first: np.ndarray, nodal: np.ndarray) -> np.ndarray:
        """Values at every sample (n, ...) from the step values ``nodal`` (steps, 4, ...),
        sample 0 being ``first``."""
        g = self.grid
        flat = nodal.reshape(len(nodal), POINTS + 1, -1)
        out = np.empty((len(g.of), flat.shape[2]))
        out[0] = np.ravel(first)
        for s, (a, b) in enumerate(zip(g.k0, g.k1, strict=True)):  # a step's samples at once
            out[a + 1 : b + 1] = g.w[a + 1 : b + 1] @ flat[s]
        return out.reshape(len(g.of), *nodal.shape[2:])

    def simulate(self, S: np.ndarray, p: np.ndarray) -> np.ndarray:
        """Scaled states at every sample (nx x n) from the nodes ``S`` (nx x nodes) at the
        parameter vector ``p``. Raises SolverError where a step fails."""
        vals, _ = self._run(p, S=S)
        return self._at_samples(S[:, 0], vals).T

    def march(self, xi0: np.ndarray, p: np.ndarray) -> np.ndarray:
        """Scaled states at every sample integrated from ``xi0`` (each interval from the
        last one's end: the node guesses of a start). Raises SolverError."""
        vals, _ = self._run(p, xi0=xi0)
        return self._at_samples(np.asarray(xi0, float), vals).T

    def predict(self, xi0: np.ndarray, p: np.ndarray) -> np.ndarray:
        """The measured signals at every sample (ny x n), integrated from ``xi0``."""
        return self.outputs(self.scale[:, None] * self.march(xi0, p), p)[0]

    def outputs(self, x: np.ndarray, p: np.ndarray) -> tuple[np.ndarray, ...]:
        """The measured signals at every sample (ny x n) from the unscaled states ``x``
        (nx x n), and their Jacobians ``Y_x`` (n, ny, nx) and ``Y_p`` (n, ny, k)."""
        L, n = OUTPUT_CHUNK, x.shape[1]
        chunks = -(-n // L)
        pad = chunks * L - n
        X = np.hstack([x, np.repeat(x[:, -1:], pad, axis=1)])
        U = np.vstack([self.u, np.repeat(self.u[-1:], pad, axis=0)]).T
        parts = [
            self.engine.outputs(X[:, c * L : (c + 1) * L], U[:, c * L : (c + 1) * L], p)
            for c in range(chunks)
        ]
        y = np.hstack([a for a, _, _ in parts])[:, :n]
        ny, nx = y.shape[0], x.shape[0]
        Yx = np.hstack([b for _, b, _ in parts]).reshape(ny, -1, nx)[:, :n].transpose(1, 0, 2)
        k = parts[0][2].shape[1] // L
        Yp = np.hstack([c for _, _, c in parts]).reshape(ny, chunks * L, k)[:, :n]
        Yp = Yp.transpose(1, 0, 2)
        return y, Yx, Yp

    def sensitivities(self, S: np.ndarray, p: np.ndarray, D: np.ndarray):
        """States at every sample (nx x n) and their sensitivities: ``dS`` (n, nx, nx) to
        the node of the interval the sample lies in (sample 0: the identity to node 0),
        ``dT`` (n, nx, ne) to ``theta_e``, and that node's index per sample (n,)."""
        nx, ne = self.model.nx, D.shape[1]
        vals, sens = self._run(p, S=S, D=D)
        if not np.all(np.isfinite(sens)):
            raise SolverError("the sensitivities of the simulation are not finite")
        X = self._at_samples(S[:, 0], vals).T
        first = np.hstack([np.eye(nx), np.zeros((nx, ne))])
        full = self._at_samples(first, sens)
        step_node = np.searchsorted(self.grid.first, np.arange(len(self.grid.k0)), "right") - 1
        node = np.concatenate([[0], step_node[self.grid.of[1:]]])
        return X, full[:, :, :nx], full[:, :, nx:], node


def step_error(coarse: Shooting, reference: np.ndarray, xi0, p, data: np.ndarray) -> np.ndarray:
    """Per output, the largest difference of ``coarse``'s outputs (integrated from
    ``xi0`` at ``p``) from ``reference`` (ny x n: one step per sample) as a fraction of
    the :func:`noise_level` of ``data`` (inf where that level is 0)."""
    gap = np.max(np.abs(coarse.predict(xi0, p) - reference), axis=1)
    level = noise_level(data)
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(level > 0, gap / level, np.where(gap > 0, np.inf, 0.0))


def auto_step(make, xi0: np.ndarray, p: np.ndarray, data: np.ndarray) -> int:
    """The largest of :data:`STEPS` samples per step whose outputs, integrated from
    ``xi0`` at ``p``, differ from one step per sample by at most :data:`STEP_TOLERANCE` of
    each signal's :func:`noise_level` in ``data`` (n, ny); 1 when none does (noise-free
    data ask for the finest grid) or the record cannot be simulated at ``p``.
    ``make(step)`` gives the record's :class:`Shooting`."""
    if not np.all(noise_level(data) > 0):
        return 1
    try:
        reference = make(1).predict(xi0, p)
    except SolverError:  # the start values cannot be simulated: the fit will say so
        return 1
    for step in STEPS:
        try:
            if np.all(step_error(make(step), reference, xi0, p, data) <= STEP_TOLERANCE):
                return step
        except SolverError:
            continue
    return 1
