"""The physics: parameters, components with ports, flattening into one CasADi model,
equilibrium, calibration and simulation.

Pipeline: ``params`` -> ``components`` (+ ``component.System``) -> ``flatten`` ->
``model.Model`` (CasADi Functions with named variables) -> ``equilibrium`` /
``simulate`` -> ``results.Result``. See docs/architecture.md.
"""
