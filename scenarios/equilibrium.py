"""Scenario kind "equilibrium": pressure sweeps of the dynamic model's equilibria, one
curve per value of a second axis (``n`` or ``load``); the scene is bound by
:mod:`.binding` (``[model]``, ``[parameters]``)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from sarcomere.dynamics.equilibrium import solve_equilibrium
from sarcomere.dynamics.errors import ParameterError
from sarcomere.dynamics.modeling.model import Model
from sarcomere.dynamics.plausibility import implausible_load
from sarcomere.dynamics.results import Result

from .binding import (
    P_CMD,
    Binding,
    aps_dict,
    bind,
    check_n,
    check_output_size,
    command_range,
    fidelity_level,
    range_error,
)
from .output import RunOutput, quantity_tag
from .runner import register_runner
from .spec import Scenario, describe


def _solve(sc: Scenario, model: Model, pressure: float, over: dict, guess):
    try:
        return solve_equilibrium(model, {P_CMD: pressure}, over, guess=guess)
    except ParameterError as exc:
        raise sc.parameter_error(exc.name, describe(exc)) from None


def run_equilibrium(sc: Scenario, out_dir: Path) -> RunOutput:
    """Sweep pressure (first axis) for each value of the other axes (``n`` or ``load``).

    Isometric: the tared force ``force`` = F(P) - F(0) [N]. Hanging: ``length`` [m],
    ``length_ratio`` = L / L' with L' = L(0 MPa, no load, same n) and the paper's
    actuation strain ``strain`` = (L[P, load] - L[0, load]) / L[0, 0].
    """
    sc.refuse_unused("inputs", "simulation", "solver", "outputs.tolerance", "control", "cosim")
    b = bind(sc)
    fid = fidelity_level(sc, allow_auto=False)
    check_n(sc, ("model", "n"), b.n, fid)
    if not sc.sweep or sc.sweep[0].name != "pressure":
        raise sc.error(("sweep",), "the first sweep axis must be 'pressure'")
    pressures = np.asarray(sc.sweep[0].values)
    others = sc.sweep[1:]
    if len(others) > 1 or (others and others[0].name not in ("n", "load")):
        raise sc.error(("sweep",), "at most one more axis, 'n' or 'load'")
    axis = others[0] if others else None
    swept = axis.name if axis else None
    if swept == "n":
        if ("model", "n") in sc.key_lines or sc.model.n != 1:
            raise sc.error(("model", "n"), "[sweep.n] sets n; remove it")
        for v in axis.values:
            check_n(sc, ("sweep", "n", "values"), v, fid)
    if swept == "load" and b.setup == "isometric":
        raise sc.error(("sweep", "load"), "the isometric set-up holds no load; sweep 'n' instead")
    if swept == "load" and "load" in sc.model.options:
        raise sc.error(("model", "options", "load"), "[sweep.load] sets the load; remove it")
    if swept == "load" and "load.m" in b.overrides:
        raise sc.parameter_error("load.m", "[sweep.load] sets the load; remove it")
    if swept == "load" and min(axis.values) < 0:
        bad = min(axis.values)
        raise sc.error(("sweep", "load", "values"), f"{bad * 1e3:g} g: a load is >= 0 kg")
    if swept == "load" and (why := implausible_load(max(axis.values))):
        sc.warn(("sweep", "load"), why)
    cases = axis.values if axis else (None,)
    check_output_size(sc, len(pressures) * len(cases), 5, ("sweep", "pressure"))
    results, metrics = {}, {}
    for value in cases:
        n = round(value) if swept == "n" else b.n
        load = value if swept == "load" else b.load_kg
        prefix = f"n{n}_" if swept == "n" else ""
        key, res, mets = _equilibrium_case(sc, b, fid, pressures, n, load, prefix)
        results[key] = res
        metrics.update(mets)
    return RunOutput(
        sc.name,
        fid,
        "damped Newton on the exact sparse Jacobian, continuation",
        metrics=metrics,
        results=results,
        extra={"aps_params": aps_dict(b.aps), "setup": b.setup},
    )


def _equilibrium_case(sc, b: Binding, fid, pressures, n, load, prefix=""):
    """One curve against pressure; ``prefix`` (``"n2_"``) names the swept n in its key
    and metrics when n is an axis."""
    model = b.build(fid, n)
    over = dict(b.overrides)
    rng = command_range(model, over)
    for p in pressures:
        if not rng[0] <= p <= rng[1]:
            raise range_error(sc, ("sweep", "pressure"), float(p), rng)
    unloaded = dict(over)
    if b.setup == "hanging":  # the end mass without the scene's load, then with this case's
        unloaded["load.m"] = model.variables["load.m"].value - b.load_kg
        over["load.m"] = unloaded["load.m"] + load
    rest = _solve(sc, model, 0.0, unloaded, None)
    base = _solve(sc, model, 0.0, over, rest)
    rows, guess = [], base
    for p in pressures:
        guess = _solve(sc, model, float(p), over, guess)
        rows.append(guess)
    chamber = np.array([e["myofibril.aps1.chamber.p_gauge"] for e in rows])
    tag_p = quantity_tag(pressures[-1] / 1e6, "MPa")
    if b.setup == "isometric":
        force = np.array([e["sensor.f"] for e in rows]) - base["sensor.f"]
        key = f"n{n}"
        res = Result(
            "pressure",
            "Pa",
            pressures,
            {"force": force, "chamber_pressure": chamber},
            {"force": "N", "chamber_pressure": "Pa"},
        )
        return key, res, {f"force_n{n}_{tag_p}_N": float(force[-1])}
    L = np.array([e["myofibril.length"] for e in rows])
    L00, L0 = rest["myofibril.length"], base["myofibril.length"]
    grams = quantity_tag(load * 1e3, "g")
    res = Result(
        "pressure",
        "Pa",
        pressures,
        {
            "length": L,
            "length_ratio": L / L00,
            "strain": (L - L0) / L00,
            "chamber_pressure": chamber,
        },
        {"length": "m", "length_ratio": "1", "strain": "1", "chamber_pressure": "Pa"},
    )
    mets = {
        f"rest_length_n{n}_mm": L00 * 1e3,
        f"length_ratio_{prefix}{grams}_0MPa": L0 / L00,
        f"length_ratio_{prefix}{grams}_{tag_p}": float(L[-1] / L00),
        f"strain_{prefix}{grams}_{tag_p}": float((L[-1] - L0) / L00),
    }
    return f"{prefix}load_{grams}", res, mets


register_runner("equilibrium", run_equilibrium)
