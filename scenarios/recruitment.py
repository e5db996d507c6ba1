"""Scenario kind "recruitment": a bundle of fibres on the isometric fixture
(``[model] name = "bundle"``, ``setup = "isometric"``) grading its force two ways.

- **Recruitment**: the fibres are recruited one by one, each stepped from 0 to the
  recruitment pressure, the last value of ``[sweep.pressure]`` (Pa);
- **pressure alone**: every fibre at one pressure, swept over ``[sweep.pressure]``; the
  pressures that give the recruitment's force levels are found on these equilibria
  (bracketing), and the same force staircase is then driven by pressure alone.

Both staircases run as transients (``[simulation] stop_time``: the dwell of each level),
from the bundle at rest at 0 Pa. Results: the equilibrium force against pressure (all
fibres) and against the number recruited; the two transients' force; metrics: the
force per level, the largest deviation of the recruitment's levels from equal steps, and
the mean 10-90 % rise time of a level under each strategy.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from scipy.optimize import brentq

from sarcomere.dynamics.equilibrium import solve_equilibrium
from sarcomere.dynamics.results import Result
from sarcomere.dynamics.signals import Staircase, Step

from .binding import bind, command_range, run, solver_settings
from .output import RunOutput
from .plots import plot_groups
from .runner import register_runner
from .spec import Scenario
from .step_metrics import rise_time

POINTS_PER_LEVEL = 200
"""Output points per level of a staircase transient."""


def _force(model, u: dict, over: dict, guess=None):
    return solve_equilibrium(model, u, over, guess=guess)


def _rises(t, f, dwell: float, levels: int) -> list[float]:
    """10-90 % rise time of each level of a staircase of ``dwell`` [s]."""
    out = []
    for j in range(1, levels + 1):
        sel = (t >= j * dwell) & (t <= (j + 1) * dwell)
        rise, why = rise_time(t[sel] - j * dwell, f[sel], 1e-6, "N")
        if rise is None:
            raise ValueError(why)  # the grid is POINTS_PER_LEVEL per level: resolved
        out.append(rise)
    return out


def run_recruitment(sc: Scenario, out_dir: Path) -> RunOutput:
    """Force grading by recruitment against grading by pressure (module docstring)."""
    sc.refuse_unused("inputs", "outputs.tolerance", "control", "cosim")
    b = bind(sc)
    if b.setup != "bundle-isometric":
        raise sc.error(
            ("model",), "kind 'recruitment' needs [model] name = 'bundle' on setup 'isometric'"
        )
    b.require_regulators("recruitment")
    if [a.name for a in sc.sweep] != ["pressure"]:
        raise sc.error(("sweep",), "give [sweep.pressure] alone")
    if sc.simulation is None:
        raise sc.error(("simulation",), "the staircases need [simulation] stop_time (a dwell)")
    pressures = np.asarray(sc.sweep[0].values)
    model = b.build(sc.model.fidelity)
    over, names = dict(b.overrides), b.inputs
    k = len(names)
    for name in names:
        rng = command_range(model, over, name)
        bad = pressures[(pressures < rng[0]) | (pressures > rng[1])]
        if bad.size:
            raise sc.error(("sweep", "pressure"), f"{bad[0] / 1e6:g} MPa is outside {rng} Pa")
    p_rec = float(pressures[-1])
    rest = _force(model, {}, over)
    grading, guess = [], rest
    for p in pressures:
        guess = _force(model, dict.fromkeys(names, float(p)), over, guess)
        grading.append(guess["sensor.f"])
    recruited, guess = [rest["sensor.f"]], rest
    for j in range(1, k + 1):
        guess = _force(
            model, {n: p_rec if i < j else 0.0 for i, n in enumerate(names)}, over, guess
        )
        recruited.append(guess["sensor.f"])
    recruited = np.array(recruited)

    def all_at(p: float) -> float:
        return _force(model, dict.fromkeys(names, p), over, rest)["sensor.f"]

    matched = [brentq(lambda p, f=f: all_at(p) - f, 0.0, p_rec, xtol=1.0) for f in recruited[1:-1]]
    matched.append(p_rec)
    dwell = sc.simulation.stop_time
    # a dwell at rest, then one level per dwell
    t_out = np.linspace(0.0, (k + 1) * dwell, (k + 1) * POINTS_PER_LEVEL + 1)
    settings = solver_settings(sc, model)
    recruit_in = {
        n: Step(final=p_rec, time=(i + 1) * dwell, unit="Pa") for i, n in enumerate(names)
    }
    levels = (0.0, *matched)
    pressure_in = {n: Staircase(levels=levels, dwell=dwell, unit="Pa") for n in names}
    runs = {}
    for key, inputs in (("recruitment", recruit_in), ("pressure", pressure_in)):
        res = run(model, inputs, over, t_out, settings, ["sensor.f"])
        runs[key] = res["sensor.f"]
    rises = {key: _rises(t_out, f, dwell, k) for key, f in runs.items()}
    steps = np.diff(recruited)
    grading_curve = Result(
        "pressure",
        "Pa",
        pressures,
        {"force_all_fibres": np.array(grading)},
        {"force_all_fibres": "N"},
    )
    plot_groups({"equilibria": grading_curve}, {"grading": ("force_all_fibres",)}, out_dir, sc.name)
    results = {
        "staircases": Result(
            "time",
            "s",
            t_out,
            {"force_recruitment": runs["recruitment"], "force_pressure": runs["pressure"]},
            {"force_recruitment": "N", "force_pressure": "N"},
        ),
    }
    metrics = {
        "fibres": float(k),
        "force_all_recruited_N": float(recruited[-1]),
        "force_first_fibre_N": float(recruited[1]),
        "recruitment_step_spread_ratio": float(np.ptp(steps) / np.mean(steps)),
        "rise_recruitment_mean_s": float(np.mean(rises["recruitment"])),
        "rise_pressure_mean_s": float(np.mean(rises["pressure"])),
        "pressure_for_first_fibre_force_MPa": matched[0] / 1e6,
    }
    extra = {
        "setup": b.setup,
        "pressure_Pa": pressures.tolist(),
        "force_all_fibres_N": [float(f) for f in grading],
        "recruited_force_N": recruited.tolist(),
        "matched_pressure_Pa": [float(p) for p in matched],
        "rise_recruitment_s": rises["recruitment"],
        "rise_pressure_s": rises["pressure"],
    }
    return RunOutput(
        sc.name,
        sc.model.fidelity,
        f"{settings.method}; damped Newton for the equilibria",
        metrics=metrics,
        results=results,
        extra=extra,
    )


register_runner("recruitment", run_recruitment)
