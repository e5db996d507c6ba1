"""Parameter identification on ``fit-synthetic`` (issue 25): convergence, coverage, speed.

The baseline is what a user writes today: ``scipy.optimize.least_squares`` (trust-region
reflective, log-parameters within the fit file's bounds, 2-point finite differences)
around ``binding.run`` (the library's simulation of a bound scene from its start
equilibrium, CVODES at ``rtol`` 1e-8), one simulation per experiment per residual. The
static curve: one ``solve_equilibrium`` per level. The fit file's parameters: the five
shared dynamic estimates and ``load.m`` per experiment
(``aps.<field>`` mapped onto the per-unit model parameters it sets, as the studies do).

Usage::

    python benchmarks/fit.py convergence [--starts 50] [--methods lsq,ms,ss] [--out DIR]
    python benchmarks/fit.py speed [--repeats 5] [--baseline 5]
    python benchmarks/fit.py profiles --repeats 1 [--workers 2]   (0: no Dask round)
    python benchmarks/fit.py coverage [--replicates 200] [--profiles 0] [--workers 2]
        [--start truth|file]
    python benchmarks/fit.py noisy-input [--noise-kpa 0.2] [--repeats 5]

(``lsq-default``: the baseline with scipy's default finite-difference step.)

``speed``: from the fit file's start values, the engine's fit (multiple shooting, the
fit file's method, and single shooting; ``fit_from`` on the built problem, known noise: a
warm-up, then ``--repeats``) interleaved with the baseline's (``--baseline``); the
baseline's CPU time until its cost first comes within ``SUCCESS_DCHI2`` of its best (its
fits and one from the truth), and the engine's optimum on the baseline's cost. Ratios
"to best": the baseline's time to that cost over the engine's whole fit
(``ratio_cpu_to_best``) and over the engine's own time to within ``SUCCESS_DCHI2`` of its
best, from a traced fit, at a feasible iterate (``ratio_cpu_both_to_best``). The
first-ever run's compile: run it with an empty
``SARCOMERE_CACHE_DIR`` (the ``build`` and ``first_fit`` records). ``profiles``: the
profiles of every parameter at that optimum as ``Fit.run`` computes them (one Dask task
per parameter on an embedded cluster of ``--workers``), then each alone in this process.
``coverage``: noise replicates ``0 .. R-1`` (:func:`replicate_data`, the generator's
fixed seeds), each fitted by the engine from the truth (or the file's start) on
``--workers`` forked processes, with the Fisher 95 % intervals; the first ``--profiles``
replicates also with profile intervals of the parameters other than
:data:`NON_IDENTIFIABLE`; per parameter the fraction of replicates whose interval holds
the truth, with that fraction's Clopper-Pearson 95 % interval.

Starts: ``--starts`` points drawn log-uniformly within 0.5-2x of the truth for every
fitted parameter (fixed seed 0), the same for every method. A start *succeeds* when its
final cost is within ``SUCCESS_DCHI2`` (chi-squared units, 2 x cost) of the best cost of
its family on the same data: statistically the same optimum. Families: the engine's
methods (``ms``, ``ss``: Radau IIA on the 1 ms samples) and scipy's (``lsq``,
``lsq-default``: CVODES; with a baseline fit started at the truth), whose costs differ by
their integrators' errors. Times are CPU seconds of
this process (``time.process_time``; the engine's Dask workers, if any, are reported by
the engine), methods interleaved start by start. Results: ``fit_<command>.json`` in
``--out`` (default ``out/bench/fit``) and a table on stdout; BENCHMARKS.md section 15.
"""

from __future__ import annotations

import argparse
import contextlib
import functools
import json
import math
import os
import re
import tempfile
import time
import tomllib
from dataclasses import dataclass
from importlib import resources
from pathlib import Path

import numpy as np
from scipy.optimize import least_squares
from scipy.sparse.linalg import splu

from sarcomere.dynamics.equilibrium import solve_equilibrium
from sarcomere.dynamics.errors import SarcomereError
from sarcomere.dynamics.identification.shooting import kinks
from sarcomere.dynamics.signals import Table
from sarcomere.dynamics.simulation.settings import SolverSettings
from sarcomere.dynamics.units import to_si
from sarcomere.scenarios import binding
from sarcomere.scenarios.explore.factors import scene_context
from sarcomere.scenarios.fits import generate as gen
from sarcomere.scenarios.loader import scenario_from_dict

FIT = "fit-synthetic.toml"
#: Success: the final cost within this many chi-squared units (2 x cost) of the best.
SUCCESS_DCHI2 = 1.0
#: Structurally non-identifiable by design: only their ratio enters (the fit file).
NON_IDENTIFIABLE = ("aps.C_tube", "aps.V0")
#: The tuned baseline's finite-difference step (scipy's ``diff_step``).
DIFF_STEP = 1e-5


@dataclass
class TimeSeries:
    """One fitted experiment of the fit file, bound for simulation (``command`` None: a
    static curve, ``t`` its pressure levels [Pa])."""

    name: str
    model: object
    base: dict  # parameter overrides of the scene (none: defaults)
    maps: dict  # fit parameter -> ((model parameter, value per unit of it), ...)
    command: Table | None
    t: np.ndarray
    outputs: tuple[str, ...]
    data: dict  # output -> measured values, SI
    sigma: dict  # output -> standard deviation, SI


def read_fit(
    replicate: int | None = None, table: bool = False
) -> tuple[dict, list[TimeSeries], dict]:
    """The fit file's parameters (name -> (start, low, high, per_experiment), SI), its
    fitted time-series experiments with their data, and the truth (name -> SI; per
    experiment ``load.m@<experiment>``). ``replicate``: the data with that noise draw of
    the generator instead of the packaged files'; ``table``: the command as the CSV's
    1001-row table (what a user with a measured input has) instead of its corners."""
    root = resources.files("sarcomere.scenarios.fits")
    spec = tomllib.loads((root / FIT).read_text())
    params = {}
    for name, p in spec["parameters"].items():
        unit = _unit(name)
        start = to_si(p["start"], unit)
        low, high = (to_si(b, unit) for b in p["bounds"])
        params[name] = (start, low, high, bool(p.get("per_experiment", False)))
    sigma = {k: to_si(v["sigma"], _signal_unit(k)) for k, v in spec["noise"].items()}
    experiments = []
    for e in spec["experiments"]:
        if e.get("validation", False):
            continue
        scene = {
            "scenario": {"name": e["name"], "kind": "transient"},
            "model": dict(e["model"]),
            "simulation": {"stop_time": "1 s"},  # the context binds a transient
        }
        sc = scenario_from_dict(scene, f"<{e['name']}>")
        b = binding.bind(sc)
        model = b.build(e["model"].get("fidelity", "full"))
        ctx = scene_context(sc)
        maps = {}  # fit parameter -> ((model parameter, its value per unit of the field), ...)
        for name in params:
            field = name.removeprefix("aps.")
            if name.startswith("aps."):
                base = getattr(b.aps, field)
                maps[name] = tuple((t, v / base) for t, v in ctx.aps_parameters(field))
            else:
                maps[name] = ((name, 1.0),)
        text = (root / e["data"]).read_text()
        rows = [r for r in text.splitlines() if not r.startswith("#")]
        head = [c.split(" [")[0] for c in rows[0].split(",")]
        values = np.array([[float(v) for v in r.split(",")] for r in rows[1:]])
        cols = {h: values[:, i] for i, h in enumerate(head)}
        si = {n: gen.SIGNALS[n][1] for n in gen.SIGNALS}
        p = cols["pressure"] / si["pressure"]
        if e["kind"] == "static":  # one equilibrium per row: t holds the levels
            t, command = p, None
        else:
            t = cols["time"]
            command = Table(times=tuple(t), values=tuple(p), unit="Pa") if table else corners(t, p)
        data = {o: cols[o] / si[o] for o in e["outputs"]}
        if replicate is not None:
            data = replicate_data(e["name"], replicate, e["outputs"])
        experiments.append(
            TimeSeries(
                e["name"],
                model,
                dict(b.overrides),
                maps,
                command,
                t,
                tuple(e["outputs"]),
                data,
                sigma,
            )
        )
    truth = {k: to_si(v, _unit(k)) for k, v in gen.TRUTH.items()}
    for e in experiments:
        payload = next(x.payload_kg for x in gen.EXPERIMENTS if x.name == e.name)
        truth[f"load.m@{e.name}"] = payload + gen.HOOK_KG
    return params, experiments, truth


@functools.lru_cache(maxsize=16)
def _clean(name: str):
    return gen.clean(next(x for x in gen.EXPERIMENTS if x.name == name))[1]


def replicate_data(name: str, replicate: int, outputs) -> dict:
    """Experiment ``name``'s measured outputs with noise draw ``replicate`` (SI)."""
    exp = next(x for x in gen.EXPERIMENTS if x.name == name)
    noisy = gen.noisy(exp, dict(_clean(name)), replicate)
    return {o: noisy[o] for o in outputs}


def corners(t: np.ndarray, values: np.ndarray) -> Table:
    """The piecewise-linear input through ``(t, values)`` as a Table of its corners only
    (the same function; the engine's :func:`~sarcomere.dynamics.identification.shooting.
    kinks`): a 1001-row table would restart the integrator at every row."""
    keep = np.r_[0, kinks(t, values), len(t) - 1]
    return Table(times=tuple(t[keep]), values=tuple(values[keep]), unit="Pa")


def _unit(name: str) -> str:
    from sarcomere.dynamics.components.aps import APSParams

    if name.startswith("aps."):
        return APSParams.unit(name.removeprefix("aps."))
    return {"regulator.tau": "s", "load.m": "kg"}[name]


def _signal_unit(signal: str) -> str:
    return "m" if signal.endswith("length") else "N" if signal.endswith(".f") else "Pa"


class Problem:
    """The weighted residuals of the fitted time series as a function of the
    log-parameters (the vector order of :meth:`names`)."""

    def __init__(self, params: dict, experiments: list[TimeSeries], rtol: float = 1e-8):
        self.params, self.experiments = params, experiments
        self.settings = SolverSettings(method="cvodes", rtol=rtol, atol=rtol * 1e-3)
        self.evaluations = 0

    def names(self) -> list[str]:
        out = []
        for name, (_, _, _, per) in self.params.items():
            out += [f"{name}@{e.name}" for e in self.experiments] if per else [name]
        return out

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        low, high = [], []
        for _, lo, hi, per in self.params.values():
            k = len(self.experiments) if per else 1
            low += [np.log(lo)] * k
            high += [np.log(hi)] * k
        return np.array(low), np.array(high)

    def overrides(self, theta: np.ndarray, exp: TimeSeries) -> dict:
        values = dict(zip(self.names(), np.exp(theta), strict=True))
        over = dict(exp.base)
        for name in self.params:
            v = values.get(f"{name}@{exp.name}", values.get(name))
            for target, per_unit in exp.maps[name]:
                over[target] = per_unit * v
        return over

    def residuals(self, theta: np.ndarray) -> np.ndarray:
        self.evaluations += 1
        out = []
        for exp in self.experiments:
            if exp.command is None:
                out += self._static(exp, theta)
                continue
            try:
                res = binding.run(
                    exp.model,
                    {binding.P_CMD: exp.command},
                    self.overrides(theta, exp),
                    exp.t,
                    self.settings,
                    list(exp.outputs),
                )
                for o in exp.outputs:
                    out.append((np.asarray(res[o]) - exp.data[o]) / exp.sigma[o])
            except SarcomereError:  # a failed simulation: a large, finite residual
                out += [np.full(len(exp.t), 1e3) for _ in exp.outputs]
        return np.concatenate(out)

    def _static(self, exp: TimeSeries, theta: np.ndarray) -> list[np.ndarray]:
        over, guess, values = self.overrides(theta, exp), None, []
        try:
            for level in exp.t:
                guess = solve_equilibrium(exp.model, {binding.P_CMD: level}, over, guess=guess)
                values.append([guess[o] for o in exp.outputs])
        except SarcomereError:
            return [np.full(len(exp.t), 1e3) for _ in exp.outputs]
        v = np.array(values)
        return [(v[:, j] - exp.data[o]) / exp.sigma[o] for j, o in enumerate(exp.outputs)]

    def cost(self, theta: np.ndarray) -> float:
        r = self.residuals(theta)
        return 0.5 * float(r @ r)


def starts(truth: dict, names: list[str], count: int, seed: int = 0) -> np.ndarray:
    """``count`` log-parameter vectors, each parameter log-uniform in 0.5-2x the truth."""
    rng = np.random.default_rng(seed)
    centre = np.log([truth[n] for n in names])
    return centre + rng.uniform(np.log(0.5), np.log(2.0), (count, len(names)))


def fit_least_squares(
    problem: Problem, theta0: np.ndarray, tuned: bool = True, trace: bool = False
) -> dict:
    """The baseline: scipy's TRF with 2-point finite differences, from ``theta0``;
    ``tuned``: a finite-difference step of :data:`DIFF_STEP` (relative, on the
    log-parameters) instead of scipy's default 1.5e-8, which is below the simulation's
    own error at ``rtol`` 1e-8 (the default stops early on noise: ``lsq-default``).
    ``trace``: also each residual evaluation's (CPU s, wall s, cost) since the start."""
    low, high = problem.bounds()
    problem.evaluations = 0
    log: list[tuple[float, float, float]] = []
    cpu, wall = time.process_time(), time.perf_counter()

    def residuals(theta: np.ndarray) -> np.ndarray:
        r = problem.residuals(theta)
        log.append((time.process_time() - cpu, time.perf_counter() - wall, 0.5 * float(r @ r)))
        return r

    sol = least_squares(
        residuals,
        np.clip(theta0, low + 1e-9, high - 1e-9),
        bounds=(low, high),
        method="trf",
        diff_step=DIFF_STEP if tuned else None,
    )
    out = {
        "cost": float(sol.cost),
        "theta": sol.x.tolist(),
        "cpu_s": time.process_time() - cpu,
        "wall_s": time.perf_counter() - wall,
        "evaluations": problem.evaluations,
        "status": int(sol.status),
        "message": str(sol.message),
    }
    if trace:
        out["trace"] = log
    return out


def time_to_reach(trace, cost: float) -> tuple[float, float] | None:
    """The (CPU, wall) seconds of the first evaluation in ``trace`` ((CPU, wall, cost)
    rows, in order) whose cost is at most ``cost``; None when none is."""
    return next(((c, w) for c, w, f in trace if f <= cost), None)


@functools.lru_cache(maxsize=4)
def engine(method: str, data_dir: str | None = None):
    """The engine's bound fit of fit-synthetic (``Fit.from_file`` on a copy with one start,
    ``method``, the data in ``data_dir``: default the packaged files)."""
    from sarcomere.scenarios.fit.run import Fit

    root = resources.files("sarcomere.scenarios.fits")
    folder = Path(data_dir) if data_dir else Path(str(root / "data"))
    text = (root / FIT).read_text().replace('data = "data/', f'data = "{folder}/')
    text = re.sub(r"(?m)^starts = \d+", "starts = 1", text)
    text = re.sub(r'(?m)^method = "[a-z-]+"', f'method = "{method}"', text)
    path = Path(tempfile.mkdtemp(prefix="fitbench")) / FIT
    path.write_text(text)
    return Fit.from_file(path)


def fit_engine(method: str, names: list[str], theta0: np.ndarray, data_dir=None) -> dict:
    """One engine fit (``fit_from``) from ``theta0`` (log-parameters in ``names``' order)."""
    from sarcomere.dynamics.identification.estimate import fit_from

    fit = engine(method, data_dir)
    order = [e.name for e in fit.built.params]
    start = dict(zip(names, np.exp(theta0), strict=True))
    cpu, wall = time.process_time(), time.perf_counter()
    iterations = 0
    try:
        sol = fit_from(fit.built.problem, np.array([start[n] for n in order])).solution
        cost, status, theta = 0.5 * sol.cost, sol.status, sol.theta.tolist()
        iterations = sol.iterations
        if not sol.success:
            cost = math.inf
    except SarcomereError as exc:
        cost, status, theta = math.inf, f"dropped: {exc}"[:200], None
    return {
        "cost": cost,  # 1/2 chi-squared, as least_squares reports it
        "theta": theta,  # in the engine's order (``fit.built.params``)
        "cpu_s": time.process_time() - cpu,
        "wall_s": time.perf_counter() - wall,
        "iterations": iterations,
        "status": status,
    }


#: The engine's methods the ``speed`` command runs side by side (key: its ``runs`` entry).
ENGINE_METHODS = {"ms": "multiple-shooting", "ss": "single-shooting"}

METHODS = {
    "lsq": lambda problem, names, theta0: fit_least_squares(problem, theta0),
    "lsq-default": lambda problem, names, theta0: fit_least_squares(problem, theta0, False),
    "ms": lambda problem, names, theta0: fit_engine("multiple-shooting", names, theta0),
    "ss": lambda problem, names, theta0: fit_engine("single-shooting", names, theta0),
}


def success_summary(runs: dict[str, list[dict]], reference_cost: float | None = None):
    """Per family (``engine``: ms, ss; ``scipy``: lsq, lsq-default, with the baseline's
    ``reference_cost`` from the truth) the best cost; per method the starts within
    :data:`SUCCESS_DCHI2` of its family's best (failed ones have an infinite cost), the
    CPU median and total, and the failures' statuses."""
    family = {m: "engine" if m in ("ms", "ss") else "scipy" for m in runs}
    best = {
        f: min(
            [*([reference_cost] if f == "scipy" and reference_cost is not None else [])]
            + [r["cost"] for m, rs in runs.items() if family[m] == f for r in rs]
        )
        for f in set(family.values())
    }
    summary = {}
    for m, rs in runs.items():
        ok = [2 * (r["cost"] - best[family[m]]) <= SUCCESS_DCHI2 for r in rs]
        cpu = [r["cpu_s"] for r in rs]
        summary[m] = {
            "success": f"{sum(ok)}/{len(ok)}",
            "success_rate": sum(ok) / len(ok),
            "cpu_median_s": float(np.median(cpu)),
            "cpu_total_s": float(np.sum(cpu)),
            "failures": {
                str(r.get("start", k)): [r["cost"], r["status"]]
                for k, (r, good) in enumerate(zip(rs, ok, strict=True))
                if not good
            },
        }
    return best, summary


def convergence_summary(args) -> dict:
    """The success rates of the starts logged so far by ``convergence`` in ``--out`` (a
    run stopped early: the starts every method finished), the baseline's reference cost
    from the truth taken from ``fit_speed.json`` there when present."""
    text = (args.out / "fit_convergence_runs.jsonl").read_text()
    rows = [json.loads(x) for x in text.splitlines()]
    methods = sorted({r["method"] for r in rows})
    done = sorted(
        k
        for k in {r["start"] for r in rows}
        if all(any(r["start"] == k and r["method"] == m for r in rows) for m in methods)
    )
    runs = {m: [r for r in rows if r["method"] == m and r["start"] in done] for m in methods}
    speed = args.out / "fit_speed.json"
    ref = json.loads(speed.read_text())["reference_from_truth"]["cost"] if speed.exists() else None
    best, summary = success_summary(runs, ref)
    return {"starts_done": len(done), "reference_cost": ref, "best_cost": best, "summary": summary}


def convergence(args) -> dict:
    params, experiments, truth = read_fit()
    problem = Problem(params, experiments)
    names = problem.names()
    theta_true = np.log([truth[n] for n in names])
    points = starts(truth, names, args.starts)
    runs = {m: [] for m in args.methods}
    args.out.mkdir(parents=True, exist_ok=True)
    with (args.out / "fit_convergence_runs.jsonl").open("w") as log:  # kept if stopped
        for k, theta0 in enumerate(points):
            for m in args.methods:  # interleaved start by start
                r = METHODS[m](problem, names, theta0)
                runs[m].append(r)
                log.write(json.dumps({"start": k, "method": m, **r}) + "\n")
                log.flush()
                print(
                    f"start {k:2d} {m:4s} cost {r['cost']:.6g} cpu {r['cpu_s']:.1f} s "
                    f"{r['status']} load {os.getloadavg()[0]:.1f}",
                    flush=True,
                )
    reference = fit_least_squares(problem, theta_true)  # from the truth: the optimum near it
    best, summary = success_summary(runs, reference["cost"])
    return {
        "names": names,
        "truth": dict(zip(names, np.exp(theta_true).tolist(), strict=True)),
        "cost_at_truth": problem.cost(theta_true),
        "reference_from_truth": reference,
        "best_cost": best,
        "summary": summary,
        "runs": runs,
    }


def _children_cpu() -> float:
    """CPU seconds of this process's finished children (the C compiler)."""
    import resource

    ru = resource.getrusage(resource.RUSAGE_CHILDREN)
    return ru.ru_utime + ru.ru_stime


def file_start(names: list[str]) -> np.ndarray:
    """The fit file's start values as log-parameters in ``names``' order."""
    fit = engine("multiple-shooting")
    start = {e.name: e.start for e in fit.built.params}
    return np.log([start[n] for n in names])


def engine_trace(
    theta0: np.ndarray, method: str = "multiple-shooting"
) -> list[tuple[float, float, float, float]]:
    """One engine fit (``method``) from ``theta0`` (SI, the engine's order) with each
    linearisation's (CPU s, wall s, 1/2 chi-squared, :func:`natural_level`) since the start:
    multiple shooting's lifted iterates are not feasible (continuity defects) until the
    end; single shooting's always are."""
    from sarcomere.dynamics.identification.estimate import fit_from

    problem = engine(method).built.problem
    inner, log = problem.linearize, []
    cpu, wall = time.process_time(), time.perf_counter()

    n = len(problem.params)

    def traced(v, weights, jacobian=True):
        lin = inner(v, weights, jacobian)
        g = natural_level(lin, n)
        half = 0.5 * float(lin.rw @ lin.rw)
        log.append((time.process_time() - cpu, time.perf_counter() - wall, half, g))
        return lin

    problem.linearize = traced  # this instance only
    try:
        fit_from(problem, theta0)
    finally:
        del problem.linearize
    return log


def natural_level(lin, n: int) -> float:
    """The constraints' size as the Gauss-Newton measures them (``max |G_y^-1 g|``: the
    node change that would restore them, in scaled states; :mod:`gauss_newton`), not the
    raw rows, whose units differ (inf without a Jacobian)."""
    if not lin.g.size:
        return 0.0
    if lin.Jg is None:
        return math.inf
    return float(np.max(np.abs(splu(lin.Jg[:, n:].tocsc()).solve(lin.g))))


def speed(args) -> dict:
    """One fit from the file's start values: the engine (multiple and single shooting, a
    warm-up then ``--repeats`` fits each in this process) interleaved with the baseline
    (``--baseline`` fits); the time the baseline takes to come within ``SUCCESS_DCHI2`` of
    its best cost."""
    cpu, wall, child = time.process_time(), time.perf_counter(), _children_cpu()
    fit = engine("multiple-shooting")  # Fit.from_file: bind, build (and compile if needed)
    build = {
        "cpu_s": time.process_time() - cpu,
        "wall_s": time.perf_counter() - wall,
        "compiler_cpu_s": _children_cpu() - child,
    }
    print(f"build {build}", flush=True)
    params, experiments, truth = read_fit()
    problem = Problem(params, experiments)
    names = problem.names()
    theta0 = file_start(names)
    runs: dict[str, list] = {"ms": [], "ss": [], "lsq": []}
    first = None
    for k in range(args.repeats + 1):
        for key, method in ENGINE_METHODS.items():
            child = _children_cpu()
            r = fit_engine(method, names, theta0)
            r["compiler_cpu_s"] = _children_cpu() - child
            print(
                f"{'warm-up' if k == 0 else f'repeat {k}'} {key}: 1/2 chi2 {r['cost']:.6f} "
                f"cpu {r['cpu_s']:.2f} s wall {r['wall_s']:.2f} s iterations "
                f"{r['iterations']} {r['status']}",
                flush=True,
            )
            if k == 0:
                first = first or r  # multiple shooting's: the first-ever fit
            else:
                runs[key].append(r)
        if 1 <= k <= args.baseline:
            b = fit_least_squares(problem, theta0, trace=True)
            print(f"repeat {k} lsq: cost {b['cost']:.6f} cpu {b['cpu_s']:.2f} s", flush=True)
            runs["lsq"].append(b)
    theta_true = np.log([truth[n] for n in names])
    reference = fit_least_squares(problem, theta_true) if runs["lsq"] else None
    best = min([reference["cost"], *(b["cost"] for b in runs["lsq"])]) if reference else None
    for b in runs["lsq"]:
        b["to_best"] = time_to_reach(b.pop("trace"), best + 0.5 * SUCCESS_DCHI2)
    order = [e.name for e in fit.built.params]
    start_si = np.exp([dict(zip(names, theta0, strict=True))[n] for n in order])
    traces = {key: engine_trace(start_si, method) for key, method in ENGINE_METHODS.items()}
    at = dict(zip(order, runs["ms"][0]["theta"], strict=True)) if runs["ms"] else None
    # the engine's optimum on the baseline's cost (CVODES): the same optimum?
    lsq_at_engine = problem.cost(np.log([at[n] for n in names])) if at else None

    def median(rs, key):
        return float(np.median([r[key] for r in rs])) if rs else None

    def engine_summary(key: str) -> dict:
        trace = traces[key]
        best = min((r["cost"] for r in runs[key]), default=math.inf)
        feasible = [(c, w, f) for c, w, f, g in trace if g <= 1e-6]  # gauss_newton's gtol
        return {
            "cpu_median_s": median(runs[key], "cpu_s"),
            "wall_median_s": median(runs[key], "wall_s"),
            "iterations": [r["iterations"] for r in runs[key]],
            "half_chi2": runs[key][0]["cost"] if runs[key] else None,
            "traced_cpu_to_best_s": time_to_reach(feasible, best + 0.5 * SUCCESS_DCHI2),
            "traced_cpu_total_s": trace[-1][0] if trace else None,
        }

    summary = {
        "engine": engine_summary("ms"),
        "single_shooting": engine_summary("ss"),
        "baseline": {
            "cpu_median_s": median(runs["lsq"], "cpu_s"),
            "wall_median_s": median(runs["lsq"], "wall_s"),
            "cpu_to_best_median_s": float(np.median([b["to_best"][0] for b in runs["lsq"]]))
            if runs["lsq"] and all(b["to_best"] for b in runs["lsq"])
            else None,
            "evaluations": [b["evaluations"] for b in runs["lsq"]],
            "best_cost": best,
            "cost_at_engine_optimum": lsq_at_engine,
        },
    }
    for key, prefix in (("engine", ""), ("single_shooting", "single_shooting_")):
        e, b = summary[key], summary["baseline"]
        if e["cpu_median_s"] and b["cpu_median_s"]:
            summary[f"{prefix}ratio_cpu"] = b["cpu_median_s"] / e["cpu_median_s"]
            if b["cpu_to_best_median_s"]:  # the engine's whole fit: at least its time there
                summary[f"{prefix}ratio_cpu_to_best"] = (
                    b["cpu_to_best_median_s"] / e["cpu_median_s"]
                )
            if b["cpu_to_best_median_s"] and e["traced_cpu_to_best_s"]:
                total = e["traced_cpu_total_s"]  # traced: scale to the untraced median
                there = e["traced_cpu_to_best_s"][0] / total * e["cpu_median_s"]
                summary[f"{prefix}ratio_cpu_both_to_best"] = b["cpu_to_best_median_s"] / there
    return {
        "names": names,
        "start": np.exp(theta0).tolist(),
        "build": build,
        "first_fit": first,
        "reference_from_truth": reference,
        "summary": summary,
        "runs": runs,
        "engine_trace": traces["ms"],
        "single_shooting_trace": traces["ss"],
        "load_average": list(os.getloadavg()),
    }


def profiles(args) -> dict:
    """The profiles of every fitted parameter at the optimum from the file's start, as
    ``Fit.run`` computes them (``Fit._profiles``: one parameter per Dask task) on an
    embedded cluster of ``--workers`` processes, ``--repeats`` times (the first: the
    workers import and build the problem); then each profile alone in this process (its
    CPU time)."""
    from sarcomere.dynamics.identification import uncertainty
    from sarcomere.dynamics.identification.estimate import fit_from
    from sarcomere.scenarios.explore.engine import cluster_client

    fit = engine("multiple-shooting")
    problem = fit.built.problem
    names = [e.name for e in problem.params]
    sol = fit_from(problem, np.array([e.start for e in problem.params])).solution
    fis = uncertainty.fisher(problem, sol)
    walls, profs, cluster_s = [], {}, None
    tic = time.perf_counter()
    with cluster_client(args.workers) if args.repeats else contextlib.nullcontext() as client:
        cluster_s = time.perf_counter() - tic
        for k in range(args.repeats):
            t = time.perf_counter()
            profs = fit._profiles(sol, fis, client)
            walls.append(time.perf_counter() - t)
            print(f"dask {k}: {len(profs)} profiles, wall {walls[-1]:.1f} s", flush=True)
    alone = {}
    for k, name in enumerate(names):
        cpu, wall = time.process_time(), time.perf_counter()
        pr = uncertainty.profile(problem, sol, k, float(fis.sd_phi[k]))
        alone[name] = {
            "cpu_s": time.process_time() - cpu,
            "wall_s": time.perf_counter() - wall,
            "points": len(pr.values),
            "failed": pr.failed,
            "interval": [pr.low, pr.high],
            "fisher": fis.interval[k].tolist(),
            "estimate": float(sol.theta[k]),
        }
        print(f"{name}: {alone[name]}", flush=True)
    return {
        "workers": args.workers,
        "cluster_start_wall_s": cluster_s,
        "dask_wall_s": walls,
        "dask_intervals": {names[k]: [p.low, p.high] for k, p in profs.items()},
        "alone": alone,
        "summary": {
            "dask_wall_first_s": walls[0] if walls else None,
            "dask_wall_warm_median_s": float(np.median(walls[1:])) if len(walls) > 1 else None,
            "alone_cpu_total_s": sum(a["cpu_s"] for a in alone.values()),
        },
        "load_average": list(os.getloadavg()),
    }


def replicate_vector(rows, draws: dict) -> np.ndarray:
    """The data vector in the order of a problem's residual ``rows`` (experiment, signal,
    sample; a static target ``<experiment>#<level>:<signal>`` at sample -1) from
    ``draws``: experiment -> signal -> values (SI, per sample or per level)."""
    out = np.empty(len(rows.experiment))
    for i, (name, signal, sample) in enumerate(
        zip(rows.experiment, rows.signal, rows.sample, strict=True)
    ):
        if sample < 0:
            name, level = name.split(":")[0].split("#")
            sample = int(level) - 1
        out[i] = draws[name][signal][sample]
    return out


def replicate_fit(r: int, from_truth: bool, profile_names: tuple[str, ...]) -> dict:
    """Noise replicate ``r``: the engine's fit (multiple shooting, known noise) from the
    truth (else the file's start), its 95 % Fisher intervals and verdicts, and the
    profile intervals of ``profile_names``. The problem is built once per process; the
    replicate's data replace its ``rows.data`` (the residuals are prediction - data)."""
    from sarcomere.dynamics.identification import uncertainty
    from sarcomere.dynamics.identification.estimate import fit_from

    fit = engine("multiple-shooting")
    problem = fit.built.problem
    names = [e.name for e in problem.params]
    signals: dict[str, set] = {}
    for name, signal in zip(problem.rows.experiment, problem.rows.signal, strict=True):
        signals.setdefault(name.split(":")[0].split("#")[0], set()).add(signal)
    draws = {n: replicate_data(n, r, sorted(s)) for n, s in signals.items()}
    problem.rows.data = replicate_vector(problem.rows, draws)
    truth = _truth()
    start = [truth[n] for n in names] if from_truth else [e.start for e in problem.params]
    cpu = time.process_time()
    out = {"replicate": r, "names": names, "truth": [truth[n] for n in names]}
    try:
        sol = fit_from(problem, np.array(start)).solution
    except SarcomereError as exc:
        return {**out, "status": f"dropped: {exc}"[:300], "cpu_s": time.process_time() - cpu}
    out.update(status=sol.status, chi2=sol.cost, iterations=sol.iterations)
    out["theta"] = sol.theta.tolist()
    if not sol.success:
        return {**out, "cpu_s": time.process_time() - cpu}
    fis = uncertainty.fisher(problem, sol)
    out["fisher"] = fis.interval.tolist()
    out["verdict"] = [v["verdict"] for v in uncertainty.verdicts(problem, fis, None)]
    out["fit_cpu_s"] = time.process_time() - cpu
    prof = {}
    for name in profile_names:
        k = names.index(name)
        tic = time.process_time()
        pr = uncertainty.profile(problem, sol, k, float(fis.sd_phi[k]))
        e = problem.params[k]
        prof[name] = {
            "interval": [pr.low, pr.high],
            "open_to": [e.low, e.high],
            "failed": pr.failed,
            "cpu_s": time.process_time() - tic,
        }
    out["profile"] = prof
    out["cpu_s"] = time.process_time() - cpu
    return out


@functools.lru_cache(maxsize=1)
def _truth() -> dict:
    return read_fit()[2]


def contains(interval, value: float, open_to=None) -> bool:
    """Whether ``interval`` (low, high; a None end is open, up to ``open_to``'s bound)
    holds ``value``."""
    lo, hi = interval
    lo = (open_to[0] if open_to else -math.inf) if lo is None else lo
    hi = (open_to[1] if open_to else math.inf) if hi is None else hi
    return lo <= value <= hi


def coverage_rates(results: list[dict]) -> dict:
    """Per parameter: replicates whose Fisher (and profile, where computed) 95 % interval
    holds the truth, out of the converged replicates, with the rate's own 95 %
    (Clopper-Pearson) interval; the verdicts counted."""
    from scipy.special import betaincinv

    ok = [r for r in results if r.get("status") == "converged"]
    if not ok:
        return {}
    names, truth = ok[0]["names"], ok[0]["truth"]

    def rate(hits: list[bool]) -> dict:
        k, n = sum(hits), len(hits)
        low = float(betaincinv(k, n - k + 1, 0.025)) if k > 0 else 0.0
        high = float(betaincinv(k + 1, n - k, 0.975)) if k < n else 1.0
        return {"hits": f"{k}/{n}", "rate": k / n, "rate_ci95": [low, high]}

    out = {}
    for j, name in enumerate(names):
        row = {"fisher": rate([contains(r["fisher"][j], truth[j]) for r in ok])}
        verdicts = [r["verdict"][j] for r in ok]
        row["verdicts"] = {v: verdicts.count(v) for v in sorted(set(verdicts))}
        with_profile = [r for r in ok if name in r.get("profile", {})]
        if with_profile:
            prof = [r["profile"][name] for r in with_profile]
            row["profile"] = rate([contains(p["interval"], truth[j], p["open_to"]) for p in prof])
            row["profile_open"] = sum(None in p["interval"] for p in prof)
        out[name] = row
    return out


def coverage(args) -> dict:
    """``--replicates`` noise replicates (0, 1, ...: the generator's fixed seeds) fitted on
    ``--workers`` processes; the first ``--profiles`` also get profile intervals."""
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor, as_completed

    params, experiments, truth = read_fit()
    names = Problem(params, experiments).names()
    shown = tuple(n for n in names if n not in NON_IDENTIFIABLE)
    args.out.mkdir(parents=True, exist_ok=True)
    log = args.out / "fit_coverage_replicates.jsonl"
    results = []
    tic = time.perf_counter()
    ctx = multiprocessing.get_context("fork")  # the workers inherit this module
    with ProcessPoolExecutor(args.workers, mp_context=ctx) as pool, log.open("w") as f:
        futures = [
            pool.submit(replicate_fit, r, args.start == "truth", shown if r < args.profiles else ())
            for r in range(args.replicates)
        ]
        for done, fut in enumerate(as_completed(futures), 1):
            r = fut.result()
            results.append(r)
            f.write(json.dumps(r) + "\n")
            f.flush()
            inside = (
                "".join(
                    "+" if contains(iv, t) else "-"
                    for iv, t in zip(r["fisher"], r["truth"], strict=True)
                )
                if "fisher" in r
                else "-"
            )
            print(
                f"{done}/{args.replicates} replicate {r['replicate']} {r['status']} "
                f"cpu {r['cpu_s']:.1f} s fisher {inside} "
                f"wall {time.perf_counter() - tic:.0f} s load {os.getloadavg()[0]:.1f}",
                flush=True,
            )
    results.sort(key=lambda r: r["replicate"])
    failed = [
        {"replicate": r["replicate"], "status": r["status"]}
        for r in results
        if r["status"] != "converged"
    ]
    return {
        "replicates": args.replicates,
        "profiled": min(args.profiles, args.replicates),
        "start": args.start,
        "wall_s": time.perf_counter() - tic,
        "fit_cpu_median_s": float(np.median([r["fit_cpu_s"] for r in results if "fit_cpu_s" in r])),
        "failed": failed,
        "summary": coverage_rates(results),
        "load_average": list(os.getloadavg()),
    }


def coverage_summary(args) -> dict:
    """The coverage rates of the replicates logged so far by ``coverage`` in ``--out``
    (a run stopped early: the replicates it finished)."""
    log = args.out / "fit_coverage_replicates.jsonl"
    results = sorted(
        (json.loads(line) for line in log.read_text().splitlines()), key=lambda r: r["replicate"]
    )
    return {
        "replicates_done": [r["replicate"] for r in results],
        "fit_cpu_median_s": float(np.median([r["fit_cpu_s"] for r in results if "fit_cpu_s" in r])),
        "iterations_median": float(np.median([r.get("iterations", 0) for r in results])),
        "failed": [
            {"replicate": r["replicate"], "status": r["status"]}
            for r in results
            if r["status"] != "converged"
        ],
        "summary": coverage_rates(results),
    }


def noisy_input_data(folder: Path, noise_kpa: float, seed: int = 0) -> None:
    """The packaged records into ``folder`` with Gaussian noise of ``noise_kpa`` on the
    pressure column of the time series (``|p + noise|``: a pressure stays >= 0), as a
    recorded supply pressure; the static curves as they are."""
    root = resources.files("sarcomere.scenarios.fits") / "data"
    rng = np.random.default_rng(seed)
    for f in sorted(root.iterdir(), key=lambda f: f.name):
        if not f.name.endswith(".csv"):
            continue
        lines = f.read_text().splitlines()
        first = next(i for i, ln in enumerate(lines) if ln[:1].isdigit())
        header = lines[first - 1].split(",")
        col = next(i for i, h in enumerate(header) if h.startswith("pressure"))
        per_kpa = to_si(1.0, "kPa") / to_si(1.0, header[col].split("[")[1].rstrip("]").strip())
        rows = lines[first:]
        if header[0].startswith("time"):  # a time series (a static curve has none)
            rows = []
            for ln in lines[first:]:
                parts = ln.split(",")
                noisy = float(parts[col]) + noise_kpa * per_kpa * rng.standard_normal()
                parts[col] = repr(abs(noisy))
                rows.append(",".join(parts))
        (folder / f.name).write_text("\n".join(lines[:first] + rows) + "\n")


def noisy_input(args) -> dict:
    """The engine's fit from the file's start on records whose applied pressure is a noisy
    measurement (every sample a kink: one Radau IIA step per sample), ``--repeats``
    times after a warm-up; the steps per record."""
    from sarcomere.dynamics.identification.estimate import fit_from

    folder = Path(tempfile.mkdtemp(prefix="fitnoisy"))
    noisy_input_data(folder, args.noise_kpa)
    fit = engine("multiple-shooting", str(folder))
    problem = fit.built.problem
    start = np.array([e.start for e in fit.built.params])
    fit_from(problem, start)
    runs = []
    for _ in range(args.repeats):
        cpu = time.process_time()
        sol = fit_from(problem, start).solution
        runs.append(
            {
                "cpu_s": time.process_time() - cpu,
                "iterations": sol.iterations,
                "status": sol.status,
                "half_chi2": 0.5 * sol.cost,
            }
        )
        print(f"noisy input: cpu {runs[-1]['cpu_s']:.2f} s, {sol.iterations} iterations")
    return {
        "noise_kpa": args.noise_kpa,
        "steps": {s.model.name + f"#{k}": len(s.grid.k0) for k, s in enumerate(problem.shootings)},
        "runs": runs,
        "summary": {"cpu_median_s": float(np.median([r["cpu_s"] for r in runs]))},
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python benchmarks/fit.py")
    parser.add_argument(
        "command",
        choices=(
            "convergence",
            "convergence-summary",
            "speed",
            "coverage",
            "coverage-summary",
            "profiles",
            "noisy-input",
        ),
    )
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--baseline", type=int, default=5)
    parser.add_argument("--replicates", type=int, default=200)
    parser.add_argument("--profiles", type=int, default=0)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--start", choices=("truth", "file"), default="truth")
    parser.add_argument("--starts", type=int, default=50)
    parser.add_argument("--methods", default="lsq", type=lambda s: s.split(","))
    parser.add_argument("--noise-kpa", type=float, default=0.2)
    parser.add_argument("--out", type=Path, default=Path("out/bench/fit"))
    args = parser.parse_args(argv)
    commands = {
        "convergence": convergence,
        "speed": speed,
        "coverage": coverage,
        "profiles": profiles,
        "coverage-summary": coverage_summary,
        "convergence-summary": convergence_summary,
        "noisy-input": noisy_input,
    }
    result = commands[args.command](args)
    args.out.mkdir(parents=True, exist_ok=True)
    path = args.out / f"fit_{args.command.replace('-', '_')}.json"
    path.write_text(json.dumps(result, indent=1) + "\n")
    print(json.dumps(result.get("summary", {}), indent=1))
    print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
