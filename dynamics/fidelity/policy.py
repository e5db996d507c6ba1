"""``fidelity = "auto"``: a deterministic rule on the chain length, the scene and the
predicted errors; nothing in it reads a clock, so a scene picks the same level on every
machine and under any load.

* ``n < REDUCED_FROM_N``: ``full``, nothing predicted. Below that length the
  predictions (three reduced models, their equilibrium paths and linearised responses:
  about 0.2 s of CPU whatever n) cost more than half of full's run, so no reduced level
  could pay 2x; and the two levels on the full model (``linear``, ``equilibrium_path``)
  cost 1.2-1.5x full end to end at n <= 6 and 3-17x beyond (BENCHMARKS.md s6).
* ``n >= REDUCED_FROM_N``: the first of :data:`AUTO_LADDER`, cheapest first, predicted
  within the tolerance; error: max over the scene's signals of ``max |y - y_full| /
  span(y_full)``, predicted (:mod:`.predictions`, before any nonlinear simulation) as

  - ``symmetric`` against ``grouped`` (what it drops: the weight gradient and the body
    inertia);
  - ``grouped`` (:data:`~sarcomere.dynamics.assemblies.GROUPS` groups) against grouped
    with one group fewer: the change when the groups grow, a convergence estimate that
    needs no full model (conservative while the error falls at least like
    ``groups^-1.7``; measured about ``groups^-2`` on steps);

  each ruled out at once by its static part alone where that exceeds the tolerance. A
  scene with more than one varying input, or a level without a signal the scene names,
  is predicted invalid: full.
"""

from __future__ import annotations

import re
from collections.abc import Callable, Mapping
from dataclasses import dataclass

import numpy as np

from ..assemblies import GROUPS
from ..components.chains import GroupedMyofibril, chain_end_names
from ..equilibrium import Equilibrium
from ..modeling.model import Model
from . import predictions
from .levels import Path, equilibrium_path
from .predictions import SAFETY

#: The levels of the report, cheapest first: the reduced chains (their cost does not grow
#: with n), the two levels on the full model (never predicted: they cost more than full,
#: module docstring), then full (docs/numerics.md, scene x level table).
AUTO_LADDER = ("symmetric", "grouped", "linear", "equilibrium_path", "full")

#: Shortest chain whose reduced levels auto predicts. The predictions cost about 0.2 s of
#: CPU whatever n: auto picking grouped against full, CPU time, one BLAS thread, medians
#: of 3 (the step-50g-n30-auto scene at other n): n = 10 x1.04, 15 x0.76, 20 x0.53,
#: 30 x0.38 (docs/numerics.md); from about 22 units full costs more than twice what the
#: predictions and the grouped run cost together, and 24 keeps a margin.
REDUCED_FROM_N = 24

#: Equilibria along the command's range when a reduced chain is compared with its
#: reference (statics on a cubic spline). The predictions of the step, ramp and slow
#: cycles at n = 10, 30, 60 are the same to 3 digits with 9 nodes: the largest static
#: difference sits at the range's ends, which are nodes.
REDUCED_PATH_NODES = 5

#: A signal of one unit of the full chain (the reduced chains have those of the ends).
_UNIT_SIGNAL = re.compile(r"^myofibril\.(aps|tube|actin)\d+\.")


def grouped_units(n: int, groups: int = GROUPS) -> int:
    """Representative units of the "grouped" level of an n-unit chain (its cost)."""
    return GroupedMyofibril.units(n, min(groups, n))


@dataclass
class Scene:
    """What the policy needs of a transient scene, SI.

    Attributes
    ----------
    n : int
        Units in the chain.
    build : callable
        ``build(level, groups=GROUPS) -> Model``: the scene's model at a flattened level.
    inputs : mapping
        Input name to signal (the ladder's predictions need exactly one).
    t_out : numpy.ndarray
        Output times [s].
    params : mapping
        Parameter overrides of the scene.
    signals : list of str
        The signals the error is measured on.
    named : set of str
        Every signal the scene names (outputs, plots): a level without one is ruled out.
    tolerance : float
        Allowed error, relative to each signal's span (0.01 = 1 %).
    """

    n: int
    build: Callable[..., Model]
    inputs: Mapping[str, object]
    t_out: np.ndarray
    params: Mapping[str, object]
    signals: list[str]
    named: set[str]
    tolerance: float


@dataclass
class Choice:
    """What :func:`choose` decided and what it built on the way: the caller runs
    ``model`` from ``start`` (an equilibrium of it already found, a continuation start;
    None if none)."""

    level: str
    predicted: dict[str, float | None]
    against: dict[str, str]
    why: dict[str, str]
    model: Model | None = None
    start: Equilibrium | None = None
    groups: int | None = None

    def report(self, scene: Scene) -> dict:
        """The ``extra.fidelity_auto`` of ``summary.json``."""
        out = {
            "chosen": self.level,
            "tolerance": scene.tolerance,
            "signals": scene.signals,
            "predicted_error": self.predicted,
            "predicted_against": self.against,
            "not_predicted": self.why,
            "safety_factor": SAFETY,
        }
        if self.groups is not None:
            out["groups"] = self.groups
        return out


class _Ladder:
    """The models, equilibrium paths and chain responses of one auto run, each built
    once."""

    def __init__(self, scene: Scene) -> None:
        self.scene = scene
        self.models: dict[tuple[str, int], Model] = {}
        self.paths: dict[tuple[str, int, int], Path] = {}
        self.responses: dict[tuple[str, int], predictions.ChainResponse] = {}

    def model(self, level: str, groups: int = GROUPS) -> Model:
        key = (level, groups if level == "grouped" else 0)
        if key not in self.models:
            self.models[key] = self.scene.build(level, groups=groups)
        return self.models[key]

    def path(self, level: str, nodes: int, groups: int = GROUPS) -> Path:
        key = (level, groups if level == "grouped" else 0, nodes)
        if key not in self.paths:
            sc = self.scene
            name, sig = next(iter(sc.inputs.items()))
            m, guess = self.model(level, groups), self.known(level, groups)
            found = [e for k, p in self.paths.items() if k[:2] == key[:2] for e in p.equilibria]
            self.paths[key] = equilibrium_path(
                m, name, sig(sc.t_out), sc.params, nodes, guess, found
            )
        return self.paths[key]

    def known(self, level: str, groups: int = GROUPS) -> Equilibrium | None:
        """An equilibrium of the model already found, at the scene's first input value
        where one is (a continuation start: long chains need seconds of settling to find
        their first one)."""
        key = (level, groups if level == "grouped" else 0)
        found = [e for k, p in self.paths.items() if k[:2] == key for e in p.equilibria]
        if not found:
            return None
        u0 = float(next(iter(self.scene.inputs.values()))(self.scene.t_out[0]))
        return min(found, key=lambda e: abs(e.u[0] - u0))

    def static_difference(self, level: str, ref_groups: int) -> float:
        """The static part of a reduced chain's prediction against grouped with
        ``ref_groups`` groups (:func:`~.predictions.static_difference`)."""
        sc = self.scene
        return predictions.static_difference(
            self.path(level, REDUCED_PATH_NODES),
            self.path("grouped", REDUCED_PATH_NODES, ref_groups),
            sc.inputs,
            sc.t_out,
            sc.signals,
        )

    def response(self, level: str, groups: int = GROUPS) -> predictions.ChainResponse:
        key = (level, groups if level == "grouped" else 0)
        if key not in self.responses:
            sc = self.scene
            path = self.path(level, REDUCED_PATH_NODES, groups)
            m = self.model(level, groups)
            self.responses[key] = predictions.chain_response(
                m, path, sc.inputs, sc.t_out, sc.signals
            )
        return self.responses[key]


def _ruled_out(scene: Scene) -> dict[str, str]:
    """Levels ruled out by the scene's shape alone (the rule on n), with the reason."""
    n = scene.n
    why = dict.fromkeys(
        ("linear", "equilibrium_path"),
        f"not cheaper at n = {n}: the full model's equilibria, exact Jacobians and matrix "
        "exponentials cost more than its run (3x at n = 10, 17x at n = 30)",
    )
    if grouped_units(n) == n:
        reason = (
            f"not cheaper at n = {n}: grouped has {grouped_units(n)} representative units, "
            "and a prediction against full costs more than it saves"
        )
    elif n < REDUCED_FROM_N:
        reason = (
            f"not predicted at n = {n} < {REDUCED_FROM_N}: the predictions cost about what "
            "half of full's run does, so no reduced level could pay"
        )
    else:
        reason = ""
    unit_signals = sorted(
        s
        for s in scene.named
        if _UNIT_SIGNAL.match(s) and s.removeprefix("myofibril.") not in chain_end_names(n)
    )
    if not reason and unit_signals:  # known without building them
        reason = f"has no signal {unit_signals} (it names the chain ends only)"
    if not reason and len(scene.inputs) != 1:
        reason = "its prediction needs the pressure command as only input"
    if reason:
        why.update(symmetric=reason, grouped=reason)
    return why


def predicts(n: int) -> bool:
    """Whether auto predicts the reduced levels of an n-unit chain (:data:`REDUCED_FROM_N`;
    below it runs full, nothing predicted)."""
    return n >= REDUCED_FROM_N


def choose(scene: Scene) -> Choice:
    """The first level of :data:`AUTO_LADDER` predicted within ``scene.tolerance``
    (module docstring): a rule on ``scene.n``, the scene and the predictions, the same
    on every machine."""
    tol, sc = scene.tolerance, scene
    run = _Ladder(scene)
    why = _ruled_out(scene)
    predicted: dict[str, float] = {}
    against: dict[str, str] = {}
    for level in ("symmetric", "grouped"):  # cheapest first; the first within tol runs
        if level in why:
            continue
        lacking = sorted(s for s in sc.named if s not in run.model(level).signal_names)
        if lacking:
            why[level] = f"has no signal {lacking}"
            continue
        ref = GROUPS - 1 if level == "grouped" else GROUPS
        against[level] = f"grouped ({ref} groups)"
        predicted[level] = run.static_difference(level, ref)
        if predicted[level] > tol:  # a lower bound already beyond: no linearisation
            against[level] += ", static part alone"
        else:
            predicted[level] = predictions.predict_reduced(
                run.response(level), run.response("grouped", ref)
            )
        if predicted[level] <= tol:
            return Choice(
                level,
                _all(predicted),
                against,
                why,
                run.model(level),
                run.known(level),
                groups=GROUPS if level == "grouped" else None,
            )
    predicted["full"] = 0.0
    return Choice("full", _all(predicted), against, why, run.model("full"), run.known("full"))


def _all(predicted: dict[str, float]) -> dict[str, float | None]:
    return {f: predicted.get(f) for f in AUTO_LADDER}
