"""``fidelity = "auto"``: the cheapest level predicted within a tolerance of ``full``.

:func:`choose` predicts each level's error from the scene (:mod:`.predictions`, before
any nonlinear simulation) and stops at the first of :data:`AUTO_LADDER`, cheapest first,
predicted within the tolerance. Error: max over the scene's signals of
``max |y - y_full| / span(y_full)``. Predictions, each built only when the cheaper levels
are ruled out:

* ``symmetric`` against ``grouped`` (what it drops: the weight gradient and the body
  inertia);
* ``grouped`` (:data:`~sarcomere.dynamics.assemblies.GROUPS` groups) against grouped
  with one group fewer: the change when the groups grow, a convergence estimate that
  needs no full model (conservative while the error falls at least like
  ``groups^-1.7``; measured about ``groups^-2`` on steps);
* ``linear`` and ``equilibrium_path`` by their defect on the full model
  (:func:`~.predictions.predict_linear`, :func:`~.predictions.predict_path`), ruled out
  at once when the static nonlinearity (linear), or the command's jumps or the
  deviation from a coarse path times it (the path), exceed the tolerance: early exits
  that only ever rule a level out, so they never make auto's error larger.

Full first, where the ladder would predict levels on the full model (n <= 2 GROUPS):
the full run starts before any prediction, in pieces, and if it finishes within
:data:`FULL_FIRST_BUDGET_S` of integration it is the answer (error 0: full is cheaper
than predicting); otherwise it pauses, the ladder predicts, and if the ladder ends at
full the paused run goes on where it stopped (nothing integrated twice).

The reduced chains are considered only where grouped has fewer representative units
than the chain (n > 2 GROUPS), the two levels on the full model only where it does not:
beyond, their equilibria, Jacobians and matrix exponentials of the full model cost more
than running it (3x at n = 10, 17x at n = 30). A scene with more than one varying input,
or a level without a signal the scene names, is predicted invalid. The predictions
depend on the scene alone; only whether full finished within its budget depends on the
machine, and full is exact whichever way it goes.
"""

from __future__ import annotations

import re
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field

import numpy as np

from ..assemblies import GROUPS
from ..components.chains import GroupedMyofibril, chain_end_names
from ..equilibrium import Equilibrium
from ..modeling.model import Model
from ..results import Result
from ..simulation.simulate import PausableRun
from . import predictions
from .levels import PATH_NODES, Path, equilibrium_path, level_result, trajectory
from .predictions import SAFETY

#: The levels "auto" considers, cheapest first: the reduced chains (their cost does not
#: grow with n), the two levels on the full model that integrate nothing, then full
#: (docs/numerics.md, scene x level table).
AUTO_LADDER = ("symmetric", "grouped", "linear", "equilibrium_path", "full")

#: Equilibria along the command's range when a reduced chain is compared with its
#: reference (statics on a cubic spline; the equilibrium path level uses
#: :data:`~.levels.PATH_NODES`). The predictions of the step, ramp and slow cycles at
#: n = 10, 30, 60 are the same to 3 digits with 9 nodes: the largest static difference
#: sits at the range's ends, which are nodes.
REDUCED_PATH_NODES = 5

#: Equilibria along the command's range for the ``linear`` level's prediction (the static
#: nonlinearity over the range) and its operating point (the middle one).
LINEAR_PATH_NODES = 3

#: Integration wall time [s] the full run may take before the ladder predicts (n <= 2
#: GROUPS). Measured (BENCHMARKS.md s6, one BLAS thread): the packaged n = 3 scenes
#: integrate full in 7-65 ms, up to ~3x that on the loaded 2-core machine, while the
#: ladder's predictions there cost 10-30 ms and its levels 10-100 ms more; so a full run
#: within 0.2 s is never beaten by more than the predictions' cost, and one beyond it has
#: predictions costing under 15 % of it.
FULL_FIRST_BUDGET_S = 0.2  # 0: no full first, the ladder predicts at once

#: A paused full run whose rest, extrapolated from its pace so far (wall time / share
#: run), is at most this long [s] is finished instead of predicting: at n <= 6 the
#: ladder's levels cost about as much per output point as full (BENCHMARKS.md s6), so
#: dropping the paused work only adds it to the bill (a 150 s dither at n = 3: full
#: 0.60 s, pause at 0.2 s, then linear: x1.56 of full).
FULL_FIRST_FINISH_S = 1.0  # 0: a paused full run always goes to the ladder

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
    keep : list of str
        The signals a level without an integrator returns.
    tolerance : float
        Allowed error, relative to each signal's span (0.01 = 1 %).
    full : PausableRun, optional
        The full model's run from the start equilibrium, not yet started (n <= 2 GROUPS:
        "full first"); None to predict at once.
    """

    n: int
    build: Callable[..., Model]
    inputs: Mapping[str, object]
    t_out: np.ndarray
    params: Mapping[str, object]
    signals: list[str]
    named: set[str]
    keep: list[str]
    tolerance: float
    full: PausableRun | None = None


@dataclass
class Choice:
    """What :func:`choose` decided and what it built on the way.

    ``result`` holds the output of ``linear`` or ``equilibrium_path`` (computed while
    predicting it); for a flattened level the caller runs ``model`` from ``start`` (an
    equilibrium of it already found, a continuation start; None if none)."""

    level: str
    predicted: dict[str, float | None]
    against: dict[str, str]
    why: dict[str, str]
    model: Model | None = None
    start: Equilibrium | None = None
    result: Result | None = None
    groups: int | None = None
    notes: dict = field(default_factory=dict)

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
        out.update(self.notes)
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
        sc = self.scene
        u0 = float(next(iter(sc.inputs.values()))(sc.t_out[0]))
        found = [e for k, p in self.paths.items() if k[:2] == key for e in p.equilibria]
        return min(found, key=lambda e: abs(e.u[0] - u0), default=None)

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


def _ruled_out(scene: Scene, reduces: bool) -> dict[str, str]:
    """Levels ruled out by the scene's shape alone, with the reason."""
    why = {}
    n = scene.n
    if not reduces:
        for level in ("symmetric", "grouped"):
            why[level] = (
                f"not cheaper at n = {n}: grouped has {grouped_units(n)} representative "
                "units, and a prediction against full costs more than it saves"
            )
    else:
        for level in ("linear", "equilibrium_path"):
            why[level] = (
                f"not cheaper at n = {n}: the full model's equilibria, exact Jacobians and "
                "matrix exponentials cost more than its run (3x at n = 10, 17x at n = 30)"
            )
    unit_signals = sorted(
        s
        for s in scene.named
        if _UNIT_SIGNAL.match(s) and s.removeprefix("myofibril.") not in chain_end_names(n)
    )
    if reduces and unit_signals:  # known without building them
        for level in ("symmetric", "grouped"):
            why[level] = f"has no signal {unit_signals} (it names the chain ends only)"
    if len(scene.inputs) != 1:
        for level in AUTO_LADDER[:-1]:
            why[level] = "its prediction needs the pressure command as only input"
    return why


def choose(scene: Scene) -> Choice:
    """The cheapest level of :data:`AUTO_LADDER` predicted within ``scene.tolerance``
    (module docstring); a level without an integrator is also run here (its result is
    what its prediction is computed from)."""
    tol, sc = scene.tolerance, scene
    reduces = grouped_units(sc.n) < sc.n
    paused = {}
    if not reduces and sc.full is not None and FULL_FIRST_BUDGET_S > 0:
        first = _full_first(sc.full)
        if first.level == "full":
            return first
        paused = first.notes
    run = _Ladder(scene)
    why = _ruled_out(scene, reduces)
    predicted: dict[str, float] = {}
    against: dict[str, str] = {}
    static = None
    for level in AUTO_LADDER[:-1]:  # cheapest first; stop at the first predicted within tol
        if level in why:
            continue
        if level in ("symmetric", "grouped"):
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
            continue
        full = run.model("full")
        nodes = LINEAR_PATH_NODES if level == "linear" else PATH_NODES
        if static is None:
            path5 = run.path("full", LINEAR_PATH_NODES)
            static = predictions.static_nonlinearity(full, path5, sc.inputs, sc.t_out, sc.signals)
        against[level] = "full"
        if level == "linear":
            early = SAFETY * float(np.max(static))
            what = "static nonlinearity alone"
        else:
            path5 = run.path("full", LINEAR_PATH_NODES)
            early = SAFETY * predictions.path_jump_bound(
                path5, sc.inputs, sc.t_out, sc.signals, static
            )
            what = "the command's jumps times the static nonlinearity"
            if early <= tol:
                early = SAFETY * predictions.path_deviation_bound(
                    full, path5, sc.inputs, sc.t_out, sc.signals, static
                )
                what = "the deviation from the path times the static nonlinearity"
        if early > tol:
            against[level] += f" ({what})"
            predicted[level] = early
            continue
        path = run.path("full", nodes)
        traj = trajectory(level, full, path, sc.inputs, sc.t_out)
        defect = predictions.level_defect(level, full, path, sc.inputs, sc.t_out, sc.signals, traj)
        predicted[level] = SAFETY * max(defect, float(np.max(static)) if level == "linear" else 0)
        if predicted[level] <= tol:
            res = level_result(level, full, path, traj, sc.t_out, sc.keep)
            return Choice(level, _all(predicted), against, why, full, result=res, notes=paused)
    predicted["full"] = 0.0
    res = sc.full.result() if paused else None  # paused by full first: go on from there
    return Choice(
        "full",
        _all(predicted),
        against,
        why,
        run.model("full"),
        run.known("full"),
        res,
        notes=paused,
    )


def _full_first(full: PausableRun) -> Choice:
    """Run ``full`` for :data:`FULL_FIRST_BUDGET_S`: level "full" with its result if it
    finished, else level "" (paused; the ladder predicts)."""
    done = full.run(FULL_FIRST_BUDGET_S)
    note = {
        "budget_s": FULL_FIRST_BUDGET_S,
        "wall_s": full.wall_s,
        "finished": done,
        "fraction_run": full.fraction,
    }
    reason = f"it ran in {full.wall_s:.3g} s, within the {FULL_FIRST_BUDGET_S:g} s budget"
    if not done:
        rest = full.wall_s * (1.0 - full.fraction) / max(full.fraction, 1e-12)
        note["extrapolated_rest_s"] = rest
        if rest > FULL_FIRST_FINISH_S:
            return Choice("", {}, {}, {}, notes={"full_first": note})
        full.run()  # a short rest: finishing costs less than predicting
        note["finished_after_pause"] = True
        reason = (
            f"paused at {note['wall_s']:.3g} s with {note['fraction_run']:.0%} run, its "
            f"rest extrapolated to {rest:.3g} s (<= {FULL_FIRST_FINISH_S:g} s): finished"
        )
    why = {level: f"full is cheaper than predicting: {reason}" for level in AUTO_LADDER[:-1]}
    predicted = {"full": 0.0}
    return Choice(
        "full", _all(predicted), {}, why, result=full.result(), notes={"full_first": note}
    )


def _all(predicted: dict[str, float]) -> dict[str, float | None]:
    return {f: predicted.get(f) for f in AUTO_LADDER}
