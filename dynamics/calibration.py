"""Calibration of the unmeasured effective APS parameters against the paper's experiments.

Targets (paper, Results):

* isometric force of 1 APS at 0.1 MPa: 0.315 N (tared: F(0.1 MPa) - F(0)), the fixture
  at the chain's hanging rest position (``assemblies.hanging_rest_position``), as in the
  experiment: inside the fit that position is itself an equilibrium constraint, so it
  follows the fitted parameters;
* 3 APS, no load, 0.1 MPa: ``L / L' = 0.875``;
* 3 APS, 100 g, 0 MPa: ``L / L' = 1.07``;

with ``L`` the hanging chain's length (what the paper's camera measured) and ``L'`` the
model's own length at 0 MPa without load (hanging under its own weight and the 1 g hook)
in both ratios: the paper's strain ``(L[P, load] - L[0, load]) / L[0, 0]`` is normalised
by that length, and its 0 g curve ends at -12.5 % = 0.875 - 1. The alternative, ``L'`` the
undeformed ``n (A + 2 r1')`` (:func:`rest_length_undeformed`, 164.94 mm: the 165 mm the
paper "measured in advance"), has no physical fit (:func:`fit` with ``rest_length =
"undeformed"``, tests/dynamics/test_calibration.py): the two length ratios then give an
isometric force of 0.48 N or more for any thread stiffness, against 0.315 N. So the
hanging chain is 170.6 mm against the measured 165 mm: a contradiction in the paper's
numbers for SPA bodies of about 8.6 g, stated in docs/paper.md, "Rest length".

Fitted: the effective pneumatic area ``A_p``, the restoring cross-section ``A_r`` and
the I-band series stiffness ``k_s``, in log space, by the identification engine
(:mod:`.identification`, docs/fitting.md): the three targets are one static experiment
set, six equilibria (:class:`~.identification.experiments.StaticPoint`, the isometric
fixture linked to the hanging chain's rest position) and three targets with the
relative residuals ``(t - T) / T``, solved as one least-squares problem with the
equilibria as constraints (constrained Gauss-Newton, exact CasADi Jacobians; the
start's equilibria solved by :func:`.equilibrium.solve_equilibrium`). The result is
accepted only after an independent check (:func:`evaluate`: every equilibrium re-solved
from scratch) meets the targets to :data:`VERIFY_RTOL`; a failure raises
:class:`SolverError` naming the solver's status.

Region of convergence: every start with each fitted parameter within a factor
:data:`START_REGION` = (0.5, 2) of its packaged value converges to the same parameters
(tested from the 8 corners and fixed-seed random starts in
tests/dynamics/test_calibration.py). The fit is unique there: the sensitivity matrix at
it is non-singular (singular values 1.0, 0.088, 0.022).

The compliance split is not identified: with the restoring length ``L_r`` estimated too,
the three targets leave a flat direction (the L_r family, :func:`family`), which the
engine's singular values flag as structurally non-identifiable
(:attr:`CalibrationResult.compliance_split`).

Identifiability is judged from the sensitivities of the targets to every candidate
parameter at the solution and their singular values.
"""

from __future__ import annotations

import fnmatch
from dataclasses import dataclass, replace

import numpy as np

from .assemblies import hanging_load, isometric
from .components.aps import APSParams
from .equilibrium import solve_equilibrium
from .errors import ParameterError, SolverError
from .identification import uncertainty
from .identification.estimate import fit_from
from .identification.experiments import Estimated, Noise, StaticPoint, Target
from .identification.gauss_newton import Options
from .identification.problem import Problem
from .newton import ContinuationFailure, NewtonFailure, continuation

P_TEST = 1.0e5  # Pa, the paper's maximum test pressure (0.1 MPa)

TARGETS = {
    "force_n1_0p1MPa_N": 0.315,
    "length_ratio_0g_0p1MPa": 0.875,
    "length_ratio_100g_0MPa": 1.07,
}
"""Paper's measured values (Results: Isometric and Concentric Contraction); the length
ratios are ``L / L'`` with ``L'`` the chain hanging at 0 MPa without load (module
docstring; :data:`REST_LENGTHS`)."""

START_REGION = (0.5, 2.0)
"""Factors on each fitted parameter's packaged value between which every start converges
to the same fit (tested: the corners and fixed-seed random starts)."""

VERIFY_RTOL = 1e-8
"""Largest relative target residual accepted when the fit's equilibria are re-solved
independently (:func:`evaluate`)."""

BOUNDS = 20.0
"""The fit's bounds: each fitted parameter within this factor of its start."""

FITTED = {  # APSParams field -> model parameter pattern
    "A_p": "*.chamber.A",
    "A_r": "*.yeoh.A_r",
    "k_s": "*.actin*.k_s",
}

SPLIT = {"L_r": "*.yeoh.L_r"}
"""The compliance-split parameter the targets cannot identify beside :data:`FITTED`."""

CANDIDATES = (
    *FITTED,
    "L_r",
    "C1",
    "C2",
    "m_body",
    "eps_slack",
    "V0",
    "C_tube",
    "m_e",
    "c_e",
    "c_s",
)
"""APSParams fields whose identifiability from the three targets is reported."""


@dataclass
class Fit:
    """A verified solution of the fit: parameters, achieved targets, relative residuals,
    status and the solver's iterations."""

    params: APSParams
    fitted: dict[str, float]
    achieved: dict[str, float]
    residuals: dict[str, float]
    status: str
    iterations: int


@dataclass
class CalibrationResult(Fit):
    """A :class:`Fit` with the identifiability of the candidates (:func:`sensitivities`)
    and the engine's verdict on the compliance split (:func:`compliance_split`)."""

    sensitivities: dict[str, dict[str, float]]
    singular_values: list[float]
    not_identifiable: list[str]
    compliance_split: dict

    def to_dict(self) -> dict:
        """JSON-ready record with provenance."""
        return {
            "fitted": {
                k: {
                    "value": v,
                    "unit": APSParams.unit(k),
                    "source": "calibrated against "
                    + ", ".join(f"{k2} = {v2}" for k2, v2 in TARGETS.items()),
                }
                for k, v in self.fitted.items()
            },
            "targets": TARGETS,
            "achieved": self.achieved,
            "relative_residuals": self.residuals,
            "sensitivities_dlog_target_dlog_param": self.sensitivities,
            "singular_values": self.singular_values,
            "not_identifiable": self.not_identifiable,
            "compliance_split": self.compliance_split,
            "status": self.status,
            "iterations": self.iterations,
            "rest_length_undeformed_n3_m": rest_length_undeformed(3, self.params),
            "rest_length_hanging_n3_m": rest_length_hanging(3, self.params),
        }


def _experiments(p: APSParams):
    """(key, model, input, parameter overrides, output, linked parameters) of each
    equilibrium the targets need; a link maps a parameter to an earlier experiment's output."""
    rest = hanging_load(1, p, load_kg=0.0)
    iso = isometric(1, p)
    hang = hanging_load(3, p, load_kg=0.0)
    link = {"fixture.s0": "rest_n1"}
    heavy = {"load.m": hang.variables["load.m"].value + 0.1}
    length = "myofibril.length"
    return [
        ("rest_n1", rest, 0.0, {}, "load.s", {}),
        ("iso_0", iso, 0.0, {}, "sensor.f", link),
        ("iso_p", iso, P_TEST, {}, "sensor.f", link),
        ("hang_0g_0", hang, 0.0, {}, length, {}),
        ("hang_0g_p", hang, P_TEST, {}, length, {}),
        ("hang_100g_0", hang, 0.0, heavy, length, {}),
    ]


def rest_length_undeformed(n: int, p: APSParams) -> float:
    """The paper's ``L'`` [m]: ``n (A + 2 r1')``, taut threads, no expansion, no weight
    (164.94 mm for the paper's 3 APS; measured: 165 mm)."""
    return n * p.unit_length_rest


def rest_length_hanging(n: int, p: APSParams) -> float:
    """Length [m] of ``n`` APS hanging under their own weight (and the 1 g hook) at 0 MPa:
    a prediction, longer than :func:`rest_length_undeformed` by the sag."""
    eq = solve_equilibrium(hanging_load(n, p, load_kg=0.0), {"regulator.p_cmd": 0.0})
    return eq["myofibril.length"]


REST_LENGTHS = ("hanging", "undeformed")
"""Definitions of ``L'`` in the length ratios: the chain hanging at 0 MPa without load
(the default: the only one with a physical fit, docs/paper.md "Rest length") or the
undeformed ``n (A + 2 r1')``."""


def _targets(y: dict, p: APSParams, rest_length: str = "hanging") -> dict:
    """Target quantities from the per-experiment outputs (force or length)."""
    if rest_length not in REST_LENGTHS:
        raise ParameterError("rest_length", rest_length, f"one of {REST_LENGTHS}")
    L_rest = y["hang_0g_0"] if rest_length == "hanging" else rest_length_undeformed(3, p)
    return {
        "force_n1_0p1MPa_N": y["iso_p"] - y["iso_0"],
        "length_ratio_0g_0p1MPa": y["hang_0g_p"] / L_rest,
        "length_ratio_100g_0MPa": y["hang_100g_0"] / L_rest,
    }


def evaluate(p: APSParams, rest_length: str = "hanging") -> dict[str, float]:
    """The three target quantities for a parameter set (by equilibrium solves from
    scratch); ``rest_length``: the ``L'`` of the ratios, one of :data:`REST_LENGTHS`."""
    y, guesses = {}, {}
    for key, model, pc, over, out, _ in _experiments(p):
        start = guesses.get(model.name)
        eq = solve_equilibrium(model, {"regulator.p_cmd": pc}, over, guess=start)
        guesses.setdefault(model.name, eq)
        y[key] = eq[out]
    return _targets(y, p, rest_length)


def problem(
    start: APSParams,
    fitted: tuple[str, ...] = tuple(FITTED),
    targets: tuple[str, ...] = tuple(TARGETS),
    rest_length: str = "hanging",
    extra: dict[str, str] | None = None,
    values: dict[str, float] | None = None,
) -> Problem:
    """The calibration as an identification problem: the ``fitted`` fields (and ``extra``:
    field -> model parameter pattern) estimated in log space from ``start``, the six
    equilibria of :func:`_experiments` and the ``targets`` (the paper's, or ``values``)
    with sigma = the paper's target (the relative residuals)."""
    patterns = {**{k: FITTED[k] for k in fitted}, **(extra or {})}
    params = [
        Estimated(k, APSParams.unit(k), v, v / BOUNDS, v * BOUNDS)
        for k, v in ((k, getattr(start, k)) for k in patterns)
    ]
    points, outs = [], {}
    for key, model, pc, over, out, link in _experiments(start):
        p = model.parameters(over)
        u = model.u0(p)
        u[model.input_names.index("regulator.p_cmd")] = pc
        uses = {
            n: (k, 1.0)
            for n in model.param_names
            for k, pat in patterns.items()
            if fnmatch.fnmatch(n, pat)
        }
        links = {name: (point, "load.s") for name, point in link.items()}
        points.append(StaticPoint(key, model, u, p, uses, links))
        outs[key] = out

    def target(k: str) -> Target:
        def expr(signal):
            y = {key: signal(key, out) for key, out in outs.items()}
            return _targets(y, start, rest_length)[k]

        return Target(k, expr, (values or TARGETS)[k], k)

    noise = {k: Noise(abs(TARGETS[k])) for k in targets}
    tight = Options(rtol=1e-20, atol=0.0, gtol=1e-8, xtol=1e-12)
    return Problem(
        params, points=points, targets=[target(k) for k in targets], noise=noise, options=tight
    )


def fit(
    start: APSParams,
    fitted: tuple[str, ...] = tuple(FITTED),
    targets: tuple[str, ...] = tuple(TARGETS),
    rest_length: str = "hanging",
    verbose: bool = False,
) -> Fit:
    """Fit the ``fitted`` parameters (keys of :data:`FITTED`) to the ``targets`` (keys of
    :data:`TARGETS`, as many as parameters) from ``start``; ``rest_length`` as
    :func:`evaluate`. The identification engine (module docstring), verified by
    :func:`evaluate` to :data:`VERIFY_RTOL`; raises :class:`SolverError` otherwise."""
    if not set(fitted) <= set(FITTED):
        raise ParameterError("fitted", fitted, f"names from {tuple(FITTED)}")
    if not set(targets) <= set(TARGETS) or len(targets) != len(fitted):
        raise ParameterError("targets", targets, f"{len(fitted)} names from {tuple(TARGETS)}")
    theta, iterations, steps = _solve(start, fitted, targets, rest_length, verbose)
    values = {k: float(v) for k, v in zip(fitted, theta, strict=True)}
    how = (
        f"least squares (constrained Gauss-Newton) in {iterations} iterations, "
        f"{steps} continuation step(s)"
    )
    return verified(start, values, how, iterations, targets, rest_length)


def verified(
    start: APSParams,
    values: dict[str, float],
    how: str,
    iterations: int,
    targets: tuple[str, ...] = tuple(TARGETS),
    rest_length: str = "hanging",
) -> Fit:
    """The :class:`Fit` of fitted ``values`` (fields of ``start``) that a solver reached
    (``how``, in ``iterations``), accepted only when its equilibria re-solved from scratch
    (:func:`evaluate`) meet the ``targets`` to :data:`VERIFY_RTOL`; SolverError otherwise."""
    p_fit = replace(start, **values)
    every = evaluate(p_fit, rest_length)
    achieved = {k: every[k] for k in targets}
    residuals = {k: (achieved[k] - TARGETS[k]) / TARGETS[k] for k in targets}
    worst = max(abs(r) for r in residuals.values())
    if not worst <= VERIFY_RTOL:
        raise SolverError(
            f"calibration failed: the fit does not hold when its equilibria are re-solved "
            f"from scratch (worst relative target residual {worst:.3g} > {VERIFY_RTOL:g}: "
            "another equilibrium branch, or targets other than calibration.TARGETS)"
        )
    status = (
        f"converged: {how}; verified by equilibrium solves from scratch (worst relative "
        f"target residual {worst:.2g})"
    )
    return Fit(p_fit, values, achieved, residuals, status, iterations)


MIN_STEP = 1.0 / 256
"""Smallest continuation step (fraction of the way to the targets) before giving up."""


def _solve(start: APSParams, fitted, targets, rest_length, verbose) -> tuple:
    """The fitted values, the iterations and the continuation steps: straight to the
    paper's targets, else (:func:`.newton.continuation`) from the targets the start
    achieves to the paper's, halving a step that fails."""
    th0 = np.array([getattr(start, k) for k in fitted])
    t0 = evaluate(start, rest_length)
    count = {"iterations": 0, "steps": 0}

    def advance(theta: np.ndarray, frac: float) -> np.ndarray:
        goal = {k: t0[k] + frac * (TARGETS[k] - t0[k]) for k in targets}
        prob = problem(
            replace(start, **dict(zip(fitted, theta, strict=True))),
            fitted,
            targets,
            rest_length,
            values=goal,
        )
        sol = fit_from(prob, theta).solution
        count["iterations"] += sol.iterations
        if verbose:
            print(
                f"calibration: targets at {100 * frac:5.1f} %: {sol.status}, "
                f"{sol.iterations} iterations"
            )
        if not sol.success:
            raise NewtonFailure(sol.status, sol.cost, sol.iterations)
        count["steps"] += 1
        return sol.theta

    try:
        theta = continuation(advance, th0, MIN_STEP)
    except ContinuationFailure as stop:
        raise SolverError(
            f"calibration failed: the least-squares solver stopped ({stop.failure.why}); the "
            f"continuation reached {100 * stop.fraction:.3g} % of the way from the start's "
            "targets to the paper's"
        ) from None
    return theta, count["iterations"], count["steps"]


def compliance_split(p: APSParams) -> dict:
    """The engine's identifiability verdicts at a calibrated ``p`` with :data:`SPLIT`
    (``L_r``) estimated beside :data:`FITTED` from the three static targets: the flat
    direction named (``verdicts``) and the ``singular_values``."""
    prob = problem(p, extra=SPLIT)
    theta = np.array([getattr(p, e.name) for e in prob.params])
    sol = prob.evaluate(prob.initial_guess(theta), prob.weights())
    fis = uncertainty.fisher(prob, sol)
    verdicts = uncertainty.verdicts(prob, fis, None)
    return {
        "parameters": [e.name for e in prob.params],
        "verdicts": dict(zip((e.name for e in prob.params), verdicts, strict=True)),
        "singular_values": fis.singular_values.tolist(),
    }


def calibrate(start: APSParams | None = None, verbose: bool = False) -> CalibrationResult:
    """Fit ``A_p``, ``A_r``, ``k_s`` to :data:`TARGETS` from ``start`` (default: the
    packaged parameters; any start in :data:`START_REGION`), with identifiability."""
    return assessed(fit(start or APSParams.from_paper(), verbose=verbose))


def assessed(f: Fit) -> CalibrationResult:
    """A verified fit of :data:`FITTED` with the identifiability of the candidates
    (:func:`sensitivities`) and the compliance split (:func:`compliance_split`)."""
    sens, sv, weak = sensitivities(f.params)
    return CalibrationResult(
        **vars(f),
        sensitivities=sens,
        singular_values=sv,
        not_identifiable=weak,
        compliance_split=compliance_split(f.params),
    )


def sensitivities(p: APSParams, rel_step: float = 1e-4) -> tuple[dict, list[float], list[str]]:
    """d log(target) / d log(parameter) for every candidate, their singular values, and the
    candidates the targets cannot identify (zero sensitivity, or lost in the null space).

    Central differences of equilibrium solves (each solve converged to 1e-10).
    """
    base = evaluate(p)
    sens: dict[str, dict[str, float]] = {}
    for name in CANDIDATES:
        v = getattr(p, name)
        if v == 0:
            continue
        up = evaluate(replace(p, **{name: v * (1 + rel_step)}))
        dn = evaluate(replace(p, **{name: v * (1 - rel_step)}))
        sens[name] = {k: float((np.log(up[k]) - np.log(dn[k])) / (2 * rel_step)) for k in base}
    names = list(sens)
    S = np.array([[sens[n][k] for n in names] for k in base])
    sv = np.linalg.svd(S[:, [names.index(k) for k in FITTED]], compute_uv=False).tolist()
    weak = [n for n in names if np.max(np.abs(S[:, names.index(n)])) < 1e-6]
    return sens, sv, weak


CONCENTRIC_LOADS_KG = (0.0, 0.01, 0.02, 0.05, 0.1)
"""Loads of the paper's concentric experiment (Results: Concentric Contraction) [kg]."""

CONCENTRIC_PRESSURES_PA = tuple(float(p) for p in np.linspace(0.0, P_TEST, 11))
"""Its pressures, 0 to 0.1 MPa in 0.01 MPa steps [Pa]."""

FAMILY_L_R = (4e-3, 8e-3, 16e-3, 20e-3, 34e-3)
"""Restoring-element lengths L_r [m] of the calibration family (docs/paper.md): each
member is calibrated to the same three targets."""


@dataclass
class Concentric:
    """The concentric experiment for one parameter set: actuation strain
    ``(L[P, load] - L[0, load]) / L[0, 0]`` [1] (rows: loads, columns: pressures) and the
    range of the Yeoh element's stretch over all its equilibria."""

    strain: np.ndarray
    stretch_min: float
    stretch_max: float


def concentric(p: APSParams, n: int = 3) -> Concentric:
    """Equilibria of ``n`` APS over :data:`CONCENTRIC_LOADS_KG` x
    :data:`CONCENTRIC_PRESSURES_PA` (continuation along the pressure)."""
    lengths, stretches = [], []
    for load in CONCENTRIC_LOADS_KG:
        m = hanging_load(n, p, load_kg=load)
        row, eq = [], None
        for pc in CONCENTRIC_PRESSURES_PA:
            eq = solve_equilibrium(m, {"regulator.p_cmd": pc}, guess=eq)
            row.append(eq["myofibril.length"])
            stretches += [eq[f"myofibril.aps{i + 1}.yeoh.lambda"] for i in range(n)]
        lengths.append(row)
    L = np.array(lengths)
    return Concentric((L - L[:, :1]) / L[0, 0], float(min(stretches)), float(max(stretches)))


@dataclass
class FamilyMember:
    """One calibration for a given ``L_r`` [m]: its fit and its concentric prediction."""

    L_r: float
    result: CalibrationResult
    concentric: Concentric


def family(L_r_values=FAMILY_L_R, start: APSParams | None = None) -> list[FamilyMember]:
    """Calibrate once per ``L_r``: every member meets the three targets, yet they predict
    different loaded strains (the passive compliance split between the SPA and the
    threads is not identified by the targets; docs/paper.md)."""
    base = start or APSParams.from_paper()
    out = []
    for L_r in L_r_values:
        res = calibrate(replace(base, L_r=float(L_r)))
        out.append(FamilyMember(float(L_r), res, concentric(res.params)))
    return out
