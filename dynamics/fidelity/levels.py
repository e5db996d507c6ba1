"""The two fidelity levels that are not a flattened model of their own.

* ``linear``: the model linearised at the middle of the input's range and stepped
  exactly (:func:`~sarcomere.dynamics.simulation.linear.linear_trajectory`).
* ``equilibrium_path``: for slow scenes, the output is the equilibrium at the present
  input, ``y_eq(u(t))``, computed on a few input values with continuation and
  interpolated, plus ``C xi`` for the deviation ``xi = x - x_eq(u)`` from the path, which
  obeys ``xi' = A xi - (dx_eq/du) du/dt`` to first order in ``xi``, with ``A``, ``C`` of
  the nearest path node, stepped exactly by matrix exponentials: the lag of the
  regulator and the chambers behind a ramp and the ringing at its corners, with no
  integration of the nonlinear model.

Both use only the Model's own Functions (equilibrium residual, exact linearisation); they
hold no physics of their own. Each returns its states as a
:class:`~sarcomere.dynamics.simulation.linear.Trajectory`, from which its error is
predicted (:mod:`.predictions`).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np
from scipy.linalg import expm

from ..equilibrium import Equilibrium, solve_equilibrium
from ..errors import SarcomereError
from ..modeling.model import Model
from ..results import Result
from ..schema import WITHOUT_MODEL
from ..simulation.linear import (
    Trajectory,
    breakpoints,
    input_values,
    linear_result,
    linear_trajectory,
    recurse,
    refine_steps,
    step_keys,
    step_times,
)

LEVELS = WITHOUT_MODEL  # the levels of this module, by name


def CubicSpline(*args, **kwargs):  # noqa: N802
    """scipy's CubicSpline, imported on first use (0.25 s of every CLI run otherwise)."""
    from scipy.interpolate import CubicSpline as spline

    return spline(*args, **kwargs)


#: Equilibria along the command's range for the ``linear`` level (its operating point,
#: the middle one, and its prediction's static nonlinearity over the range).
LINEAR_PATH_NODES = 3

PATH_NODES = 9
"""Equilibria along the input range for the equilibrium path (cubic interpolation of the
static map in between, nearest node for the deviation's A and C). With 9 the ramp-50g
path is 0.30 % off full (17: 0.094 %, 5: 0.64 %; tests/dynamics/test_fidelity.py), at
half the equilibria and linearisations of 17: enough for tolerances of 1 % and more,
and what the path leaves out is in its prediction."""


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
    steps: dict = field(default_factory=dict, repr=False)

    def _spline(self, V: np.ndarray, u: np.ndarray, derivative: int = 0) -> np.ndarray:
        """The rows ``V`` (one per node) on a cubic spline at ``u`` (constant for one node)."""
        if len(self.nodes) == 1:
            return np.repeat(V * (derivative == 0), len(u), axis=0)
        return CubicSpline(self.nodes, V, axis=0)(u, derivative)

    def state_slope(self, u: np.ndarray) -> np.ndarray:
        """``dx_eq/du`` of the states at the input values ``u``, shape (len(u), nx)."""
        return self._spline(np.array([e.x for e in self.equilibria]), u, 1)

    def state(self, u: np.ndarray) -> np.ndarray:
        """``x_eq(u)`` at the input values ``u``, shape (len(u), nx)."""
        return self._spline(np.array([e.x for e in self.equilibria]), u)

    def static(self, signals: Sequence[str], u: np.ndarray) -> np.ndarray:
        """``y_eq(u)`` of ``signals`` at the input values ``u``, shape (len(u), ny)."""
        return self._spline(np.array([[e[n] for n in signals] for e in self.equilibria]), u)


def equilibrium_path(
    model: Model,
    input_name: str,
    u: np.ndarray,
    params: Mapping[str, object] | None = None,
    nodes: int = PATH_NODES,
    guess: Equilibrium | None = None,
    known: Sequence[Equilibrium] = (),
) -> Path:
    """Equilibria of ``model`` at ``nodes`` values spanning the input samples ``u``, by
    continuation from ``guess`` (an equilibrium of ``model``; default: its start values);
    ``known`` equilibria (of the same model and parameters) at a node's value, to 1e-12,
    are taken as they are (a coarser path's nodes are among a finer one's)."""
    lo, hi = float(np.min(u)), float(np.max(u))
    values = np.linspace(lo, hi, nodes) if hi > lo else np.array([lo])
    i = model.input_names.index(input_name)
    eqs = []
    for v in values:
        same = [e for e in known if abs(e.u[i] - v) <= 1e-12 * max(1.0, abs(v))]
        guess = same[0] if same else solve_equilibrium(model, {input_name: v}, params, guess=guess)
        eqs.append(guess)
    values = np.array([e.u[i] for e in eqs])
    return Path(input_name, values, eqs, eqs[len(eqs) // 2])


def single_input(inputs: Mapping[str, object]) -> tuple[str, object]:
    """The one ``(name, signal)`` of ``inputs``; an error for more or fewer."""
    if len(inputs) != 1:
        raise SarcomereError(f"fidelity levels linear/equilibrium_path need one input: {inputs}")
    return next(iter(inputs.items()))


def trajectory(
    level: str,
    model: Model,
    path: Path,
    inputs: Mapping[str, object],
    t_out: np.ndarray,
) -> Trajectory:
    """The states of ``level`` (one of :data:`LEVELS`) on ``t_out``: the linearisation
    at the path's operating point, or the path plus the scheduled deviation."""
    single_input(inputs)
    if level == "linear":
        return linear_trajectory(model, path.operating_point, inputs, t_out)
    return path_trajectory(model, path, inputs, t_out)


def level_result(
    level: str, model: Model, path: Path, traj: Trajectory, t_out: np.ndarray, signals
) -> Result:
    """The outputs ``signals`` of ``level``'s :func:`trajectory` (checked finite)."""
    if level == "linear":
        return linear_result(model, path.operating_point, traj, t_out, list(signals))
    return path_result(model, path, traj, t_out, signals)


def path_result(model: Model, path: Path, traj: Trajectory, t_out: np.ndarray, signals) -> Result:
    """The outputs ``y_eq(u) + C xi`` of a :func:`path_trajectory`, ``C`` of the node
    nearest to the present input."""
    signals = list(signals)
    fn = model.linearization(signals)
    k = traj.keep
    u = traj.u_right[k, model.input_names.index(path.input_name)]
    near = np.abs(u[:, None] - path.nodes[None, :]).argmin(axis=1)
    Cs = {}
    for j in np.unique(near):
        e = path.equilibria[j]
        Cs[j] = np.array(fn(e.x, e.z, e.u, e.p)[2])
    xi = traj.x[k] - path.state(u)
    dev = np.array([Cs[j] @ d for j, d in zip(near, xi, strict=True)])
    Y = path.static(signals, u) + dev
    meta = {"method": "equilibrium path + scheduled linear deviation", "n_steps": 0}
    units = {n: model.unit(n) for n in signals}
    res = Result("time", "s", t_out, {n: Y[:, j] for j, n in enumerate(signals)}, units, meta)
    return res.require_finite("equilibrium_path")


def path_trajectory(
    model: Model,
    path: Path,
    inputs: Mapping[str, object],
    t_out: np.ndarray,
    use: Sequence[int] | None = None,
) -> Trajectory:
    """The states ``x_eq(u) + xi`` of the equilibrium path level, the deviation from the
    path ``xi = x - x_eq(u)`` following ``xi' = A xi - (dx_eq/du) du/dt`` with ``A`` of
    the path node nearest to the present input (of the nodes ``use``, default all), each
    step exact (matrix exponential) for a piecewise-linear input; the level's own state
    derivative is ``A xi``."""
    name, sig = single_input(inputs)
    i = model.input_names.index(name)
    use = range(len(path.nodes)) if use is None else use
    nodes = np.array([path.nodes[k] for k in use])
    As = []
    fn = model.linearization([])
    for k in use:
        e = path.equilibria[k]
        As.append(np.array(fn(e.x, e.z, e.u, e.p)[0]))
    t_out = np.asarray(t_out, float)
    times, keep = step_times(t_out, breakpoints(inputs, float(t_out[0]), float(t_out[-1])))
    times, keep = refine_steps(times, keep, inputs)
    op = path.operating_point
    u_right, u_left = input_values(model, inputs, op.u, times)
    right, left = u_right[:, i], u_left[:, i]
    h = np.diff(times)
    mid = 0.5 * (right[:-1] + left[1:])
    # the path's own state slope dx_eq/du (its spline), times the input's slope on the step
    drive = -path.state_slope(mid) * ((left[1:] - right[:-1]) / h)[:, None]
    which = np.abs(mid[:, None] - nodes[None, :]).argmin(axis=1)
    jumps = path.state(right) - path.state(left)
    nx = As[0].shape[0]
    steps = step_matrices(As, which, h, path.steps, [use[w] for w in range(len(As))])
    # xi[k+1] = Phi xi[k] + Psi drive[k] - jump[k+1]: the state is continuous where the
    # path jumps; ``end`` is xi at the end of each step, before the jump
    forcing = apply_each([P for _, P in steps], drive) - jumps[1:]
    xi = recurse(np.zeros(nx), [Phi for Phi, _ in steps], forcing)
    end = xi[1:] + jumps[1:]
    A_step = [As[w] for w in which]
    slope_start, slope_end = apply_each(A_step, xi[:-1]), apply_each(A_step, end)
    x = path.state(right) + xi
    return Trajectory(times, keep, x, u_right, u_left, slope_start, slope_end, As, which)


def apply_each(mats: list, v: np.ndarray) -> np.ndarray:
    """``mats[k] @ v[k]`` for every k, shape of ``v``: one product per distinct matrix
    object (the steps share a few)."""
    out = np.empty_like(v)
    ids = np.array([id(M) for M in mats])
    for u, first in zip(*np.unique(ids, return_index=True), strict=True):
        sel = ids == u
        out[sel] = v[sel] @ mats[first].T
    return out


def step_matrices(
    As: list, which: np.ndarray, h: np.ndarray, cache: dict, names: list | None = None
) -> list[tuple[np.ndarray, np.ndarray]]:
    """:func:`exact_step` of every step (``As[which[k]]`` over ``h[k]``), each distinct
    (matrix, h) computed once; ``names`` name the matrices in ``cache`` (default their
    index)."""
    names = list(range(len(As))) if names is None else names
    hk = step_keys(h)
    distinct = {}
    for w, step in set(zip(which.tolist(), hk.tolist(), strict=True)):
        distinct[w, step] = exact_step(As[w], (names[w], step), cache)
    return [distinct[w, step] for w, step in zip(which.tolist(), hk.tolist(), strict=True)]


def exact_step(A: np.ndarray, key: tuple, cache: dict) -> tuple[np.ndarray, np.ndarray]:
    """``Phi = e^(A h)``, ``Psi = int_0^h e^(A s) ds = A^-1 (Phi - I)`` with ``h =
    key[-1]``, cached under ``key`` (which matrix, h as :func:`step_keys` rounds it)."""
    if key not in cache:
        Phi = expm(A * key[-1])
        cache[key] = (Phi, np.linalg.solve(A, Phi - np.eye(len(A))))
    return cache[key]
