"""Speed of the CasADi path (CVODES, compiled Radau IIA) against scipy's Radau at equal
accuracy.

Scenario: n = 3 APS, 50 g, pressure step 0 -> 0.1 MPa at 0.1 s, 2 s, 201 saved points
(:func:`sarcomere.dynamics.studies.workprecision.scenarios`). Accuracy: the l2 error of
:mod:`sarcomere.dynamics.studies.workprecision` (states scaled by their nominal magnitude)
against CVODES at rtol 1e-12. Each solver is swept over rtol = 10^-2.5 ... 10^-8 in
half decades, every point timed as the median of ``--repeats`` warm calls of
``simulate``, and the wall time at error 1e-6 is interpolated log-log.

Then the CVODES path is taken apart (cold call, integrator, output evaluation,
restart) and a compiled right-hand side (CasADi ``jit`` with gcc -O2) is measured, and
the compiled Radau IIA (``radau``) is split into Python and C time
(:func:`dissect_radau`).
Last, why BDF needs more steps than Radau (:func:`bdf_steps`): CVODES steps at error 1e-6
per maximum BDF order, with the exact flow law and its C1 variant, and the angles of the
model's oscillatory eigenvalues against the stability sectors of BDF of each order.

Usage::

    python benchmarks/speed.py --out out/bench/speed.json [--repeats 7]
"""

from __future__ import annotations

import argparse
import json
import statistics
import time
from pathlib import Path

import numpy as np

from sarcomere.dynamics import hanging_load
from sarcomere.dynamics.equilibrium import solve_equilibrium
from sarcomere.dynamics.simulation import radau
from sarcomere.dynamics.simulation.settings import HELD
from sarcomere.dynamics.simulation.simulate import SolverSettings, simulate
from sarcomere.dynamics.simulation.sundials import integrator
from sarcomere.dynamics.studies import workprecision as wp
from sarcomere.dynamics.studies.pysource import register_baseline

TARGET = 1e-6
TOLERANCES = tuple(10.0 ** (-k / 2) for k in range(5, 17))
SOLVERS = {
    "radau (compiled Radau IIA, C + CasADi-generated RHS and Jacobian)": ("radau", ()),
    "cvodes": ("cvodes", ()),
    "cvodes, compiled RHS (jit, gcc -O2)": (
        "cvodes",
        (("jit", True), ("compiler", "shell"), ("jit_options", {"flags": ["-O2"]})),
    ),
    "scipy_radau_numpy (Python RHS from the CasADi graph, scipy FD Jacobian)": (
        "scipy_radau_numpy",
        (),
    ),
    "scipy_radau (buffered CasADi calls)": ("scipy_radau", ()),
    "scipy_radau (plain CasADi calls)": ("scipy_radau", (("call", "plain"),)),
    "scipy_bdf": ("scipy_bdf", ()),
    "scipy_lsoda": ("scipy_lsoda", ()),
}


def median_wall(fn, repeats: int) -> tuple[float, float]:
    """(cold, median of ``repeats`` warm) wall times [s] of ``fn()``."""
    tic = time.perf_counter()
    fn()
    cold = time.perf_counter() - tic
    walls = []
    for _ in range(repeats):
        tic = time.perf_counter()
        fn()
        walls.append(time.perf_counter() - tic)
    return cold, statistics.median(walls)


def equal_accuracy(sc: wp.Scenario, ref: wp.Reference, repeats: int) -> dict:
    """Wall time at l2 error 1e-6 per solver, interpolated on its tolerance sweep."""
    plan = wp.Plan(TOLERANCES, {}, repeats, 10.0, 0.0)
    out = {}
    for label, (method, options) in SOLVERS.items():
        recs = []
        for tol in TOLERANCES:
            s = SolverSettings(method, tol, tol * wp.ATOL_PER_RTOL, options=options)
            recs.append(wp.run_point(sc, ref, s, plan))
            if recs[-1]["status"] == "ok" and recs[-1]["error_l2"] < TARGET / 10:
                break
        out[label] = {
            "wall_at_1em6_s": wp.wall_at_error(recs, method, TARGET),
            "points": [
                {
                    k: r.get(k)
                    for k in ("rtol", "error_l2", "wall_time_s", "n_steps", "n_rhs", "status")
                }
                for r in recs
            ],
        }
        print(f"{label:40s} wall at 1e-6: {out[label]['wall_at_1em6_s']}")
    return out


PAIRED = ("radau", "cvodes", "scipy_radau_numpy")


def paired(sc: wp.Scenario, acc: dict, repeats: int) -> dict:
    """The headline ratio, timed interleaved: for each of :data:`PAIRED` the two sweep
    points that bracket error 1e-6 (their errors from the sweep), then ``repeats`` rounds
    in which every one of those runs is called once, so machine load hits all methods
    alike; medians per point, interpolated log-log at 1e-6. Wall time and the process's
    CPU time (``time.process_time``: what the call itself used, robust to other jobs on
    a shared machine, which stretch a 200 ms call more often than a 2 ms one)."""
    runs = {}
    for label, (method, options) in SOLVERS.items():
        if method not in PAIRED or options or method in runs:
            continue
        pts = [q for q in acc[label]["points"] if q["status"] == "ok"]
        for a, b in zip(pts[:-1], pts[1:], strict=False):
            if min(a["error_l2"], b["error_l2"]) <= TARGET <= max(a["error_l2"], b["error_l2"]):
                runs[method] = [dict(a), dict(b)]
                break
    walls: dict[tuple[str, int], list[float]] = {}
    cpus: dict[tuple[str, int], list[float]] = {}
    for _ in range(repeats + 1):  # the first round is warm-up
        for method, pts in runs.items():
            for i, q in enumerate(pts):
                s = SolverSettings(method, q["rtol"], q["rtol"] * wp.ATOL_PER_RTOL)
                tic, cpu = time.perf_counter(), time.process_time()
                sc.run(s)
                walls.setdefault((method, i), []).append(time.perf_counter() - tic)
                cpus.setdefault((method, i), []).append(time.process_time() - cpu)
    out = {}
    for method, pts in runs.items():
        recs = [{**q, "method": method} for q in pts]
        for i, q in enumerate(recs):
            q["wall_time_s"] = statistics.median(walls[method, i][1:])
            q["cpu_time_s"] = statistics.median(cpus[method, i][1:])
        cpu_recs = [{**q, "wall_time_s": q["cpu_time_s"]} for q in recs]
        out[method] = {
            "wall_at_1em6_s": wp.wall_at_error(recs, method, TARGET),
            "cpu_at_1em6_s": wp.wall_at_error(cpu_recs, method, TARGET),
            "points": recs,
        }
    for key in ("wall", "cpu"):
        base = out.get("scipy_radau_numpy", {}).get(f"{key}_at_1em6_s")
        for v in out.values():
            t = v[f"{key}_at_1em6_s"]
            v[f"speedup_vs_scipy_radau_numpy_{key}"] = base / t if base and t else None
    return out


def dissect_cvodes(sc: wp.Scenario, rtol: float, repeats: int) -> dict:
    """Where the time of one ``simulate`` call with CVODES goes."""
    model, x0 = sc.setup()
    settings = SolverSettings("cvodes", rtol, rtol * wp.ATOL_PER_RTOL)
    sc.run(settings)
    totals, methods = [], []
    for _ in range(repeats):
        tic = time.perf_counter()
        res = sc.run(settings)
        totals.append(time.perf_counter() - tic)
        methods.append(res.meta["wall_time_s"])
    out = {
        "rtol": rtol,
        "simulate_total_s": statistics.median(totals),
        "method_s": statistics.median(methods),
        "n_steps": res.meta["n_steps"],
        "n_rhs": res.meta["n_rhs"],
        "n_jac": res.meta["n_jac"],
    }
    out["outputs_and_setup_s"] = out["simulate_total_s"] - out["method_s"]
    out.update(_output_costs(model, sc.run(settings, all_signals=True), repeats))
    jit = SolverSettings(
        "cvodes", rtol, rtol * wp.ATOL_PER_RTOL, options=(("jit", True), ("compiler", "shell"))
    )
    cold, warm = median_wall(lambda: sc.run(jit), repeats)
    out["simulate_jit_default_flags_cold_s"], out["simulate_jit_default_flags_s"] = cold, warm
    for label, extra in (
        ("integrator", {}),
        (
            "integrator_jit_O2",
            {"jit": True, "compiler": "shell", "jit_options": {"flags": ["-O2"]}},
        ),
    ):
        tic = time.perf_counter()
        F_pre, F_post = _direct_integrators(sc, model, rtol, extra)
        out[f"{label}_build_s"] = time.perf_counter() - tic

        def run(F_pre=F_pre, F_post=F_post):
            F_post(F_pre(x0)[:, -1])

        out[f"{label}_call_s"] = median_wall(run, repeats)[1]
    no_restart = wp.Scenario(
        "step_no_restart", "", sc.n, sc.load_kg, sc.p_start, _NoBreakpoints(sc.command)
    )
    ref = wp.reference(sc, 1e-8)
    settings_nr = SolverSettings("cvodes", rtol, rtol * wp.ATOL_PER_RTOL)
    res_nr = no_restart.run(settings_nr)
    out["no_restart_s"] = median_wall(lambda: no_restart.run(settings_nr), repeats)[1]
    out["no_restart_error_l2"] = wp.state_errors(wp.states(res_nr, model), ref)[1]
    out["restart_error_l2"] = wp.state_errors(wp.states(res, model), ref)[1]
    return out


def dissect_radau(sc: wp.Scenario, rtol: float, repeats: int) -> dict:
    """Where the time of one ``simulate`` call with ``radau`` goes: ``simulate`` in
    total, the method's share (``meta["wall_time_s"]``), the one compiled call
    (``radau_runs.c``: both pieces, the domain checks) timed around the ctypes call, in
    CPU time (``time.process_time``) and wall time, and the integrator's counters. The
    Python share is the call minus the C: what the library runs in Python around it."""
    model, x0 = sc.setup()
    settings = SolverSettings("radau", rtol, rtol * wp.ATOL_PER_RTOL)
    tic = time.perf_counter()
    sc.run(settings)
    cold = time.perf_counter() - tic
    lib = radau.library(model, HELD)
    raw, c_wall, c_cpu = lib.runs, [0.0], [0.0]

    def timed(*args):
        tic, cpu = time.perf_counter(), time.process_time()
        code = raw(*args)
        c_wall[0] += time.perf_counter() - tic
        c_cpu[0] += time.process_time() - cpu
        return code

    lib.runs = timed
    totals, cpus, methods, c_walls, c_cpus = [], [], [], [], []
    try:
        for _ in range(repeats):
            c_wall[0] = c_cpu[0] = 0.0
            tic, cpu = time.perf_counter(), time.process_time()
            res = sc.run(settings)
            totals.append(time.perf_counter() - tic)
            cpus.append(time.process_time() - cpu)
            methods.append(res.meta["wall_time_s"])
            c_walls.append(c_wall[0])
            c_cpus.append(c_cpu[0])
    finally:
        lib.runs = raw
    counts = {k: res.meta[k] for k in res.meta if k.startswith("n_")}
    total, cpu_total = statistics.median(totals), statistics.median(cpus)
    method, c_calls, c_cpu_s = (statistics.median(v) for v in (methods, c_walls, c_cpus))
    return {
        "rtol": rtol,
        "cold_s": cold,
        "build_s": lib.build_s,
        "simulate_total_s": total,
        "simulate_total_cpu_s": cpu_total,
        "method_s": method,
        "c_calls_s": c_calls,
        "c_calls_cpu_s": c_cpu_s,
        "python_around_c_s": method - c_calls,
        "simulate_outside_method_s": total - method,
        "python_share_wall": (total - c_calls) / total,
        "python_share_cpu": (cpu_total - c_cpu_s) / cpu_total,
        "counts": counts,
        "c_per_step_us": 1e6 * c_calls / counts["n_steps"],
    }


def _output_costs(model, res, repeats: int) -> dict:
    """Cost of evaluating every named signal on the output grid (what ``simulate`` does)."""
    N = len(res.index)
    f = model.function("signals")
    tic = time.perf_counter()
    fm = f.map(N)
    build = time.perf_counter() - tic
    X = wp.states(res, model).T
    Z = np.zeros((model.nz, N))
    U = np.vstack([res[n] for n in model.input_names])
    P = np.repeat(model.parameters()[:, None], N, axis=1)
    evaluate = median_wall(lambda: np.array(fm(X, Z, U, P)), repeats)[1]
    return {"signals_map_build_s": build, "signals_eval_s": evaluate}


class _NoBreakpoints:
    """The same command without breakpoints: the integrator steps across the jump."""

    def __init__(self, sig) -> None:
        self.sig = sig

    def __call__(self, t):
        return self.sig(t)

    def casadi(self, t):
        return self.sig.casadi(t)


def _direct_integrators(sc: wp.Scenario, model, rtol: float, extra: dict):
    """The two CVODES integrators ``simulate`` uses (before/after the step): the library's
    own (:func:`sundials.integrator`, input held, time normalised per segment), built on a
    fresh copy of the model so the build is timed. Returns the two runs as callables."""
    fresh = hanging_load(sc.n, load_kg=sc.load_kg)
    settings = SolverSettings("cvodes", rtol, rtol * wp.ATOL_PER_RTOL, options=tuple(extra.items()))
    tb, grid = sc.command.time, sc.t_out
    T = float(grid[-1])
    pre, post = grid[(grid > 0) & (grid <= tb)], grid[grid > tb]
    taus = (np.round(pre / tb, 12), np.round((post - tb) / (T - tb), 12))
    F_pre, F_post = (integrator(fresh, settings, HELD, tuple(t.tolist())) for t in taus)
    p = model.parameters()
    u_pre, u_post = float(sc.command(0.0)), float(sc.command(tb))

    def pre_run(x0):
        u = np.full((1, len(pre)), u_pre)
        return F_pre(x0=x0, p=np.append(p, (0.0, tb)), u=u)["xf"]

    def post_run(x0):
        u = np.full((1, len(post)), u_post)
        return F_post(x0=x0, p=np.append(p, (tb, T - tb)), u=u)["xf"]

    return pre_run, post_run


#: Stability sector A(alpha) of the BDF methods of order 1..5 [deg]: the method is stable
#: for every h lambda with |arg(-lambda)| < alpha (Hairer & Wanner, Solving ODEs II, V.2).
BDF_ALPHA_DEG = {1: 90.0, 2: 90.0, 3: 86.03, 4: 73.35, 5: 51.84}


def bdf_steps(sc: wp.Scenario) -> dict:
    """CVODES steps at error 1e-6 per maximum BDF order (``max_order``) and flow law
    ("iso6358": linear laminar join with a 2x slope jump; "smooth": the C1 cubic join),
    each against its own CVODES reference at rtol 1e-12; the l2/max difference between
    the two laws' references (what the C1 join changes in the physics); and the
    oscillatory eigenvalues at the start and end equilibria with their angle from the
    negative real axis, against :data:`BDF_ALPHA_DEG`."""
    out: dict = {"laws": {}}
    refs = {}
    for law in ("iso6358", "smooth"):
        model = hanging_load(sc.n, load_kg=sc.load_kg, flow_law=law)
        x0 = solve_equilibrium(model, {wp.P_CMD: sc.p_start}).x

        def run(settings, model=model, x0=x0):
            res = simulate(
                model,
                sc.t_final,
                {wp.P_CMD: sc.command},
                x0=x0,
                settings=settings,
                t_out=sc.t_out,
                signals=model.state_names,
            )
            return wp.states(res, model), res.meta["n_steps"]

        X_ref, _ = run(SolverSettings("cvodes", 1e-12, 1e-15))
        refs[law] = X_ref
        scale = np.where(np.abs(X_ref).max(axis=0) > 0, np.abs(X_ref).max(axis=0), 1.0)
        per_order = {}
        for order in (2, 3, 4, 5):
            pts = []
            for tol in TOLERANCES:
                s = SolverSettings(
                    "cvodes", tol, tol * wp.ATOL_PER_RTOL, options=(("max_order", order),)
                )
                X, steps = run(s)
                err = float(np.sqrt(np.mean(((X - X_ref) / scale) ** 2)))
                pts.append({"rtol": tol, "error_l2": err, "n_steps": steps})
                if err < TARGET / 10:
                    break
            per_order[order] = {"steps_at_1em6": _steps_at(pts, TARGET), "points": pts}
            print(f"{law:8s} max_order {order}: steps at 1e-6 {per_order[order]['steps_at_1em6']}")
        out["laws"][law] = per_order
    scale = np.where(
        np.abs(refs["iso6358"]).max(axis=0) > 0, np.abs(refs["iso6358"]).max(axis=0), 1
    )
    E = (refs["smooth"] - refs["iso6358"]) / scale
    out["smooth_vs_exact"] = {
        "error_l2": float(np.sqrt(np.mean(E**2))),
        "error_max": float(np.abs(E).max()),
    }
    model = hanging_load(sc.n, load_kg=sc.load_kg)
    lin = model.linearization(["load.s"])
    out["eigenvalues"] = {}
    for p_cmd in (sc.p_start, float(sc.command(sc.t_final))):
        eq = solve_equilibrium(model, {wp.P_CMD: p_cmd})
        A = np.array(lin(eq.x, eq.z, eq.u, eq.p)[0])
        ev = [complex(e) for e in np.linalg.eigvals(A) if e.imag > 0]
        out["eigenvalues"][f"{p_cmd:g} Pa"] = [
            {
                "re": e.real,
                "im": e.imag,
                "angle_deg": float(np.degrees(np.arctan2(e.imag, -e.real))),
            }
            for e in sorted(ev, key=abs)
        ]
    out["bdf_alpha_deg"] = BDF_ALPHA_DEG
    return out


def _steps_at(points: list[dict], target: float) -> float | None:
    """Steps at error ``target``, interpolated log-log between the bracketing points."""
    for a, b in zip(points[:-1], points[1:], strict=False):
        ea, eb = a["error_l2"], b["error_l2"]
        if min(ea, eb) <= target <= max(ea, eb) and ea != eb:
            w = (np.log(target) - np.log(ea)) / (np.log(eb) - np.log(ea))
            return float(np.exp(np.log(a["n_steps"]) + w * np.log(b["n_steps"] / a["n_steps"])))
    return None


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path("out/bench/speed.json"))
    parser.add_argument("--repeats", type=int, default=7)
    parser.add_argument(
        "--bdf-only", action="store_true", help="only the BDF step study (10 s), no timings"
    )
    args = parser.parse_args()
    register_baseline()
    sc = wp.scenarios(3)["step"]
    if args.bdf_only:
        bdf = bdf_steps(sc)
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(json.dumps({"scenario": sc.description, "bdf_steps": bdf}, indent=1))
        print(json.dumps({k: bdf[k] for k in ("smooth_vs_exact", "eigenvalues")}, indent=1))
        return
    ref = wp.reference(sc, 1e-8)
    acc = equal_accuracy(sc, ref, args.repeats)
    cv = acc["cvodes"]["wall_at_1em6_s"]
    ratios = {
        k: (v["wall_at_1em6_s"] / cv if v["wall_at_1em6_s"] and cv else None)
        for k, v in acc.items()
    }
    pair = paired(sc, acc, args.repeats)
    for method, v in pair.items():
        print(f"paired {method:20s} at 1e-6: wall {v['wall_at_1em6_s']}, cpu "
              f"{v['cpu_at_1em6_s']}; speedup vs scipy_radau_numpy: wall "
              f"{v['speedup_vs_scipy_radau_numpy_wall']}, cpu "
              f"{v['speedup_vs_scipy_radau_numpy_cpu']}")  # fmt: skip
    dis = dissect_cvodes(sc, 1e-6, args.repeats)
    dis_radau = dissect_radau(sc, 10**-4.5, args.repeats)
    bdf = bdf_steps(sc)
    result = {
        "scenario": sc.description,
        "target_error_l2": TARGET,
        "equal_accuracy": acc,
        "ratio_to_cvodes": ratios,
        "paired": pair,
        "cvodes_dissection": dis,
        "radau_dissection": dis_radau,
        "bdf_steps": bdf,
        "reference_crosscheck": ref.crosscheck,
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(result, indent=1))
    print(json.dumps({"ratio_to_cvodes": ratios, "radau_dissection": dis_radau}, indent=1))


if __name__ == "__main__":
    main()
