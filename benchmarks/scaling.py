"""Cost per simulated second against chain length n, and CVODES linear-solver options.

For n = 1, 3, 10, 30, 100 APS (50 g, step 0 -> 0.1 MPa at 0.1 s, 0.5 s, 51 saved
points; start: the 0 MPa equilibrium, or where Newton does not converge from the
start values (n >= 30) the state after 5 s of settling) each configuration is run
``--repeats`` times warm; reported: the median wall time of ``simulate`` per simulated
second and per integrator step, with the exponent ``k`` of a least-squares fit
``cost ~ n^k`` over n >= 3 (a failed run is recorded, not timed). Configurations:
CVODES with its default linear solver, with ``linear_solver = "csparse"`` (sparse
LU) and ``"qr"`` (CasADi's sparse QR), and scipy Radau with the exact sparse Jacobian.

``--at-error``: instead, ``radau`` against CVODES at equal accuracy for n = 30 and 100:
the step scenario of :mod:`sarcomere.dynamics.studies.workprecision` over 0.5 s (51
saved points) from the 0 MPa equilibrium, each method swept over rtol = 10^-4 ...
10^-8 in half decades (``atol = 1e-3 rtol``), the l2 error (states scaled) against
CVODES at rtol 1e-10, the wall time at error 1e-6 interpolated log-log (medians of
``--repeats`` warm calls; radau's library compiled, or loaded from the cache, by the
cold call).

Usage::

    python benchmarks/scaling.py --out out/bench/scaling.json [--repeats 3] [--max-n 100]
    python benchmarks/scaling.py --at-error [--n 30 100] [--out out/bench/radau_n.json]
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import statistics
import time
from pathlib import Path

import numpy as np

from sarcomere.dynamics.assemblies import hanging_load
from sarcomere.dynamics.equilibrium import solve_equilibrium
from sarcomere.dynamics.errors import SolverError
from sarcomere.dynamics.simulation.simulate import SolverSettings, simulate
from sarcomere.dynamics.studies import workprecision as wp

SIZES = (1, 3, 10, 30, 100)
T_FINAL_S = 0.5
RTOL = 1e-6
CONFIGS = {
    "cvodes (default)": SolverSettings("cvodes", RTOL, RTOL * 1e-3),
    "cvodes csparse": SolverSettings(
        "cvodes", RTOL, RTOL * 1e-3, options=(("linear_solver", "csparse"),)
    ),
    "cvodes qr (sparse QR)": SolverSettings(
        "cvodes", RTOL, RTOL * 1e-3, options=(("linear_solver", "qr"),)
    ),
    "scipy_radau": SolverSettings("scipy_radau", RTOL, RTOL * 1e-3),
}


def start_state(model) -> tuple[np.ndarray, str]:
    """The 0 MPa equilibrium (the solver settles long chains before Newton itself)."""
    return solve_equilibrium(model, {wp.P_CMD: 0.0}).x, "equilibrium"


def cost(model, x0: np.ndarray, settings: SolverSettings, repeats: int) -> dict:
    """Median warm wall time per simulated second [s/s] and statistics of one config."""
    step = dataclasses.replace(wp.scenarios(1)["step"], t_final=T_FINAL_S, n_out=51)

    def run():
        return simulate(
            model,
            step.t_final,
            inputs={wp.P_CMD: step.command},
            x0=x0,
            settings=settings,
            t_out=step.t_out,
            signals=model.state_names,  # integration cost, not output evaluation
        )

    tic = time.perf_counter()
    try:
        res = run()
    except SolverError as exc:
        return {"status": "failed", "message": " ".join(str(exc).split())[:200]}
    cold = time.perf_counter() - tic
    walls = []
    for _ in range(repeats):
        tic = time.perf_counter()
        res = run()
        walls.append(time.perf_counter() - tic)
    return {
        "status": "ok",
        "cost_s_per_s": statistics.median(walls) / step.t_final,
        "cost_per_step_us": statistics.median(walls) / res.meta["n_steps"] * 1e6,
        "cold_s": cold,
        "method_s": res.meta["wall_time_s"],
        "n_steps": res.meta["n_steps"],
        "n_rhs": res.meta["n_rhs"],
        "n_jac": res.meta["n_jac"],
    }


def at_error(n: int, repeats: int) -> dict:
    """radau and CVODES at error 1e-6 (l2, states scaled) on the n-APS step scenario."""
    sc = dataclasses.replace(wp.scenarios(n)["step"], t_final=T_FINAL_S, n_out=51)
    model, _ = sc.setup()
    res = sc.run(SolverSettings("cvodes", 1e-10, 1e-13))
    X = wp.states(res, model)
    scale = np.abs(X).max(axis=0)
    ref = wp.Reference(res, X, np.where(scale > 0, scale, 1.0), res.meta)
    tols = tuple(10.0 ** (-k / 2) for k in range(8, 17))
    plan = wp.Plan(tols, {}, repeats, budget_s=20.0, check_rtol=0.0)
    records = wp.sweep(sc, ref, plan, only=("radau", "cvodes"))
    walls = {m: wp.wall_at_error(records, m, 1e-6) for m in ("radau", "cvodes")}
    return {"n": n, "states": model.nx, "wall_at_1e-6_s": walls, "records": records}


def main_at_error(ns: list[int], repeats: int, out: Path | None) -> None:
    rows = []
    for n in ns:
        row = at_error(n, repeats)
        rows.append(row)
        for r in row["records"]:
            if r["status"] != "ok":
                print(f"n={n} {r['method']:6s} rtol {r['rtol']:.1e} FAILED {r['message'][:100]}")
                continue
            print(
                f"n={n} {r['method']:6s} rtol {r['rtol']:.1e} error {r['error_l2']:.2e} "
                f"wall {1e3 * r['wall_time_s']:8.1f} ms steps {r['n_steps']} "
                f"(cold {r['wall_time_cold_s']:.1f} s)"
            )
        w = row["wall_at_1e-6_s"]
        ratio = w["cvodes"] / w["radau"] if all(w.values()) else None
        print(f"n={n} ({row['states']} states) at error 1e-6: {w}, cvodes/radau = {ratio}")
    if out:
        out.parent.mkdir(parents=True, exist_ok=True)
        out.write_text(json.dumps(rows, indent=1))


def exponent(sizes: list[int], costs: list[float]) -> float:
    """Slope of log(cost) against log(n), least squares."""
    return float(np.polyfit(np.log(sizes), np.log(costs), 1)[0])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path("out/bench/scaling.json"))
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--max-n", type=int, default=100)
    parser.add_argument("--at-error", action="store_true", help="radau vs CVODES at 1e-6")
    parser.add_argument("--n", type=int, nargs="+", default=[30, 100])
    args = parser.parse_args()
    if args.at_error:
        main_at_error(args.n, args.repeats, args.out)
        return
    sizes = [n for n in SIZES if n <= args.max_n]
    table: dict[str, dict] = {label: {} for label in CONFIGS}
    for n in sizes:
        tic = time.perf_counter()
        model = hanging_load(n, load_kg=0.05)
        x0, start = start_state(model)
        build = time.perf_counter() - tic
        for label, settings in CONFIGS.items():
            table[label][n] = {**cost(model, x0, settings, args.repeats), "nx": model.nx}
            table[label][n]["start"] = start
            row = table[label][n]
            if row["status"] != "ok":
                print(f"n={n:4d} nx={model.nx:4d} {label:18s} FAILED {row['message'][:120]}")
                continue
            print(
                f"n={n:4d} nx={model.nx:4d} {label:18s} {row['cost_s_per_s']:.4g} s/s, "
                f"{row['cost_per_step_us']:.1f} us/step (steps {row['n_steps']}, "
                f"build+start {build:.2f} s, {start})"
            )
    fits = {}
    for label, rows in table.items():
        ok = [n for n in sizes if n >= 3 and rows[n]["status"] == "ok"]
        for key in ("cost_s_per_s", "cost_per_step_us"):
            fits[f"{label}: {key}"] = (
                exponent(ok, [rows[n][key] for n in ok]) if len(ok) > 1 else None
            )
    result = {"rtol": RTOL, "t_final_s": T_FINAL_S, "sizes": sizes, "table": table}
    result["exponent_n_ge_3"] = fits
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(result, indent=1))
    print(json.dumps(fits, indent=1))


if __name__ == "__main__":
    main()
