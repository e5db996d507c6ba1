"""The exact discrete LTI level: the model linearised at an operating point, simulated
without an integrator.

About an equilibrium ``(x_op, u_op)`` the model is ``dx' = A dx + B du``,
``dy = C dx + D du`` (:meth:`~sarcomere.dynamics.modeling.model.Model.linearization`, exact
CasADi Jacobians, ``z`` eliminated). Between two consecutive times ``a < b`` of the output
grid joined with the inputs' breakpoints the input is taken linear from its value just
after ``a`` to its value just before ``b`` (first-order hold), and the state is advanced
exactly by one matrix exponential of the augmented system (Franklin, Powell & Workman,
Digital Control of Dynamic Systems, 3rd ed., section 6.3.2)::

    d/dt [dx; du; w] = [[A, B, 0], [0, 0, I], [0, 0, 0]] [dx; du; w],  w = (u_b- - u_a+)/h

so piecewise-linear inputs whose breakpoints lie on that grid (steps, ramps, staircases,
tables) are simulated exactly, and smooth inputs (sines, chirps) with the error of linear
interpolation between the grid points. The start state is the linear model's own
equilibrium at the first input value, ``dx0 = -A^-1 B du0``. What this level leaves out is
everything nonlinear: it is valid only for small deviations from the operating point.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
from scipy.linalg import expm

from ..errors import SarcomereError
from ..modeling.model import Model
from ..results import Result


def _lfilter(*args, **kwargs):
    """scipy.signal's lfilter, imported on first use (scipy.signal costs every CLI run
    ~0.3 s otherwise: BENCHMARKS.md, start-up)."""
    from scipy.signal import lfilter

    return lfilter(*args, **kwargs)


def foh_matrices(
    A: np.ndarray, B: np.ndarray, h: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(Phi, G1, G2)`` with ``x(h) = Phi x(0) + G1 u(0) + G2 (u(h) - u(0))`` for
    ``x' = A x + B u`` and ``u`` linear over ``[0, h]`` (exact)."""
    n, m = B.shape
    M = np.zeros((n + 2 * m, n + 2 * m))
    M[:n, :n], M[:n, n : n + m] = A, B
    M[n : n + m, n + m :] = np.eye(m) / h  # w is the slope times h: columns of G2 per du
    E = expm(M * h)
    return E[:n, :n], E[:n, n : n + m], E[:n, n + m :]


MERGE_ULPS = 64
"""Times closer than this many ulps of the run's time scale (``max(1 s, |t0|, |tf|)``)
are one time: a breakpoint that round-off puts next to an output time (``0.4 * 3`` s
against ``1.2`` s) is not a step of its own (a zero-length step divides by zero)."""


def step_times(t_out: np.ndarray, breakpoints: Sequence[float]) -> tuple[np.ndarray, np.ndarray]:
    """The times a level steps between and where each output time is among them.

    The output grid joined with the inputs' breakpoints, times within
    :data:`MERGE_ULPS` ulps of each other merged into one (a breakpoint wins over an
    output time, so the input jumps exactly there; the output time is then reported at
    that instant, round-off away); every step is longer than that.

    Returns
    -------
    times : numpy.ndarray
        Increasing times [s], consecutive ones more than the merge distance apart.
    keep : numpy.ndarray
        Index into ``times`` of each entry of ``t_out``.
    """
    t_out = np.asarray(t_out, float)
    bps = np.asarray(breakpoints, float).reshape(-1)
    tol = MERGE_ULPS * np.finfo(float).eps * max(1.0, float(np.max(np.abs(t_out))))
    cand = np.concatenate([bps, t_out])
    is_bp = np.arange(len(cand)) < len(bps)
    times: list[float] = []
    rep_is_bp: list[bool] = []
    where = np.empty(len(cand), int)
    for j in np.lexsort((~is_bp, cand)):  # by time, a breakpoint first among equals
        if times and cand[j] - times[-1] <= tol:
            if is_bp[j] and not rep_is_bp[-1]:  # the input jumps exactly here
                times[-1], rep_is_bp[-1] = float(cand[j]), True
        else:
            times.append(float(cand[j]))
            rep_is_bp.append(bool(is_bp[j]))
        where[j] = len(times) - 1
    return np.array(times), where[len(bps) :]


#: A step is halved where the input's value at its middle is further than this from the
#: straight line between its ends, relative to the input's span over the run (at most
#: :data:`MAX_HALVINGS` times): the first-order hold then follows sines and chirps to
#: 3e-4 of their span (a 5 Hz sine on a 20 ms grid is 4.8 % of its amplitude off its
#: chords, which a linear level passes on to its output).
INPUT_CHORD_TOL = 3e-4
MAX_HALVINGS = 6


def refine_steps(
    times: np.ndarray, keep: np.ndarray, inputs: Mapping[str, object]
) -> tuple[np.ndarray, np.ndarray]:
    """``times`` (:func:`step_times`) with steps halved until every input is within
    :data:`INPUT_CHORD_TOL` of its chord on each step, and ``keep`` re-indexed; exact
    (nothing added) for piecewise-linear inputs whose breakpoints are step times."""
    sigs = list(inputs.values())
    spans = [np.ptp(np.asarray(s(times), float) * np.ones(len(times))) for s in sigs]
    marks = times[keep]
    for _ in range(MAX_HALVINGS):
        a, b = times[:-1], times[1:]
        mid = 0.5 * (a + b)
        bad = np.zeros(len(mid), bool)
        for sig, span in zip(sigs, spans, strict=True):
            chord = 0.5 * (np.asarray(sig(a), float) + np.asarray(sig(np.nextafter(b, -np.inf))))
            bad |= np.abs(np.asarray(sig(mid), float) - chord) > INPUT_CHORD_TOL * span
        if not bad.any():
            break
        times = np.sort(np.concatenate([times, mid[bad]]))
    return times, np.searchsorted(times, marks)


#: Runs of at least this many equal steps go through :func:`scipy.signal.lfilter` in the
#: eigenbasis of the step's matrix (one C loop per mode instead of a Python loop).
FILTER_RUN = 32


def step_keys(h: np.ndarray) -> np.ndarray:
    """Step lengths [s] rounded to 10 significant digits: the key under which a step's
    matrices are computed once. Output grids ``t0 + k dt`` differ from ``dt`` by ulps of
    ``t`` (3.6e-15 s at 30 s), which would otherwise give each step its own matrix
    exponential; the rounding moves a step by 5e-11 of its length at most."""
    h = np.asarray(h, float)
    scale = 10.0 ** np.floor(np.log10(np.maximum(h, 1e-300)))
    return np.round(h / scale, 9) * scale


def recurse(x0: np.ndarray, Phis: list, forcing: np.ndarray) -> np.ndarray:
    """``X[k + 1] = Phis[k] @ X[k] + forcing[k]`` from ``X[0] = x0``, shape (N, n).

    Runs of :data:`FILTER_RUN` or more steps with the same matrix object are filtered
    per mode (``Phi = V diag(w) V^-1``; exact up to round-off, used only where ``V`` is
    well conditioned), the rest stepped one by one."""
    N = len(forcing) + 1
    X = np.empty((N, len(x0)))
    X[0] = x0
    ids = np.array([id(M) for M in Phis])
    starts = np.flatnonzero(np.r_[True, ids[1:] != ids[:-1]])  # runs of one matrix
    modes: dict = {}  # id -> the matrix's eigen-decomposition, None if ill conditioned
    for j, k in zip(starts, np.r_[starts[1:], N - 1] - 1, strict=True):
        if k - j + 1 >= FILTER_RUN and ids[j] not in modes:
            modes[ids[j]] = _modes(Phis[j])
        if k - j + 1 < FILTER_RUN or modes[ids[j]] is None:
            for i in range(j, k + 1):
                X[i + 1] = Phis[i] @ X[i] + forcing[i]
        else:
            _filter(X, modes[ids[j]], forcing, j, k)
    return X


def _modes(Phi: np.ndarray) -> tuple | None:
    """``(w, V, V^-1)`` of ``Phi = V diag(w) V^-1``, None where ``V`` is ill conditioned."""
    w, V = np.linalg.eig(Phi)
    if np.linalg.cond(V) > 1e6:
        return None
    return w, V, np.linalg.inv(V)


def _filter(X: np.ndarray, modes: tuple, forcing: np.ndarray, j: int, k: int) -> None:
    """Steps ``j..k`` of :func:`recurse` with one matrix, by mode (its :func:`_modes`)."""
    w, V, Vi = modes
    b = forcing[j : k + 1] @ Vi.T  # (run, n) in the modes
    z0 = Vi @ X[j]
    Z = np.empty_like(b)
    for m in range(len(w)):
        Z[:, m] = _lfilter([1.0], [1.0, -w[m]], b[:, m], zi=[w[m] * z0[m]])[0]
    X[j + 1 : k + 2] = (Z @ V.T).real


def static_gain(model: Model, operating_point, signals: Sequence[str]) -> np.ndarray:
    """The linearisation's steady-state gain ``K = D - C A^-1 B`` of ``signals`` per input
    at ``operating_point``: ``dy = K du`` once the linear model has settled."""
    op = operating_point
    A, B, C, D = (np.array(v) for v in model.linearization(list(signals))(op.x, op.z, op.u, op.p))
    return D - C @ np.linalg.solve(A, B)


@dataclass
class Trajectory:
    """The states a level without an integrator steps through, and its own state
    derivative at each step's ends: what its defect (the model's ODE at those states
    minus that derivative) and so its predicted error are computed from.

    Attributes
    ----------
    times : numpy.ndarray
        Step times [s] (:func:`step_times`), shape (N,).
    keep : numpy.ndarray
        Index into ``times`` of each output time.
    x : numpy.ndarray
        States at ``times``, shape (N, nx), SI.
    u_right, u_left : numpy.ndarray
        Every input just after and just before each time, shape (N, nu).
    slope_start, slope_end : numpy.ndarray
        The level's own ``dx/dt`` at the start and at the end of each step, (N-1, nx).
    A : list of numpy.ndarray
        The state matrices the level steps with; ``which`` (N-1,) indexes them per step.
    """

    times: np.ndarray
    keep: np.ndarray
    x: np.ndarray
    u_right: np.ndarray
    u_left: np.ndarray
    slope_start: np.ndarray
    slope_end: np.ndarray
    A: list
    which: np.ndarray


def input_values(
    model: Model, inputs: Mapping[str, object], base: np.ndarray, t: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Every input of ``model`` just after and just before the times ``t``, shape
    (len(t), nu): the signals ``inputs`` by name, the others held at ``base``."""
    names = model.input_names
    unknown = [k for k in inputs if k not in names]
    if unknown:
        raise SarcomereError(f"{unknown} are not inputs of model '{model.name}'")
    out = []
    for at in (t, np.nextafter(t, -np.inf)):  # signals are right-continuous
        U = np.repeat(np.asarray(base, float)[None, :], len(t), axis=0)
        for k, sig in inputs.items():
            U[:, names.index(k)] = np.asarray(sig(at), float) * np.ones(len(t))
        out.append(U)
    return out[0], out[1]


def breakpoints(inputs: Mapping[str, object], t0: float, tf: float) -> list[float]:
    """The inputs' breakpoints in ``[t0, tf]`` [s]."""
    return [b for s in inputs.values() if hasattr(s, "breakpoints") for b in s.breakpoints(t0, tf)]


def linear_trajectory(
    model: Model, operating_point, inputs: Mapping[str, object], t_out: np.ndarray
) -> Trajectory:
    """The states of the linearisation at ``operating_point`` on ``t_out`` (and the
    inputs' breakpoints), stepped exactly (module docstring)."""
    op = operating_point
    A, B, _, _ = (np.array(v) for v in model.linearization([])(op.x, op.z, op.u, op.p))
    t_out = np.asarray(t_out, float)
    times, keep = step_times(t_out, breakpoints(inputs, float(t_out[0]), float(t_out[-1])))
    times, keep = refine_steps(times, keep, inputs)
    u_right, u_left = input_values(model, inputs, op.u, times)
    du_right, du_left = u_right - op.u, u_left - op.u
    try:
        dx = -np.linalg.solve(A, B @ du_right[0])
    except np.linalg.LinAlgError:
        raise SarcomereError("linear: A is singular at the operating point") from None
    h = np.diff(times)
    keys = step_keys(h)
    F = np.empty((len(h), A.shape[0]))  # the input's part of each step, all steps at once
    Phis = {}
    for key in np.unique(keys):
        Phi, G1, G2 = foh_matrices(A, B, float(key))
        Phis[key] = Phi
        sel = keys == key
        ua, ub = du_right[:-1][sel], du_left[1:][sel]
        F[sel] = ua @ G1.T + (ub - ua) @ G2.T
    X = recurse(dx, [Phis[key] for key in keys], F)
    return Trajectory(
        times,
        keep,
        op.x + X,
        u_right,
        u_left,
        X[:-1] @ A.T + du_right[:-1] @ B.T,
        X[1:] @ A.T + du_left[1:] @ B.T,
        [A],
        np.zeros(len(h), int),
    )


def simulate_linear(
    model: Model,
    operating_point,
    inputs: Mapping[str, object],
    t_out: np.ndarray,
    signals: Sequence[str],
) -> Result:
    """Simulate the linearisation of ``model`` at ``operating_point`` on ``t_out``.

    Parameters
    ----------
    model : Model
        The flattened model.
    operating_point : Equilibrium
        An equilibrium of ``model`` (``x``, ``z``, ``u``, ``p``): where it is linearised.
    inputs : mapping
        Input name to a signal (``__call__(t)``, optionally ``breakpoints(t0, tf)``); the
        inputs not named are held at the operating point.
    t_out : numpy.ndarray
        Output times [s], increasing; the simulation starts at ``t_out[0]``.
    signals : sequence of str
        Signals to return (any :attr:`~Model.signal_names`), as ``y_op + C dx + D du``.

    Returns
    -------
    Result
        Time and the signals; ``meta`` holds ``method = "linear"`` and the eigenvalues'
        slowest and fastest rates [1/s].
    """
    return linear_result(
        model,
        operating_point,
        linear_trajectory(model, operating_point, inputs, t_out),
        t_out,
        signals,
    )


def linear_result(
    model: Model, operating_point, traj: Trajectory, t_out: np.ndarray, signals: Sequence[str]
) -> Result:
    """The outputs ``y_op + C dx + D du`` of a :func:`linear_trajectory`."""
    op = operating_point
    _, _, C, D = (np.array(v) for v in model.linearization(list(signals))(op.x, op.z, op.u, op.p))
    y_op = np.array(model.signals_function(list(signals))(op.x, op.z, op.u, op.p)).ravel()
    k = traj.keep
    Y = y_op[None, :] + (traj.x[k] - op.x) @ C.T + (traj.u_right[k] - op.u) @ D.T
    rates = np.abs(np.linalg.eigvals(traj.A[0]).real)
    res = Result(
        "time",
        "s",
        np.asarray(t_out, float),
        {n: Y[:, j] for j, n in enumerate(signals)},
        {n: model.unit(n) for n in signals},
        meta={
            "method": "linear (exact FOH matrix exponential)",
            "n_steps": len(traj.times) - 1,
            "slowest_rate_per_s": float(rates.min()),
            "fastest_rate_per_s": float(rates.max()),
        },
    )
    return res.require_finite("linear")
