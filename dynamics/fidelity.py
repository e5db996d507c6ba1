"""Fidelity levels that are not a flattened model of their own, and their validity.

* ``linear``: the model linearised at the scene's operating point and simulated exactly
  (:func:`~sarcomere.dynamics.simulation.linear.simulate_linear`).
* ``equilibrium_path``: for slow scenes, the output is the equilibrium at the present
  input, ``y_eq(u(t))``, computed on a few input values with continuation and
  interpolated (no integration), plus the dynamic part of the linear response,
  ``y_lin(t) - (y_op + K du(t))`` with ``K`` the linear model's steady-state gain: the lag
  of the regulator and the chambers behind a ramp, exact for the linearised model.

Both use only the Model's own Functions (equilibrium residual, exact linearisation); they
hold no physics of their own. What each leaves out, and the predicted error of that, is
:func:`predict`: computed from the equilibria along the input's range before anything is
simulated.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
from scipy.interpolate import CubicSpline

from .equilibrium import Equilibrium, solve_equilibrium
from .errors import SarcomereError
from .modeling.model import Model
from .results import Result
from .simulation.linear import simulate_linear, static_gain

PATH_NODES = 9
"""Equilibria along the input range for the equilibrium path (cubic interpolation in
between; 9 nodes keep the interpolation error of the packaged scenes below 1e-4 of the
span, measured in tests/dynamics/test_fidelity.py)."""


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
        The equilibrium at the middle of the input's range (where it is linearised).
    """

    input_name: str
    nodes: np.ndarray
    equilibria: list[Equilibrium]
    operating_point: Equilibrium

    def static(self, signals: Sequence[str], u: np.ndarray, slope: bool = False) -> np.ndarray:
        """``y_eq(u)`` of ``signals`` at the input values ``u`` (or its slope
        ``dy_eq/du``), shape (len(u), ny)."""
        Y = np.array([[e[n] for n in signals] for e in self.equilibria])
        if len(self.nodes) == 1:
            return np.zeros((len(u), len(signals))) if slope else np.repeat(Y, len(u), axis=0)
        return CubicSpline(self.nodes, Y, axis=0)(u, 1 if slope else 0)


def equilibrium_path(
    model: Model,
    input_name: str,
    u: np.ndarray,
    params: Mapping[str, object] | None = None,
    nodes: int = PATH_NODES,
) -> Path:
    """Equilibria of ``model`` at ``nodes`` values spanning the input samples ``u``."""
    lo, hi = float(np.min(u)), float(np.max(u))
    values = np.linspace(lo, hi, nodes) if hi > lo else np.array([lo])
    eqs, guess = [], None
    for v in values:
        guess = solve_equilibrium(model, {input_name: float(v)}, params, guess=guess)
        eqs.append(guess)
    mid = solve_equilibrium(model, {input_name: 0.5 * (lo + hi)}, params, guess=eqs[0])
    return Path(input_name, values, eqs, mid)


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
    name, sig = _single_input(inputs)
    lin = simulate_linear(model, path.operating_point, inputs, t_out, signals)
    u = np.asarray(sig(t_out), float) * np.ones(len(t_out))
    op = path.operating_point
    i = model.input_names.index(name)
    K = static_gain(model, op, signals)[:, i]
    y_op = np.array([op[n] for n in signals])
    dynamic = np.column_stack([lin[n] for n in signals]) - (y_op + np.outer(u - op.u[i], K))
    # the dynamic part scaled by the local steady-state gain dy_eq/du over the linear one
    ratio = path.static(signals, u, slope=True) / np.where(K != 0, K, 1.0)
    Y = path.static(signals, u) + dynamic * ratio
    meta = {**lin.meta, "method": "equilibrium path + linear dynamic part"}
    return Result(
        "time", "s", t_out, {n: Y[:, j] for j, n in enumerate(signals)}, dict(lin.units), meta=meta
    )


QUASI_STATIC_FRACTION = 0.1
"""Largest dynamic part (relative to the output's span) for which the equilibrium path's
error is predicted by the first-order lag expansion (:func:`predict`)."""


def predict(
    model: Model, path: Path, inputs: Mapping[str, object], t_out: np.ndarray, signals
) -> dict[str, float]:
    """Predicted error of ``linear`` and ``equilibrium_path``: max over ``signals`` of the
    error relative to the output's span, from the equilibria along the input's range and
    one linear run, before any nonlinear simulation.

    * ``linear`` leaves out the static nonlinearity: ``max |y_eq(u) - y_op - K du|``.
    * ``equilibrium_path`` is exact for the linear model and for the static map; it leaves
      out how the dynamics change along the path. With ``d`` the dynamic part over the
      span: for a slow input (``d <= QUASI_STATIC_FRACTION``) the dynamic part is the lag
      ``T(u) dy_eq/du du/dt`` with ``T = C A^-2 B / K``, which the level takes at the
      operating point, so the error is ``d`` times the relative spread of ``T`` over the
      path; otherwise ``d`` times the relative spread of the gain ``dy_eq/du``.
    """
    name, sig = _single_input(inputs)
    u = np.asarray(sig(t_out), float) * np.ones(len(t_out))
    op, i = path.operating_point, model.input_names.index(name)
    K = static_gain(model, op, signals)[:, i]
    y_static = path.static(signals, u)
    span = np.maximum(np.ptp(y_static, axis=0), 1e-300)
    y_lin = np.array([op[n] for n in signals]) + np.outer(u - op.u[i], K)
    e_lin = np.max(np.abs(y_static - y_lin), axis=0) / span
    lin = simulate_linear(model, op, inputs, t_out, signals)
    d = np.max(np.abs(np.column_stack([lin[n] for n in signals]) - y_lin), axis=0) / span
    lag, gain = [], []
    fn = model.linearization(list(signals))
    for e in path.equilibria:
        A, B, C, D = (np.array(v) for v in fn(e.x, e.z, e.u, e.p))
        Ke = (D - C @ np.linalg.solve(A, B))[:, i]
        G1 = (-C @ np.linalg.solve(A, np.linalg.solve(A, B)))[:, i]
        gain.append(Ke)
        lag.append(G1 / np.where(Ke != 0, Ke, 1.0))
    spread = {
        k: (np.ptp(v, axis=0) / np.maximum(np.abs(v).max(axis=0), 1e-300))
        for k, v in (("lag", np.array(lag)), ("gain", np.array(gain)))
    }
    e_path = np.where(d <= QUASI_STATIC_FRACTION, d * spread["lag"], d * spread["gain"])
    return {"linear": float(e_lin.max()), "equilibrium_path": float(e_path.max())}


def predict_reduced(
    reduced: Model,
    full: Model,
    path: Path,
    inputs: Mapping[str, object],
    t_out: np.ndarray,
    signals: Sequence[str],
    params: Mapping[str, object] | None = None,
) -> float:
    """Predicted error of a reduced chain level (``symmetric``, ``grouped``) against
    ``full``: its static error on the full model's equilibrium path plus the difference
    of the two linearised dynamic parts (:func:`run_equilibrium_path`), both relative to
    the span of the full model's static response; the nonlinear interplay of the two is
    left out."""
    name, sig = _single_input(inputs)
    u = np.asarray(sig(t_out), float) * np.ones(len(t_out))
    red = equilibrium_path(reduced, name, u, params, nodes=len(path.nodes))
    y_full = path.static(signals, u)
    span = np.maximum(np.ptp(y_full, axis=0), 1e-300)
    e_static = np.max(np.abs(red.static(signals, u) - y_full), axis=0) / span

    def dynamic(model: Model, p: Path) -> np.ndarray:
        op, i = p.operating_point, model.input_names.index(name)
        K = static_gain(model, op, signals)[:, i]
        lin = simulate_linear(model, op, inputs, t_out, signals)
        y_op = np.array([op[n] for n in signals])
        return np.column_stack([lin[n] for n in signals]) - (y_op + np.outer(u - op.u[i], K))

    e_dyn = np.max(np.abs(dynamic(reduced, red) - dynamic(full, path)), axis=0) / span
    return float(np.max(e_static + e_dyn))
