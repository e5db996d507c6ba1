"""Work-precision diagrams: error against wall time for every method, four scenarios
(the fourth on a PWM-driven valve, whose switching edges every method stops at).

Following the SciML benchmarks, each method is swept over its accuracy knob (the
tolerance of an adaptive method, the step of a fixed-step method) and each run gives
one point (wall time, error) against a reference solution.

**Error metric.** Over the 18 (n = 3) states ``x_i`` at the saved points (201 points,
every 10 ms for a 2 s run), each state scaled by its nominal magnitude
``s_i = max_t |x_ref,i(t)|``:

* ``error_final = sqrt(mean_i ((x_i(T) - x_ref,i(T)) / s_i)^2)`` (final time);
* ``error_l2 = sqrt(mean_{k,i} ((x_i(t_k) - x_ref,i(t_k)) / s_i)^2)`` (all saved points).

Both are dimensionless relative errors; "1e-6 relative accuracy" means
``error_l2 = 1e-6``.

**Reference.** CVODES at ``rtol = 1e-12``, ``atol = 1e-15``, cross-checked against
scipy's Radau (exact sparse Jacobian) at ``rtol = 1e-12`` (``1e-8`` in quick mode);
their difference in the same metric is reported with every scenario.

**Tolerances** are paired: ``atol = rtol * 1e-3`` (SI units: the air masses are about
5e-6 kg, so their absolute tolerance dominates; this is part of what is measured).
**Wall time** is the median over repeated calls of :func:`~.simulate.simulate` (warm:
CasADi Functions and integrators are built by the first call and cached).
"""

from __future__ import annotations

import functools
import math
import statistics
import time
import warnings
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..assemblies import hanging_load
from ..equilibrium import solve_equilibrium
from ..errors import SarcomereError
from ..modeling.model import Model
from ..results import Result
from ..signals import Ramp, Step
from ..simulation.simulate import SolverSettings, simulate
from .pysource import register_baseline

P_CMD = "regulator.p_cmd"
ATOL_PER_RTOL = 1e-3
"""Paired tolerances: ``atol = rtol * ATOL_PER_RTOL``."""


# --- scenarios --------------------------------------------------------------------------
@dataclass(frozen=True)
class Scenario:
    """One benchmark case: a hanging myofibril, a start equilibrium and a command.

    Attributes
    ----------
    name, description : str
        Key and one line.
    n : int
        Number of APS.
    load_kg : float
        Load mass [kg] (the 1 g hook comes on top).
    p_start : float
        Command of the start equilibrium [Pa gauge].
    command : Step or Ramp
        The regulator command [Pa gauge] over time.
    t_final : float
        Stop time [s].
    n_out : int
        Number of saved points (evenly spaced, both ends included).
    params : tuple of (str, float)
        Parameter overrides by name (SI).
    supply : str
        "regulator" (``command`` in Pa gauge) or "valve_pwm" (the 50 Hz 3/2 valve of
        :func:`~sarcomere.dynamics.supply.add_supply`; ``p_start`` and ``command`` are
        duty cycles: every PWM edge is a breakpoint each method stops at).
    """

    name: str
    description: str
    n: int
    load_kg: float
    p_start: float
    command: Step | Ramp
    t_final: float = 2.0
    n_out: int = 201
    params: tuple = ()
    supply: str = "regulator"

    @property
    def input(self) -> str:
        """The commanded input: the regulator's or the valve's duty."""
        return P_CMD if self.supply == "regulator" else "valve.cmd"

    @property
    def t_out(self) -> np.ndarray:
        """Saved points [s]."""
        return np.linspace(0.0, self.t_final, self.n_out)

    def setup(self) -> tuple[Model, np.ndarray]:
        """The model and the start equilibrium state (cached)."""
        return _setup(self.n, self.load_kg, self.p_start, self.params, self.supply)

    def run(self, settings: SolverSettings, all_signals: bool = False) -> Result:
        """Simulate with ``settings`` on the saved points (the states only, unless
        ``all_signals``: the error metric needs no more, and every method pays alike)."""
        model, x0 = self.setup()
        return simulate(
            model,
            self.t_final,
            inputs={self.input: self.command},
            params=dict(self.params),
            x0=x0,
            settings=settings,
            t_out=self.t_out,
            signals=None if all_signals else model.state_names,
        )


@functools.cache
def _setup(
    n: int, load_kg: float, p_start: float, params: tuple, supply: str = "regulator"
) -> tuple[Model, np.ndarray]:
    model = hanging_load(n, load_kg=load_kg, supply=supply)
    name = P_CMD if supply == "regulator" else "valve.cmd"
    eq = solve_equilibrium(model, {name: p_start}, params=dict(params))
    return model, eq.x


def scenarios(n: int = 3) -> dict[str, Scenario]:
    """The four work-precision scenarios for a chain of ``n`` APS."""
    return {
        "ramp": Scenario(
            "ramp",
            "slow ramp 0 -> 0.1 MPa over 2 s, 50 g load",
            n,
            0.05,
            0.0,
            Ramp(final=1e5, duration=2.0, unit="Pa"),
        ),
        "step": Scenario(
            "step",
            "pressure step 0 -> 0.1 MPa at 0.1 s, 50 g load",
            n,
            0.05,
            0.0,
            Step(final=1e5, time=0.1, unit="Pa"),
        ),
        "vent": Scenario(
            "vent",
            "venting from 0.1 MPa, no load, 10 ms regulator lag: threads go slack",
            n,
            0.0,
            1e5,
            Step(initial=1e5, final=0.0, time=0.1, unit="Pa"),
            params=(("regulator.tau", 0.01),),
        ),
        "pwm": Scenario(
            "pwm",
            "3/2 valve at 50 Hz PWM, duty 0.3 -> 0.5 at 0.1 s, 20 g load: 50 edges",
            n,
            0.02,
            0.3,
            Step(initial=0.3, final=0.5, time=0.1),
            t_final=0.5,
            n_out=51,
            supply="valve_pwm",
        ),
    }


# --- reference and error metric ---------------------------------------------------------
@dataclass
class Reference:
    """A reference solution with its scale and cross-check.

    Attributes
    ----------
    result : Result
        The reference run.
    X : numpy.ndarray
        Reference states at the saved points, shape (N, nx).
    scale : numpy.ndarray
        Nominal magnitude of each state, ``max_t |x_ref,i|`` (1 where that is 0).
    settings : SolverSettings
        How it was computed.
    crosscheck : dict
        The second method, its settings, its steps and the errors of the reference
        against it.
    """

    result: Result
    X: np.ndarray
    scale: np.ndarray
    settings: SolverSettings
    crosscheck: dict = field(default_factory=dict)


def states(result: Result, model: Model) -> np.ndarray:
    """The state columns of a result, shape (N, nx)."""
    return np.column_stack([result[n] for n in model.state_names])


def state_errors(X: np.ndarray, ref: Reference) -> tuple[float, float]:
    """(final-time error, l2 error over the saved points), scaled as in the module doc."""
    E = (X - ref.X) / ref.scale
    return float(np.sqrt(np.mean(E[-1] ** 2))), float(np.sqrt(np.mean(E**2)))


REFERENCE_RTOL = 1e-12
CHECK_ATOL_MIN = 1e-13
"""The cross-check's smallest absolute tolerance [SI units of each state]: at atol 1e-15
(rtol 1e-12) scipy's Radau cannot converge its Newton iteration on resting velocities
(their stage equations' roundoff is above the increments it asks for), halves its step
down to about 5 us and takes more than 20 000 steps for the vent scene's first 15 ms at
rest (n = 1); at atol 1e-13 it takes 2 steps there (``docs/numerics.md``)."""


def reference(sc: Scenario, check_rtol: float = 1e-12) -> Reference:
    """CVODES at rtol 1e-12, cross-checked against scipy Radau at ``check_rtol`` (atol
    ``check_rtol * ATOL_PER_RTOL``, at least :data:`CHECK_ATOL_MIN`)."""
    model, _ = sc.setup()
    settings = SolverSettings("cvodes", REFERENCE_RTOL, REFERENCE_RTOL * ATOL_PER_RTOL)
    res = sc.run(settings, all_signals=True)
    X = states(res, model)
    scale = np.abs(X).max(axis=0)
    ref = Reference(res, X, np.where(scale > 0, scale, 1.0), settings)
    check_atol = max(check_rtol * ATOL_PER_RTOL, CHECK_ATOL_MIN)
    check = SolverSettings("scipy_radau", check_rtol, check_atol)
    tic = time.perf_counter()
    other = sc.run(check)
    final, l2 = state_errors(states(other, model), ref)
    ref.crosscheck = {
        "method": check.method,
        "rtol": check.rtol,
        "atol": check.atol,
        "error_final": final,
        "error_l2": l2,
        "n_steps": int(other.meta["n_steps"]),
        "wall_time_s": time.perf_counter() - tic,
    }
    return ref


# --- sweeps -----------------------------------------------------------------------------
ADAPTIVE = (
    "radau",
    "rodas",
    "cvodes",
    "scipy_rk45",
    "scipy_radau",
    "scipy_radau_numpy",
    "scipy_bdf",
    "scipy_lsoda",
)
FIXED = ("rk4", "radau_fixed", "collocation")


@dataclass(frozen=True)
class Plan:
    """What to sweep and how often to time each run.

    Attributes
    ----------
    tolerances : tuple of float
        ``rtol`` values for the adaptive methods (``atol = rtol * 1e-3``).
    steps : dict of str to tuple of float
        Step sizes [s] per fixed-step method.
    repeats : int
        Timed calls per point (the median is kept), after one cold call.
    budget_s : float
        No further call once the calls of a point have taken this long [s]; a point
        whose cold call alone exceeds it keeps the cold time (its build cost is
        negligible next to it).
    check_rtol : float
        Tolerance of the reference's scipy Radau cross-check.
    """

    tolerances: tuple
    steps: dict
    repeats: int
    budget_s: float
    check_rtol: float


FULL = Plan(
    tolerances=tuple(10.0**-k for k in range(3, 11)),
    steps={
        "rk4": (1e-3, 5e-4, 2.5e-4, 1.25e-4, 6.25e-5),
        "radau_fixed": (1e-2, 5e-3, 2e-3, 1e-3, 5e-4),
        "collocation": (1e-2, 5e-3, 2e-3, 1e-3),
    },
    repeats=5,
    budget_s=3.0,
    check_rtol=1e-12,
)
QUICK = Plan(
    tolerances=(1e-3, 1e-4, 1e-5, 1e-6, 1e-7),
    steps={"rk4": (1e-3, 2.5e-4), "radau_fixed": (1e-2, 2e-3), "collocation": (1e-2,)},
    repeats=3,
    budget_s=0.3,
    check_rtol=1e-8,
)


def run_point(sc: Scenario, ref: Reference, settings: SolverSettings, plan: Plan) -> dict:
    """One record: errors, median wall time, statistics (or the failure)."""
    record = {
        "scenario": sc.name,
        "method": settings.method,
        "kind": "fixed" if settings.step is not None else "adaptive",
        "rtol": None if settings.step is not None else settings.rtol,
        "atol": None if settings.step is not None else settings.atol,
        "step_s": settings.step,
    }
    model, _ = sc.setup()
    walls: list[float] = []
    try:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            tic = time.perf_counter()
            res = sc.run(settings)  # cold: builds and caches the CasADi Functions
            cold = time.perf_counter() - tic
            while len(walls) < plan.repeats and sum(walls) + cold <= plan.budget_s:
                tic = time.perf_counter()
                res = sc.run(settings)
                walls.append(time.perf_counter() - tic)
    except SarcomereError as exc:
        return {**record, "status": "failed", "message": " ".join(str(exc).split())[:300]}
    final, l2 = state_errors(states(res, model), ref)
    return {
        **record,
        "status": "ok",
        "error_final": final,
        "error_l2": l2,
        "wall_time_s": statistics.median(walls) if walls else cold,
        "wall_time_cold_s": cold,
        "n_timed": len(walls),
        "n_steps": res.meta.get("n_steps"),
        "n_rhs": res.meta.get("n_rhs"),
        "n_jac": res.meta.get("n_jac"),
        "warnings": sorted({type(w.message).__name__ for w in caught}),
    }


def sweep(
    sc: Scenario, ref: Reference, plan: Plan, only: Sequence[str] | None = None
) -> list[dict]:
    """Records for every method of ``plan`` (or only the named ones) on one scenario (the
    Python-source baseline registered first)."""
    register_baseline()
    wanted = only or (*ADAPTIVE, *FIXED)
    out = []
    for m in wanted:
        if m in plan.steps:
            grid = [SolverSettings(m, step=h) for h in plan.steps[m]]
        else:
            grid = [SolverSettings(m, tol, tol * ATOL_PER_RTOL) for tol in plan.tolerances]
        out.extend(run_point(sc, ref, s, plan) for s in grid)
    return out


def wall_at_error(
    records: Sequence[dict], method: str, target: float, metric: str = "error_l2"
) -> float | None:
    """Wall time [s] at error ``target``, interpolated log-log between two sweep points.

    The points of ``method`` are taken in order of decreasing tolerance (or step); the
    first consecutive pair whose errors bracket ``target`` is interpolated. None when
    no pair brackets it.
    """
    pts = [r for r in records if r["method"] == method and r["status"] == "ok"]
    pts.sort(key=lambda r: -(r["rtol"] if r["rtol"] is not None else r["step_s"]))
    for a, b in zip(pts[:-1], pts[1:], strict=True):
        ea, eb = a[metric], b[metric]
        if min(ea, eb) <= target <= max(ea, eb) and ea != eb and min(ea, eb) > 0:
            w = (math.log(target) - math.log(ea)) / (math.log(eb) - math.log(ea))
            return math.exp(
                math.log(a["wall_time_s"])
                + w * (math.log(b["wall_time_s"]) - math.log(a["wall_time_s"]))
            )
    return None


# --- charts -----------------------------------------------------------------------------
def plot(records: Sequence[dict], sc: Scenario, ref: Reference, path: Path) -> Path:
    """Error (l2 and final) against wall time, log-log, one line per method."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(9.0, 3.8), sharey=True)
    for ax, metric, title in zip(
        axes,
        ("error_l2", "error_final"),
        ("l2 error over saved points", "final-time error"),
        strict=True,
    ):
        for i, m in enumerate(dict.fromkeys(r["method"] for r in records)):
            pts = [r for r in records if r["method"] == m and r["status"] == "ok" and r[metric] > 0]
            if not pts:
                continue
            pts.sort(key=lambda r: r["wall_time_s"])
            style = "-o" if pts[0]["kind"] == "adaptive" else "--s"
            ax.loglog(
                [r["wall_time_s"] for r in pts],
                [r[metric] for r in pts],
                style,
                color=f"C{i}",
                ms=3.5,
                lw=1.2,
                label=m,
            )
        ax.axhline(ref.crosscheck.get(metric, np.nan), color="0.6", lw=0.8, ls=":")
        ax.set_xlabel("wall time [s] (median)")
        ax.set_title(title, fontsize=9)
        ax.grid(True, which="major", alpha=0.3)
    axes[0].set_ylabel("relative error [1]")
    axes[1].legend(fontsize=7, loc="upper right")
    fig.suptitle(f"{sc.name}: {sc.description} (n = {sc.n})", fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=80)
    plt.close(fig)
    return path


# --- the whole study --------------------------------------------------------------------
def study(out_dir: Path, quick: bool = False, n: int = 3) -> dict:
    """Run every scenario, write ``work_precision.json`` and one chart per scenario.

    Returns
    -------
    dict
        ``records`` (list), ``references`` (per scenario: cross-check and checks),
        ``metrics`` (named numbers for summary.json) and ``files`` (paths written).
    """
    import json

    plan = QUICK if quick else FULL
    out_dir.mkdir(parents=True, exist_ok=True)
    records: list[dict] = []
    refs: dict[str, dict] = {}
    files: list[Path] = []
    metrics: dict[str, float | None] = {}
    for name, sc in scenarios(n).items():
        ref = reference(sc, plan.check_rtol)
        recs = sweep(sc, ref, plan)
        records.extend(recs)
        refs[name] = {
            "description": sc.description,
            "reference": _ref_info(sc, ref),
            **_checks(ref),
        }
        files.append(plot(recs, sc, ref, out_dir / f"work_precision_{name}.png"))
        metrics[f"reference_crosscheck_{name}_error_l2_ratio"] = ref.crosscheck["error_l2"]
    step_recs = [r for r in records if r["scenario"] == "step"]
    cv = wall_at_error(step_recs, "cvodes", 1e-6)
    sn = wall_at_error(step_recs, "scipy_radau_numpy", 1e-6)
    sr = wall_at_error(step_recs, "scipy_radau", 1e-6)
    metrics["cvodes_wall_at_1em6_s"] = cv
    metrics["scipy_radau_numpy_wall_at_1em6_s"] = sn
    metrics["scipy_radau_wall_at_1em6_s"] = sr
    # the baseline: scipy Radau on a numpy/Python right-hand side (FD Jacobian)
    metrics["speedup_cvodes_vs_scipy_radau"] = sn / cv if cv and sn else None
    # a stronger baseline: scipy Radau on CasADi's RHS and exact sparse Jacobian
    metrics["speedup_cvodes_vs_scipy_radau_casadi_rhs"] = sr / cv if cv and sr else None
    ra = wall_at_error(step_recs, "radau", 1e-6)  # the compiled Radau IIA
    metrics["radau_wall_at_1em6_s"] = ra
    metrics["speedup_radau_vs_scipy_radau"] = sn / ra if ra and sn else None
    for name in scenarios(n):  # the Rosenbrock method against radau, every scenario
        recs = [r for r in records if r["scenario"] == name]
        ro, rd = (wall_at_error(recs, m, 1e-6) for m in ("rodas", "radau"))
        metrics[f"rodas_wall_at_1em6_{name}_s"] = ro
        metrics[f"rodas_over_radau_wall_at_1em6_{name}_ratio"] = ro / rd if ro and rd else None
    metrics["vent_min_thread_stretch_m"] = refs["vent"]["min_thread_stretch_m"]
    path = out_dir / "work_precision.json"
    path.write_text(json.dumps({"records": records, "references": refs}, indent=1))
    files.insert(0, path)
    return {"records": records, "references": refs, "metrics": metrics, "files": files}


def _ref_info(sc: Scenario, ref: Reference) -> dict:
    names = sc.setup()[0].state_names
    return {
        "method": ref.settings.method,
        "rtol": ref.settings.rtol,
        "atol": ref.settings.atol,
        "crosscheck": ref.crosscheck,
        "state_scale": dict(zip(names, ref.scale.tolist(), strict=True)),
    }


def _checks(ref: Reference) -> dict:
    """Scenario checks: the smallest thread stretch (negative: slack) [m]."""
    e = [
        ref.result[k]
        for k in ref.result.names
        if k.startswith("myofibril.actin") and k.endswith(".e")
    ]
    return {"min_thread_stretch_m": float(np.min(e)) if e else math.nan}
