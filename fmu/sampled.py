"""Sampled systems (discrete laws such as a controller's) as Co-Simulation FMUs.

A :class:`SampledSystem` is ``x_{k+1} = update(x_k, u_k, p)``, ``y = output(x, p)``: at
each sample instant the update runs on the inputs, and the outputs (functions of the
state only) hold between instants. It is exported through the same pipeline as a
continuous model (:func:`~.export.build`: generated C, ``model_data``, the FMI wrapper of
``fmu/c/`` with ``SM_SAMPLED``), as a **Co-Simulation FMU only**.

``doStep(t, h)`` semantics (the C wrapper, ``physics.c``):

* the sample instants are ``t_0 + k T`` (``t_0`` the start time, ``T`` the period,
  ``k = 0, 1, ...``): the first sample is at the start time;
* a ``doStep(t, h)`` executes the update at every sample instant in ``[t, t + h)`` (each
  to :data:`~.export.SAMPLE_TOL` of a period), in order, on the inputs set before it
  (inputs are held over a step); the sample at ``t + h`` belongs to the next step;
* the outputs after the step are those of the last sample executed (before the first
  sample: the start state's);
* any ``h > 0`` holding at most :data:`~.export.MAX_SAMPLES` instants is accepted (a
  longer step is refused with a message): with ``h = T`` each step runs one sample; with
  ``h < T`` the outputs hold over the steps without an instant; with ``h > T`` (or not a multiple of
  ``T``) every instant in the step runs, all on the same held inputs, so a sample inside
  a step does not see the other participants move. Align the communication points with
  the instants (``T`` a multiple of ``h``) for a sampled controller that sees fresh values.

Model Exchange is refused: at export (``interface="ModelExchange"``) and by the binary
(instantiation as Model Exchange returns NULL with a logged reason), since a discrete
law has no continuous-time form.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import casadi as cs
import numpy as np

from sarcomere.dynamics.errors import ParameterError

from .export import Experiment, Layout, build, check_target

INTERFACES = ("CoSimulation", "ModelExchange")


@dataclass(frozen=True)
class Variable:
    """One variable of a sampled system: ``start`` [unit] is the value of a parameter and
    the start of an input (ignored for states and outputs, which ``start``/``output``
    compute); ``[low, high]`` its range."""

    name: str
    unit: str
    description: str
    start: float = 0.0
    low: float = -math.inf
    high: float = math.inf


@dataclass(frozen=True)
class SampledSystem:
    """A discrete law sampled every ``period`` seconds (see the module docstring).

    Parameters
    ----------
    name : str
        The model name and the FMU's model identifier (letters, digits, ``_``).
    description : str
        One line for the model description.
    period : float
        Sample period ``T`` [s], > 0.
    states, inputs, outputs, parameters : tuple of Variable
        In the order of the Functions' vectors.
    update : casadi.Function
        ``(x, u, p) -> x_next``, run at each sample instant.
    output : casadi.Function
        ``(x, p) -> y``, held between instants.
    start : casadi.Function
        ``(u, p) -> x_0``, the state before the first sample.
    """

    name: str
    description: str
    period: float
    states: tuple[Variable, ...]
    inputs: tuple[Variable, ...]
    outputs: tuple[Variable, ...]
    parameters: tuple[Variable, ...]
    update: cs.Function
    output: cs.Function
    start: cs.Function

    def __post_init__(self) -> None:
        if not (math.isfinite(self.period) and self.period > 0):
            raise ParameterError("period", self.period, "(0, inf) s")
        if not self.name.isidentifier():
            raise ParameterError("name", self.name, "letters, digits and '_'")
        nx, nu, ny, np_ = (
            len(v) for v in (self.states, self.inputs, self.outputs, self.parameters)
        )
        for f, ins, outs in (
            (self.update, (nx, nu, np_), (nx,)),
            (self.output, (nx, np_), (ny,)),
            (self.start, (nu, np_), (nx,)),
        ):
            got_in = tuple(f.size1_in(i) for i in range(f.n_in()))
            got_out = tuple(f.size1_out(i) for i in range(f.n_out()))
            if (got_in, got_out) != (ins, outs):
                raise ParameterError(
                    f"{f.name()} sizes", (got_in, got_out), f"inputs {ins}, outputs {outs}"
                )


def functions(system: SampledSystem) -> list[cs.Function]:
    """The generated Functions ``physics.c`` calls for a sampled system: ``sm_out``
    ``(x, u, p) -> y``, ``sm_start`` ``(u, p) -> x``, ``sm_update`` ``(x, u, p) -> x``."""
    s = system
    x = cs.MX.sym("x", len(s.states))
    u, p = cs.MX.sym("u", len(s.inputs)), cs.MX.sym("p", len(s.parameters))
    return [
        cs.Function("sm_out", [x, u, p], [s.output(x, p)], ["x", "u", "p"], ["y"]),
        cs.Function("sm_start", [u, p], [s.start(u, p)], ["u", "p"], ["x"]),
        cs.Function("sm_update", [x, u, p], [s.update(x, u, p)], ["x", "u", "p"], ["x_next"]),
    ]


def layout(system: SampledSystem) -> Layout:
    """The FMU variables: states (discrete, their start from ``start`` at the inputs' and
    parameters' start values), inputs, outputs (discrete, no direct feedthrough),
    parameters (tunable unless the start state depends on them)."""
    s = system
    u0 = np.array([v.start for v in s.inputs])
    p0 = np.array([v.start for v in s.parameters])
    x0 = np.array(s.start(u0, p0), dtype=float).ravel()
    rows = []
    for v, x in zip(s.states, x0, strict=True):
        rows.append((v.name, "x", v.unit, float(x), v.low, v.high, None, v.description))
    for group, variables in (("u", s.inputs), ("y", s.outputs), ("p", s.parameters)):
        for v in variables:
            start = None if group == "y" else v.start
            rows.append((v.name, group, v.unit, start, v.low, v.high, None, v.description))
    u, p = cs.MX.sym("u", len(s.inputs)), cs.MX.sym("p", len(s.parameters))
    used = set(cs.jacobian(s.start(u, p), p).sparsity().get_col())
    tunable = frozenset(v.name for i, v in enumerate(s.parameters) if i not in used)
    return Layout(s.name, s.description, rows, tunable, [[] for _ in s.outputs], [], s.period)


def export_sampled_fmu(
    system: SampledSystem,
    path: str | Path,
    fmi_version: int = 2,
    interface: str = "CoSimulation",
    experiment: Experiment | None = None,
) -> Path:
    """Write ``system`` as a Co-Simulation FMU (FMI 2.0 or 3.0, linux64 binary, sources).

    Raises
    ------
    ParameterError
        For ``interface="ModelExchange"`` (a discrete law has no continuous-time form),
        a bad version or path.
    FmuError
        If the C compiler fails.
    """
    if interface not in INTERFACES:
        raise ParameterError("interface", interface, "'CoSimulation'")
    if interface == "ModelExchange":
        raise ParameterError(
            "interface",
            interface,
            "'CoSimulation'",
            f"'{system.name}' is sampled every {system.period:g} s: a discrete law has no "
            "continuous-time form for Model Exchange",
        )
    path = check_target(path, fmi_version)
    experiment = experiment or Experiment(step_size=system.period)
    return build(layout(system), functions(system), path, fmi_version, experiment)
