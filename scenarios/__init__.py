"""Scenarios: experiments written as data (TOML) and the runner and CLI that execute them.

A scenario file names a model, its parameters, inputs, a sweep or a simulation, the solver
and the outputs (see ``docs/scenarios.md``). ``run`` loads it, calls the runner registered
for its ``kind`` and writes ``summary.json``, CSV time series and PNG plots.

>>> from sarcomere.scenarios import load_scenario
>>> load_scenario("paper-static").model.fidelity
'paper'
"""

from . import control, cosim, dynamic, static  # noqa: F401  (register the kinds)
from .loader import load_scenario, packaged_scenarios, parse_scenario, resolve_scenario
from .output import RunOutput, quantity_tag
from .runner import register_runner, run, runner_kinds
from .signals import (
    SIGNAL_TYPES,
    Chirp,
    Ramp,
    Signal,
    Sine,
    Staircase,
    Step,
    Table,
    signal_from_spec,
)
from .spec import Scenario

__all__ = [
    "SIGNAL_TYPES",
    "Chirp",
    "Ramp",
    "RunOutput",
    "Scenario",
    "Signal",
    "Sine",
    "Staircase",
    "Step",
    "Table",
    "load_scenario",
    "packaged_scenarios",
    "parse_scenario",
    "quantity_tag",
    "register_runner",
    "resolve_scenario",
    "run",
    "runner_kinds",
    "signal_from_spec",
]
