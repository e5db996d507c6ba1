"""Exact linearisation of the flattened model as a named python-control ``StateSpace``.

An operating point is an equilibrium (:func:`operating_point`): at given inputs, at a
given load, or at the input that puts an output on a target (a length, a force).
:func:`linearize` evaluates the model's exact Jacobians there
(:meth:`~sarcomere.dynamics.Model.linearization`, algebraic unknowns eliminated by the
implicit function theorem, so the DAE fidelity levels are covered) and returns the
deviation model ``dx' = A dx + B du``, ``dy = C dx + D du`` with every state, input and
output labelled by :func:`~sarcomere.dynamics.modeling.labels.to_label`. With ``dt`` it is
the exact zero-order-hold discretisation (matrix exponential). :func:`classify_poles`
names each pole by the state that dominates its eigenvector.

Examples
--------
>>> from sarcomere.dynamics import hanging_load
>>> m = hanging_load(n=1, load_kg=0.02)
>>> op = operating_point(m, {"regulator.p_cmd": 5e4})
>>> sys = linearize(m, op, ["myofibril.length"])
>>> sys.input_labels, sys.output_labels
(['regulator__p_cmd'], ['myofibril__length'])
>>> bool(sys.dcgain() < 0)  # more pressure, shorter chain
True
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence

import control as ct
import numpy as np

from sarcomere.dynamics.assemblies import HOOK_MASS_KG
from sarcomere.dynamics.equilibrium import Equilibrium, solve_equilibrium
from sarcomere.dynamics.errors import ParameterError, SolverError
from sarcomere.dynamics.modeling.labels import to_label
from sarcomere.dynamics.modeling.model import Model

P_CMD = "regulator.p_cmd"

#: State-name segment (the component owning the state) -> the physical mode it names.
MODE_OF_COMPONENT = {
    "regulator": "pressure",
    "chamber": "pressure",
    "expansion": "expansion",
    "body": "body",
    "load": "load",
    "hook": "load",
}


def operating_point(
    model: Model,
    inputs: Mapping[str, float] | None = None,
    params: Mapping[str, object] | None = None,
    *,
    load_kg: float | None = None,
    target: tuple[str, float] | None = None,
    input_name: str = P_CMD,
    tol: float = 1e-9,
) -> Equilibrium:
    """An equilibrium to linearise about.

    Parameters
    ----------
    model : Model
    inputs : mapping, optional
        Input values by name [SI] (default: the model's start values).
    params : mapping, optional
        Parameter overrides by name (units allowed).
    load_kg : float, optional
        The hanging load [kg] (sets ``load.m`` to it plus the hook's mass).
    target : (str, float), optional
        ``(signal, value)``: solve for the value of ``input_name`` that puts the signal
        there at equilibrium (Newton on the exact steady-state gain), e.g.
        ``("myofibril.length", 0.165)``.
    input_name : str
        The input moved to meet ``target``.
    tol : float
        Relative tolerance on the target (of its value, or 1e-12 absolute at 0).

    Raises
    ------
    ParameterError
        For an unknown name, a model without a load, or a target that no input within
        the input's bounds reaches (naming the reachable range).
    """
    over = dict(params or {})
    if load_kg is not None:
        if "load.m" not in model.param_names:
            raise ParameterError("load_kg", load_kg, "None for a model without a hanging load")
        if not (math.isfinite(load_kg) and load_kg >= 0):
            raise ParameterError("load_kg", load_kg, "[0, inf) kg")
        over["load.m"] = HOOK_MASS_KG + load_kg
    u = dict(inputs or {})
    eq = solve_equilibrium(model, u, over)
    if target is None:
        return eq
    name, value = target
    if input_name not in model.input_names:
        raise ParameterError("input_name", input_name, f"an input of {model.input_names}")
    var = model.variables[input_name]
    lo, hi = var.low, var.high
    if "regulator.p_max" in model.param_names and input_name == P_CMD:
        hi = min(hi, float(model.parameters(over)[model.index("regulator.p_max")[1]]))
    # the reachable range: the ends of the input range (monotone steady-state map)
    ends = [solve_equilibrium(model, {**u, input_name: v}, over, guess=eq) for v in (lo, hi)]
    ys = sorted(e[name] for e in ends)
    if not ys[0] <= value <= ys[1]:
        raise ParameterError(
            f"target.{name}",
            value,
            f"[{ys[0]:.6g}, {ys[1]:.6g}] (reached by {input_name} in [{lo:g}, {hi:g}])",
        )
    k = model.input_names.index(input_name)
    lin = model.linearization([name])
    for _ in range(30):
        err = eq[name] - value
        if abs(err) <= tol * max(abs(value), 1e-12):
            return eq
        A, B, C, D = (np.array(M) for M in lin(eq.x, eq.z, eq.u, eq.p))
        gain = float((D - C @ np.linalg.solve(A, B))[0, k])  # steady state d y / d u
        v = float(np.clip(eq.u[k] - err / gain, lo, hi))
        eq = solve_equilibrium(model, {**u, input_name: v}, over, guess=eq)
    raise SolverError(f"operating point: {name} = {value:g} not met in 30 Newton steps")


def linearize(
    model: Model,
    op: Equilibrium,
    outputs: Sequence[str],
    dt: float | None = None,
    inputs: Sequence[str] | None = None,
) -> ct.StateSpace:
    """The exact linearisation about ``op`` as a python-control ``StateSpace``.

    Parameters
    ----------
    model : Model
    op : Equilibrium
        The operating point (:func:`operating_point`); ``op.z`` must satisfy the
        algebraic equations (an equilibrium does).
    outputs : sequence of str
        Signals of the model (states, algebraic, solved, declared outputs, inputs).
    dt : float, optional
        Sample time [s]: the exact zero-order-hold discretisation; None: continuous.
    inputs : sequence of str, optional
        The inputs kept (default: all).

    Returns
    -------
    control.StateSpace
        Deviations from ``op``; states, inputs and outputs labelled ``to_label(name)``.
    """
    ins = list(model.input_names if inputs is None else inputs)
    for n in ins:
        if n not in model.input_names:
            raise ParameterError("inputs", n, f"one of {model.input_names}")
    cols = [model.input_names.index(n) for n in ins]
    A, B, C, D = (
        np.array(M, dtype=float) for M in model.linearization(list(outputs))(op.x, op.z, op.u, op.p)
    )
    sys = ct.ss(
        A,
        B[:, cols],
        C,
        D[:, cols],
        states=[to_label(n) for n in model.state_names],
        inputs=[to_label(n) for n in ins],
        outputs=[to_label(n) for n in outputs],
        name=model.name,
    )
    if dt is None:
        return sys
    if not (isinstance(dt, int | float) and math.isfinite(dt) and dt > 0):
        raise ParameterError("dt", dt, "(0, inf) s, or None for the continuous model")
    return sys.sample(float(dt), method="zoh", name=f"{model.name}_d")


def classify_poles(model: Model, sys: ct.StateSpace) -> list[dict]:
    """Each pole of a continuous linearisation with the physical mode it belongs to.

    The dominant state of a pole is the one with the largest participation factor
    ``|v_i w_i|`` (right and left eigenvector entries: independent of the states' units
    and scaling); that state's component names the mode (:data:`MODE_OF_COMPONENT`:
    pressure, expansion, body, load; otherwise the component's own name). Complex pairs
    are listed once (positive imaginary part).

    Returns
    -------
    list of dict
        ``{"real_1_s", "imag_1_s", "frequency_Hz", "damping", "mode", "dominant_state",
        "share"}`` sorted from slowest to fastest; ``share`` is the dominant state's part
        of the pole's participation (they sum to 1 over the states).
    """
    vals, right = np.linalg.eig(sys.A)
    left = np.linalg.inv(right)  # rows: left eigenvectors, normalised so left @ right = I
    rows = []
    for k, lam in enumerate(vals):
        if lam.imag < 0:
            continue
        w = np.abs(right[:, k] * left[k, :])
        i = int(np.argmax(w))
        state = model.state_names[i]
        component = state.split(".")[-2] if "." in state else state
        wn = abs(lam)
        rows.append(
            {
                "real_1_s": float(lam.real),
                "imag_1_s": float(lam.imag),
                "frequency_Hz": float(wn / (2 * math.pi)),
                "damping": float(-lam.real / wn) if wn > 0 else 1.0,
                "mode": MODE_OF_COMPONENT.get(component.rstrip("0123456789"), component),
                "dominant_state": state,
                "share": float(w[i] / w.sum()),
            }
        )
    return sorted(rows, key=lambda r: abs(complex(r["real_1_s"], r["imag_1_s"])))
