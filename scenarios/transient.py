"""Scenario kind "transient": a run from the equilibrium at the inputs' start values, at
one fidelity level, at a level without a model of its own (``linear``,
``equilibrium_path``, with its predicted error) or at ``"auto"`` (the level
:func:`sarcomere.dynamics.fidelity.choose` picks); the scene is bound and run by
:mod:`.binding`, its step metrics come from :mod:`.step_metrics`."""

from __future__ import annotations

import time
from pathlib import Path

from sarcomere.dynamics import fidelity as ladder
from sarcomere.dynamics.assemblies import GROUPS
from sarcomere.dynamics.modeling.model import Model
from sarcomere.dynamics.results import Result

from . import binding
from .binding import Binding, aps_dict, bind, check_n, fidelity_level
from .output import RunOutput
from .runner import register_runner
from .spec import Scenario
from .step_metrics import transient_metrics
from .valve_supply import check_level, valve_auto


def run_transient(sc: Scenario, out_dir: Path) -> RunOutput:
    """Simulate from the equilibrium at the inputs' start values (module docstring).

    ``fidelity = "auto"``: the level of the auto rule runs, and only that one (see
    :func:`choose_fidelity`; on the valve supply, the valve's level:
    :func:`.valve_supply.valve_auto`).
    """
    sc.refuse_unused("sweep", "control", "cosim")
    if sc.model.fidelity != "auto":
        sc.refuse_unused("outputs.tolerance")
    b = bind(sc)
    fid = fidelity_level(sc, allow_auto=True, without_model=True)
    check_n(sc, ("model", "n"), b.n, fid)
    extra = {"aps_params": aps_dict(b.aps), "setup": b.setup}
    metrics = {}
    check_level(sc, b, fid)
    if fid == "auto" and b.supply == "valve_pwm":
        fid, res, extra["fidelity_auto"] = valve_auto(
            sc, b, binding.prepare, binding.simulate_scene
        )
        valve = extra["fidelity_auto"]["valve"]
        metrics["valve_predicted_error"] = valve["predicted_relative_error"]
    elif fid == "auto":
        fid, res, report = choose_fidelity(sc, b)
        extra["fidelity_auto"] = report
        metrics["fidelity_predicted_error"] = report["predicted_error"][fid]
    elif fid in ladder.LEVELS:
        res, metrics["fidelity_predicted_error"] = without_model(sc, b, fid)
    else:
        res = binding.simulate_scene(sc, b, fid)
    if "method_reason" in res.meta:  # the scene names no method: the default's choice
        extra["solver"] = {"method": res.meta["method"], "method_reason": res.meta["method_reason"]}
    found, left_out = transient_metrics(res)
    metrics.update(found)
    if left_out:
        extra["metrics_left_out"] = left_out
    return RunOutput(
        sc.name, fid, res.meta["method"], metrics=metrics, results={"main": res}, extra=extra
    )


def choose_fidelity(sc: Scenario, b: Binding) -> tuple[str, Result, dict]:
    """Bind the scene to the auto rule (:func:`sarcomere.dynamics.fidelity.choose`: full
    below :data:`~sarcomere.dynamics.fidelity.REDUCED_FROM_N` units, else the cheapest
    reduced level predicted within ``[outputs] tolerance``, default 1 %, of "full", over
    ``[outputs] signals``, default ``myofibril.length``) and run the chosen level alone.
    The choice reads no clock; the auto run's wall time is in the report."""
    tic = time.perf_counter()
    if sc.simulation is None:
        raise sc.error(("simulation",), "a transient needs [simulation] stop_time")
    grid = binding.time_grid(sc.simulation)
    first = "symmetric" if ladder.predicts(b.n) else "full"
    cheap = b.build(first)  # the first model the rule needs: inputs checked on it
    inputs = binding.scene_inputs(sc, cheap)
    binding.check_commands(sc, cheap, b.overrides, inputs, grid)
    care = list(sc.outputs.signals) or ["myofibril.length"]

    def build(level: str, groups: int = GROUPS) -> Model:  # the rule builds each once
        return cheap if (level, groups) == (first, GROUPS) else b.build(level, groups=groups)

    scene = ladder.Scene(
        n=b.n,
        build=build,
        inputs=inputs,
        t_out=grid,
        params=b.overrides,
        signals=care,
        named={*care, *(n for names in sc.outputs.plots.values() for n in names)},
        tolerance=sc.outputs.tolerance if sc.outputs.tolerance is not None else 0.01,
    )
    choice = ladder.choose(scene)
    res = binding.simulate_scene(sc, b, choice.level, choice.model, choice.start)
    res.require_finite(choice.level)
    report = choice.report(scene)
    report["wall_time_s"] = time.perf_counter() - tic
    return choice.level, res, report


#: Why a study on an auto scene runs full in every sample (its summary's "fidelity").
AUTO_WHY = (
    f"the auto rule runs full below n = {ladder.REDUCED_FROM_N} units, nothing predicted; "
    f"the factor n is kept below {ladder.REDUCED_FROM_N}"
)


def study_level(sc: Scenario, n: int) -> str:
    """The level of every sample of a study on a scene at ``fidelity = "auto"`` with n
    units: full below :data:`~sarcomere.dynamics.fidelity.REDUCED_FROM_N` (the rule,
    nothing predicted). From it auto predicts each run's level, which a study's samples
    cannot share: refused, saying what to write in the study file; so is a valve-supplied
    scene, whose auto picks the valve's level per scene."""
    if sc.model.options.get("supply") == "valve_pwm":
        raise sc.error(
            ("model", "fidelity"),
            "'auto' picks the valve's level from each run's predicted ripple; a study runs "
            'one level: set [model] fidelity = "full" and [model.options.valve] level',
        )
    if ladder.predicts(n):
        raise sc.error(
            ("model", "fidelity"),
            f"'auto' picks each run's level by prediction from n = {ladder.REDUCED_FROM_N} on "
            f"(n = {n}); a study runs one level: set it in the study file, [model] fidelity "
            '= "grouped" (or another level)',
        )
    return "full"


def without_model(sc: Scenario, b: Binding, level: str) -> tuple[Result, float]:
    """``linear`` or ``equilibrium_path`` on the full model: its equilibria along the
    command's range, the level, and its predicted error against full over ``[outputs]
    signals`` (default ``myofibril.length``; :func:`~sarcomere.dynamics.fidelity.run_level`)."""
    model = b.build("full")
    inputs, wanted, grid = binding.prepare(sc, b, model)
    if len(inputs) != 1:
        raise sc.error(("inputs",), f"level '{level}' needs one input, the pressure command")
    name, sig = next(iter(inputs.items()))
    nodes = ladder.LINEAR_PATH_NODES if level == "linear" else ladder.PATH_NODES
    path = ladder.equilibrium_path(model, name, sig(grid), b.overrides, nodes)
    care = list(sc.outputs.signals) or ["myofibril.length"]
    return ladder.run_level(level, model, path, inputs, grid, care, wanted)


register_runner("transient", run_transient)
