"""A myofibril scene on the PWM valve supply (issue 26): ``[model.options] supply`` and
``valve`` checked (:func:`supply_options`), and the valve's level under ``fidelity =
"auto"`` (:func:`valve_auto`).

``supply = "valve_pwm"`` puts the chain on a PWM-driven on/off valve
(:func:`~sarcomere.dynamics.supply.add_supply`); its command is the duty cycle
``valve.cmd`` [1]. ``valve`` holds :class:`~sarcomere.dynamics.supply.ValveOptions`
fields with their units. Only the kinds of :data:`VALVE_KINDS` read it: the others
command the regulator's pressure and refuse it.

``fidelity = "auto"`` on a valve-supplied chain: the chain runs ``full`` (the chain's
rule below :data:`~sarcomere.dynamics.fidelity.REDUCED_FROM_N` units; from there it is
refused: the reduced chains' predictions read a pressure command) and the valve's level
is the one :func:`~sarcomere.dynamics.fidelity.ripple.choose_level` picks at every duty
the scene holds: ``averaged`` where the averaged valve's predicted error is within
``[outputs] tolerance`` (default 1 %) of each ``[outputs] signals``' span (default
``myofibril.length``) at each of them, else ``switched``. Deterministic (no clock); the
reason is ``summary.json`` ``extra.fidelity_auto.valve``.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from sarcomere.dynamics import fidelity as ladder
from sarcomere.dynamics.errors import ParameterError
from sarcomere.dynamics.fidelity.ripple import choose_level
from sarcomere.dynamics.results import Result
from sarcomere.dynamics.supply import SUPPLIES, UNITS, ValveOptions
from sarcomere.dynamics.units import to_si

from .spec import Scenario, describe

VALVE_KINDS = ("transient",)
"""Kinds that read ``supply = "valve_pwm"`` (the others command a pressure)."""

DUTY = "valve.cmd"
"""The valve supply's command, the duty cycle [1]."""


def supply_options(sc: Scenario, opts: dict, p_max: float | None) -> dict:
    """``supply`` and ``valve`` popped from the checked ``[model.options]`` ``opts``:
    ``{"supply": ..., "valve": ValveOptions or None}``; refused where unused."""
    path = ("model", "options")
    supply = opts.pop("supply", "regulator")
    raw = opts.pop("valve", None)
    if supply not in SUPPLIES:
        raise sc.error((*path, "supply"), f"{supply!r}: use one of {', '.join(SUPPLIES)}")
    if supply == "regulator":
        if raw is not None:
            raise sc.error((*path, "valve"), "valve options need supply = 'valve_pwm'")
        return {"supply": supply, "valve": None}
    if sc.kind not in VALVE_KINDS:
        raise sc.error(
            (*path, "supply"),
            f"kind '{sc.kind}' commands the regulator's pressure; supply = 'valve_pwm' (the "
            f"duty cycle {DUTY}) is read by kind {' and '.join(VALVE_KINDS)} (kind "
            "'pwm_hold' builds its own valve plant)",
        )
    if "regulator_tau" in opts:
        raise sc.error((*path, "regulator_tau"), "there is no regulator with supply = 'valve_pwm'")
    if p_max is not None:
        raise sc.parameter_error("regulator.p_max", "there is no regulator with 'valve_pwm'")
    if not isinstance(raw, dict | None):
        raise sc.error((*path, "valve"), f"{raw!r}: expected a table of valve options")
    raw = dict(raw or {})
    if "level" in raw and sc.model.fidelity == "auto":
        raise sc.error((*path, "valve", "level"), "fidelity = 'auto' picks the valve's level")
    try:
        valve = ValveOptions.from_mapping(raw)
        for key, value in raw.items():  # dimensioned values need their unit
            if UNITS[key] not in (None, "1"):
                to_si(value, UNITS[key], f"valve.{key}", bare_ok=False)
    except ParameterError as exc:
        raise sc.error((*path, "valve"), describe(exc)) from None
    return {"supply": supply, "valve": valve}


def check_level(sc: Scenario, b, fid: str) -> None:
    """Refuse the levels without a model of their own on a valve supply (their
    equilibrium path reads a pressure command, not a PWM duty)."""
    if getattr(b, "supply", "regulator") == "valve_pwm" and fid in ladder.LEVELS:
        raise sc.error(
            ("model", "fidelity"),
            f"'{fid}' follows the equilibria of a pressure command; with supply = "
            "'valve_pwm' use a dynamic level (full, ...) or 'auto'",
        )


def valve_auto(sc: Scenario, b, prepare, simulate) -> tuple[str, Result, dict]:
    """The level, the run and the report of ``fidelity = "auto"`` on a valve-supplied
    chain (module docstring); ``prepare(sc, b, model)`` and ``simulate(sc, b, level,
    model)`` are the binding's (:func:`.binding.prepare`, :func:`.binding.simulate_scene`)."""
    if ladder.predicts(b.n):
        raise sc.error(
            ("model", "fidelity"),
            f"'auto' on supply = 'valve_pwm' picks the valve's level on the full chain, "
            f"below n = {ladder.REDUCED_FROM_N} units (n = {b.n}); set a level",
        )
    switched = b.build("full")
    inputs, _, grid = prepare(sc, b, switched)
    if DUTY not in inputs:
        raise sc.error(("inputs",), f"'auto' on supply = 'valve_pwm' needs [inputs.\"{DUTY}\"]")
    sig = inputs[DUTY]
    times = np.concatenate([grid, sig.breakpoints(grid[0], grid[-1])])
    duties = np.unique(np.asarray(sig(times), dtype=float) * np.ones_like(times))
    tol = sc.outputs.tolerance if sc.outputs.tolerance is not None else 0.01
    care = list(sc.outputs.signals) or ["myofibril.length"]
    choices = {}
    for d in duties:
        try:
            choices[f"{d:g}"] = choose_level(switched, float(d), care, tol, b.overrides)
        except ParameterError as exc:
            raise sc.error(("inputs", DUTY), describe(exc)) from None
    worst = max(choices, key=lambda k: max(choices[k].prediction.relative().values()))
    level = "averaged" if all(c.level == "averaged" for c in choices.values()) else "switched"
    why = (
        f"{level}: at the held duty {worst} (the worst of {len(choices)}) the {choices[worst].why}"
    )
    if level == "averaged":
        b = dataclasses.replace(b, valve=dataclasses.replace(b.valve, level="averaged"))
        res = simulate(sc, b, "full", b.build("full"))
    else:
        res = simulate(sc, b, "full", switched)
    worst_error = max(choices[worst].prediction.relative().values())
    report = {
        "chosen": "full",
        "why": f"the chain: full below n = {ladder.REDUCED_FROM_N} units, nothing predicted",
        "valve": {
            "chosen": level,
            "tolerance": tol,
            "why": why,
            "predicted_relative_error": float(worst_error),
            "duties": {k: c.report() for k, c in choices.items()},
        },
    }
    return "full", res, report


__all__ = ["DUTY", "VALVE_KINDS", "check_level", "supply_options", "valve_auto"]
