"""Scenarios: experiments written as data (TOML) and the runner and CLI that execute them.

A scenario file names a model, its parameters, inputs, a sweep or a simulation, the solver
and the outputs (see ``docs/scenarios.md``). ``run`` loads it, calls the runner registered
for its ``kind`` and writes ``summary.json``, CSV time series and PNG plots.

>>> from sarcomere.scenarios import load_scenario
>>> load_scenario("paper-static").model.fidelity
'paper'
"""

from sarcomere.dynamics.lazy import lazy_exports

#: Public name -> the module defining it, imported on first use: ``import
#: sarcomere.scenarios`` stays light (the CLI's ``--version`` and ``list`` need no CasADi);
#: the runners of the packaged kinds register when :func:`run` first needs them.
_HOMES = {
    **dict.fromkeys(("load_scenario", "parse_scenario", "resolve_scenario"), "loader"),
    "packaged_scenarios": "catalog",
    **dict.fromkeys(("RunOutput", "quantity_tag"), "output"),
    **dict.fromkeys(("register_runner", "run", "runner_kinds"), "runner"),
    **dict.fromkeys(
        (
            "SIGNAL_TYPES",
            "Chirp",
            "Ramp",
            "Signal",
            "Sine",
            "Staircase",
            "Step",
            "Table",
            "signal_from_spec",
        ),
        "signals",
    ),
    "Scenario": "spec",
    "Study": "explore.study",
}


__all__ = sorted(_HOMES)  # every lazily imported name is public

__getattr__, __dir__ = lazy_exports(__name__, _HOMES, __all__)
