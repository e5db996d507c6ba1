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

from .lazy import lazy_exports

#: Public name -> the module defining it, imported on first use (``import
#: sarcomere.dynamics.errors`` then stays light: no CasADi, no SciPy; the CLI starts fast).
_HOMES = {
    **dict.fromkeys(("FIDELITIES", "hanging_load", "isometric"), "assemblies"),
    **dict.fromkeys(("Equilibrium", "solve_equilibrium"), "equilibrium"),
    **dict.fromkeys(
        ("ModelError", "ParameterError", "SarcomereError", "ScenarioError", "SolverError"),
        "errors",
    ),
    **dict.fromkeys(("Component", "System"), "modeling.component"),
    "Model": "modeling.model",
    "PlausibilityWarning": "plausibility",
    "Result": "results",
    **dict.fromkeys(("antagonistic_joint", "bundle"), "robots"),
    **dict.fromkeys(("Chirp", "Ramp", "Signal", "Sine", "Staircase", "Step", "Table"), "signals"),
    **dict.fromkeys(("METHODS", "SolverSettings"), "simulation.settings"),
    "simulate": "simulation.simulate",
    "Simulator": "simulation.simulator",
}


__all__ = sorted(_HOMES)  # every lazily imported name is public

__getattr__, __dir__ = lazy_exports(__name__, _HOMES, __all__)
