"""Fidelity levels that are not a flattened model of their own, and their validity.

* ``linear``: the model linearised at the scene's operating point and simulated exactly
  (:func:`~sarcomere.dynamics.simulation.linear.simulate_linear`).
* ``equilibrium_path``: for slow scenes, the output is the equilibrium at the present
  input, ``y_eq(u(t))``, computed on a few input values with continuation and
  interpolated, plus ``C xi`` for the deviation ``xi = x - x_eq(u)`` from the path, which
  obeys ``xi' = A xi - (dx_eq/du) du/dt`` to first order in ``xi``, with ``A``, ``C`` of
  the nearest path node, stepped exactly by matrix exponentials: the lag of the
  regulator and the chambers behind a ramp and the ringing at its corners, with no
  integration of the nonlinear model.

Both use only the Model's own Functions (equilibrium residual, exact linearisation); they
hold no physics of their own. What each leaves out, and the predicted error of that, is
:func:`predict_linear` and :func:`predict_path`: computed from the equilibria along the
input's range before anything is simulated; :func:`predict_reduced` compares a reduced
chain with a reference chain the same way (:func:`chain_response`).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
from scipy.interpolate import CubicSpline
from scipy.linalg import expm

from .equilibrium import Equilibrium, solve_equilibrium
from .errors import SarcomereError
from .modeling.model import Model
from .results import Result
from .simulation.linear import simulate_linear, static_gain, step_times

PATH_NODES = 17
"""Equilibria along the input range for the equilibrium path (cubic interpolation of the
static map in between, nearest node for the deviation's A and C). With 17 the ramp-50g
path is 0.094 % off full (9: 0.30 %, 5: 0.64 %; tests/dynamics/test_fidelity.py)."""


@dataclass
class Path:
    """Equilibria along the input's range: the static map of a one-input scene.

    Attributes
    ----------
    input_name : str
        The input that varies.
    nodes : numpy.ndarray
        Input values of the equilibria (increasing).
    equilibria : list of Equilibrium
        One per node, found by continuation from the first.
    operating_point : Equilibrium
        The middle node's equilibrium (mid-range for an odd number of nodes): where the
        ``linear`` level linearises.
    """

    input_name: str
    nodes: np.ndarray
    equilibria: list[Equilibrium]
    operating_point: Equilibrium

    def state_slope(self, u: np.ndarray) -> np.ndarray:
        """``dx_eq/du`` of the states at the input values ``u``, shape (len(u), nx)."""
        X = np.array([e.x for e in self.equilibria])
        if len(self.nodes) == 1:
            return np.zeros((len(u), X.shape[1]))
        return CubicSpline(self.nodes, X, axis=0)(u, 1)

    def static(self, signals: Sequence[str], u: np.ndarray) -> np.ndarray:
        """``y_eq(u)`` of ``signals`` at the input values ``u``, shape (len(u), ny)."""
        Y = np.array([[e[n] for n in signals] for e in self.equilibria])
        if len(self.nodes) == 1:
            return np.repeat(Y, len(u), axis=0)
        return CubicSpline(self.nodes, Y, axis=0)(u)


def equilibrium_path(
    model: Model,
    input_name: str,
    u: np.ndarray,
    params: Mapping[str, object] | None = None,
    nodes: int = PATH_NODES,
    guess: Equilibrium | None = None,
) -> Path:
    """Equilibria of ``model`` at ``nodes`` values spanning the input samples ``u``, by
    continuation from ``guess`` (an equilibrium of ``model``; default: its start values)."""
    lo, hi = float(np.min(u)), float(np.max(u))
    values = np.linspace(lo, hi, nodes) if hi > lo else np.array([lo])
    eqs = []
    for v in values:
        guess = solve_equilibrium(model, {input_name: float(v)}, params, guess=guess)
        eqs.append(guess)
    return Path(input_name, values, eqs, eqs[len(eqs) // 2])


def _single_input(inputs: Mapping[str, object]) -> tuple[str, object]:
    if len(inputs) != 1:
        raise SarcomereError(f"fidelity levels linear/equilibrium_path need one input: {inputs}")
    return next(iter(inputs.items()))


def run_linear(
    model: Model, path: Path, inputs: Mapping[str, object], t_out: np.ndarray, signals
) -> Result:
    """The ``linear`` level: the linearisation at the middle of the input's range."""
    return simulate_linear(model, path.operating_point, inputs, t_out, signals)


def run_equilibrium_path(
    model: Model, path: Path, inputs: Mapping[str, object], t_out: np.ndarray, signals
) -> Result:
    """The ``equilibrium_path`` level (module docstring)."""
    Y = _path_response(model, path, inputs, t_out, list(signals), range(len(path.nodes)))
    meta = {"method": "equilibrium path + scheduled linear deviation", "n_steps": 0}
    units = {n: model.unit(n) for n in signals}
    res = Result("time", "s", t_out, {n: Y[:, j] for j, n in enumerate(signals)}, units, meta)
    return res.require_finite("equilibrium_path")


def _path_response(
    model: Model,
    path: Path,
    inputs: Mapping[str, object],
    t_out: np.ndarray,
    signals: list[str],
    use: Sequence[int],
) -> np.ndarray:
    """``y_eq(u(t)) + C xi`` with the deviation from the path ``xi = x - x_eq(u)``
    following ``xi' = A xi - (dx_eq/du) du/dt``, ``A``, ``C`` and ``dx_eq/du = -A^-1 B``
    of the path node nearest to the present input (of the nodes ``use``), each step
    exact (matrix exponential) for a piecewise-linear input."""
    name, sig = _single_input(inputs)
    fn = model.linearization(signals)
    nodes = np.array([path.nodes[k] for k in use])
    mats = []
    for k in use:
        e = path.equilibria[k]
        A, _, C, _ = (np.array(v) for v in fn(e.x, e.z, e.u, e.p))
        mats.append((A, C))
    t0, tf = float(t_out[0]), float(t_out[-1])
    bps = sig.breakpoints(t0, tf) if hasattr(sig, "breakpoints") else []
    times, keep = step_times(t_out, bps)
    right = np.asarray(sig(times), float) * np.ones(len(times))
    left = np.asarray(sig(np.nextafter(times, -np.inf)), float) * np.ones(len(times))
    h = np.diff(times)
    mid = 0.5 * (right[:-1] + left[1:])
    # the path's own state slope dx_eq/du (its spline), times the input's slope on the step
    drive = -path.state_slope(mid) * ((left[1:] - right[:-1]) / h)[:, None]
    which = np.abs(mid[:, None] - nodes[None, :]).argmin(axis=1)
    X_eq = [e.x for e in path.equilibria]
    spline = CubicSpline(path.nodes, X_eq, axis=0) if len(path.nodes) > 1 else None
    jumps = np.zeros((len(times), len(X_eq[0])))
    if spline is not None:
        jumps = spline(right) - spline(left)
    nx = mats[0][0].shape[0]
    xi = np.zeros((len(times), nx))
    cache: dict[tuple[int, float], tuple[np.ndarray, np.ndarray]] = {}
    for k in range(len(h)):
        key = (int(which[k]), round(float(h[k]), 15))
        if key not in cache:  # Phi = e^(A h), Psi = int_0^h e^(A s) ds = A^-1 (Phi - I)
            A = mats[key[0]][0]
            Phi = expm(A * key[1])
            cache[key] = (Phi, np.linalg.solve(A, Phi - np.eye(nx)))
        Phi, Psi = cache[key]
        xi[k + 1] = Phi @ xi[k] + Psi @ drive[k]
        xi[k + 1] -= jumps[k + 1]  # the state is continuous where the equilibrium jumps
    u = right[keep]
    near = np.abs(u[:, None] - nodes[None, :]).argmin(axis=1)
    dev = np.array([mats[j][1] @ x for j, x in zip(near, xi[keep], strict=True)])
    return path.static(signals, u) + dev


def predict_linear(
    model: Model, path: Path, inputs: Mapping[str, object], t_out: np.ndarray, signals
) -> np.ndarray:
    """Predicted error of ``linear`` per signal (relative to the output's span): the
    static nonlinearity it leaves out, ``max |y_eq(u) - y_op - K du|`` over the input's
    samples, from the equilibria along the input's range."""
    name, sig = _single_input(inputs)
    signals = list(signals)
    u = np.asarray(sig(t_out), float) * np.ones(len(t_out))
    op, i = path.operating_point, model.input_names.index(name)
    K = static_gain(model, op, signals)[:, i]
    y_static = path.static(signals, u)
    y_lin = np.array([op[n] for n in signals]) + np.outer(u - op.u[i], K)
    return np.max(np.abs(y_static - y_lin), axis=0) / _span(y_static)


def _span(y: np.ndarray) -> np.ndarray:
    return np.maximum(np.ptp(y, axis=0), 1e-300)


def predict_path(
    model: Model,
    path: Path,
    inputs: Mapping[str, object],
    t_out: np.ndarray,
    signals,
    e_lin: np.ndarray | None = None,
) -> float:
    """Predicted error of ``equilibrium_path`` (max over ``signals``, relative to the
    span): it leaves out how ``A`` and ``C`` change between path nodes and the
    nonlinearity of the deviation ``xi``. The first is estimated by running the deviation
    on every second node (nearest-node scheduling converges to first order in the node
    spacing, so the difference estimates the error of the full set), the second as
    ``e_lin d`` with ``d`` the deviation's size over the span and ``e_lin``
    (:func:`predict_linear`, computed when not given) the static nonlinearity met by a
    deviation of that size (conservative for slow scenes, where it is of order ``d^2``).
    """
    _, sig = _single_input(inputs)
    signals = list(signals)
    if e_lin is None:
        e_lin = predict_linear(model, path, inputs, t_out, signals)
    u = np.asarray(sig(t_out), float) * np.ones(len(t_out))
    y_static = path.static(signals, u)
    span = _span(y_static)
    every = range(len(path.nodes))
    Y = _path_response(model, path, inputs, t_out, signals, every)
    d = np.max(np.abs(Y - y_static), axis=0) / span
    coarse = _path_response(model, path, inputs, t_out, signals, every[::2])
    e_sched = np.max(np.abs(Y - coarse), axis=0) / span
    return float(np.max(e_sched + e_lin * d))


def path_jump_bound(
    path: Path,
    inputs: Mapping[str, object],
    t_out: np.ndarray,
    signals,
    e_lin: np.ndarray,
) -> float:
    """A lower bound of :func:`predict_path` from the input alone: where the input jumps
    (a step), the state cannot, so the deviation from the path right after the jump is
    the jump of the static response, ``d >= |y_eq(u+) - y_eq(u-)| / span``, and the
    error term ``e_lin d`` is at least ``e_lin`` times that; zero (up to round-off) for
    continuous inputs."""
    _, sig = _single_input(inputs)
    signals = list(signals)
    t0, tf = float(t_out[0]), float(t_out[-1])
    bps = np.asarray(sig.breakpoints(t0, tf) if hasattr(sig, "breakpoints") else [], float)
    if not bps.size:
        return 0.0
    after = np.asarray(sig(bps), float) * np.ones(len(bps))
    before = np.asarray(sig(np.nextafter(bps, -np.inf)), float) * np.ones(len(bps))
    u = np.asarray(sig(t_out), float) * np.ones(len(t_out))
    span = _span(path.static(signals, u))
    jump = np.abs(path.static(signals, after) - path.static(signals, before))
    return float(np.max(e_lin * np.max(jump, axis=0) / span))


def predict(
    model: Model, path: Path, inputs: Mapping[str, object], t_out: np.ndarray, signals
) -> dict[str, float]:
    """Predicted error of ``linear`` and ``equilibrium_path`` (:func:`predict_linear`,
    :func:`predict_path`): max over ``signals`` of the error relative to the output's
    span, from the equilibria along the input's range and their linearisations, before
    any nonlinear simulation."""
    e_lin = predict_linear(model, path, inputs, t_out, signals)
    e_path = predict_path(model, path, inputs, t_out, signals, e_lin)
    return {"linear": float(e_lin.max()), "equilibrium_path": e_path}


@dataclass
class ChainResponse:
    """What a reduced chain's prediction compares, on the scene's output grid.

    Attributes
    ----------
    static : numpy.ndarray
        ``y_eq(u(t))`` of the signals, shape (len(t), ny), from the chain's own path.
    dynamic : numpy.ndarray
        The linearised dynamic part ``y_lin - (y_op + K du)`` at the path's operating
        point, same shape.
    """

    static: np.ndarray
    dynamic: np.ndarray


def chain_response(
    model: Model,
    path: Path,
    inputs: Mapping[str, object],
    t_out: np.ndarray,
    signals: Sequence[str],
) -> ChainResponse:
    """The static and linearised dynamic response of a chain model on its ``path``."""
    name, sig = _single_input(inputs)
    signals = list(signals)
    u = np.asarray(sig(t_out), float) * np.ones(len(t_out))
    op, i = path.operating_point, model.input_names.index(name)
    K = static_gain(model, op, signals)[:, i]
    lin = simulate_linear(model, op, inputs, t_out, signals)
    y_op = np.array([op[n] for n in signals])
    dyn = np.column_stack([lin[n] for n in signals]) - (y_op + np.outer(u - op.u[i], K))
    return ChainResponse(path.static(signals, u), dyn)


def predict_reduced(reduced: ChainResponse, reference: ChainResponse) -> float:
    """Predicted difference of a reduced chain (``symmetric``, ``grouped``) to a
    reference chain (``full``, or a grouped chain as a convergence estimate), both
    :func:`chain_response` on paths with the same nodes: the difference of the statics
    plus that of the linearised dynamic parts, each relative to the span of the
    reference's static response (max over time, then over the signals); the nonlinear
    interplay of the two is left out."""
    span = _span(reference.static)
    e_static = np.max(np.abs(reduced.static - reference.static), axis=0) / span
    e_dyn = np.max(np.abs(reduced.dynamic - reference.dynamic), axis=0) / span
    return float(np.max(e_static + e_dyn))


def static_difference(
    reduced: Path,
    reference: Path,
    inputs: Mapping[str, object],
    t_out: np.ndarray,
    signals: Sequence[str],
) -> float:
    """The static part of :func:`predict_reduced` alone, from the two chains' paths (no
    linearisation): a lower bound of the prediction, enough to rule a chain out."""
    _, sig = _single_input(inputs)
    signals = list(signals)
    u = np.asarray(sig(t_out), float) * np.ones(len(t_out))
    y_ref = reference.static(signals, u)
    diff = np.max(np.abs(reduced.static(signals, u) - y_ref), axis=0) / _span(y_ref)
    return float(np.max(diff))
