"""``[design]``: candidate experiments for the next measurement, ranked at the estimate
(:func:`sarcomere.dynamics.identification.design.rank`).

Each candidate is the first fitted time series' set-up (its ``[model]``) with the hanging
load of ``loads`` and an input of ``kinds`` to a level of ``levels``: ``step`` (0 to the
level at 10 % of ``duration``) or ``staircase`` (four equal steps up to the level, at 10,
30, 50 and 70 %), sampled every ``sample``, measuring ``outputs`` (default: the signals
the fitted time series measure) with their fit-file noise.
"""

from __future__ import annotations

import copy

import numpy as np

from sarcomere.dynamics.identification.design import rank
from sarcomere.dynamics.identification.experiments import TimeSeries
from sarcomere.dynamics.identification.problem import Problem

from .build import Built, model_of, place


def _input(kind: str, level: float, t: np.ndarray) -> np.ndarray:
    T = t[-1]
    if kind == "step":
        return np.where(t < 0.1 * T, 0.0, level)
    steps = sum(np.where(t < f * T, 0.0, level / 4) for f in (0.1, 0.3, 0.5, 0.7))
    return np.asarray(steps, dtype=float)


def candidates(built: Built) -> list[tuple[str, Problem]]:
    """The candidate problems of ``built.spec.design`` (empty without ``[design]``)."""
    d = built.spec.design
    series = [
        b for b in built.experiments if b.spec.kind == "time-series" and not b.spec.validation
    ]
    if d is None or not series:
        return []
    base = series[0]
    outputs = list(d.outputs or dict.fromkeys(s for b in series for s in b.spec.outputs))
    t = np.arange(0.0, d.duration + d.sample / 2, d.sample)
    out = []
    for load in d.loads:
        tbl = copy.deepcopy(base.spec.model)
        if base.binding.setup == "hanging":
            tbl.setdefault("options", {})["load"] = f"{load} kg"
        binding, model = model_of(built.spec, base.spec, tbl)
        uses = place(built, binding, model, base)
        p = model.parameters(binding.overrides)
        for kind in d.kinds:
            for level in d.levels:
                name = f"{kind} to {level / 1e3:g} kPa, {1e3 * load:g} g"
                u = np.tile(model.u0(p), (len(t), 1))
                u[:, model.input_names.index("regulator.p_cmd")] = _input(kind, level, t)
                data = np.zeros((len(t), len(outputs)))
                ts = TimeSeries(name, model, t, u, outputs, data, p, uses, built.spec.interval)
                noise = {s: built.problem.noise[s] for s in outputs}
                out.append((name, Problem(built.params, [ts], noise=noise)))
    return out


def ranking(built: Built, solution, sigma: dict[str, float]) -> list[dict]:
    """The candidates of ``[design]`` ranked by D-optimality gain (empty without it)."""
    cands = candidates(built)
    return rank(built.problem, solution, cands, sigma) if cands else []
