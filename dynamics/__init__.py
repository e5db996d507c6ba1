"""The physics and its numerics: a Modelica-style modelling language, the APS components,
their flattened CasADi model, equilibrium, calibration and simulation.

Pipeline: ``params`` -> ``components`` in a :class:`System` -> ``flatten`` ->
:class:`Model` (plain CasADi Functions with named variables) -> :func:`solve_equilibrium`
/ :func:`simulate` -> :class:`Result`. See docs/architecture.md.

The names below are the public API; the sub-packages are ``modeling`` (the language),
``components`` and ``params`` (the physics), ``simulation`` (the numerics) and
``studies`` (numerical studies, never imported by the library).

Examples
--------
>>> from sarcomere.dynamics import Step, hanging_load, simulate, solve_equilibrium
>>> model = hanging_load(n=1, load_kg=0.05)
>>> rest = solve_equilibrium(model, {"regulator.p_cmd": 0.0})
>>> res = simulate(model, 0.5, inputs={"regulator.p_cmd": Step(final=1e5, time=0.1)}, x0=rest.x)
>>> bool(res.final("myofibril.length") < rest.signals["myofibril.length"])
True
"""

from .assemblies import FIDELITIES, hanging_load, isometric
from .equilibrium import Equilibrium, solve_equilibrium
from .errors import ModelError, ParameterError, SarcomereError, ScenarioError, SolverError
from .modeling.component import Component, System
from .modeling.model import Model
from .results import Result
from .signals import Chirp, Ramp, Signal, Sine, Staircase, Step, Table
from .simulation.settings import METHODS, SolverSettings
from .simulation.simulate import simulate
from .simulation.simulator import Simulator

__all__ = [
    "FIDELITIES",
    "METHODS",
    "Chirp",
    "Component",
    "Equilibrium",
    "Model",
    "ModelError",
    "ParameterError",
    "Ramp",
    "Result",
    "SarcomereError",
    "ScenarioError",
    "Signal",
    "Simulator",
    "Sine",
    "SolverError",
    "SolverSettings",
    "Staircase",
    "Step",
    "System",
    "Table",
    "hanging_load",
    "isometric",
    "simulate",
    "solve_equilibrium",
]
